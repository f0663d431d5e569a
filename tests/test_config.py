"""The one config system (handx_jax.config) and the family dispatch table (handx_jax.families)."""

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Optional

import pytest

from handx_jax.config import (ConfigError, add_config_args, apply_overrides, from_dict, get_preset, parse_value,
                              to_dict)


@dataclass(frozen=True)
class Inner:
    levels: tuple[int, ...] = (8, 5, 5, 5)
    pair: tuple[int, float] = (1, 0.5)
    names: list[str] = field(default_factory=lambda: ["a"])
    limit: Optional[int] = None
    scale: float | None = 1.0


@dataclass(frozen=True)
class Outer:
    name: str = "x"
    steps: int = 10
    on: bool = False
    inner: Inner = Inner()

    def validate(self):
        if self.steps < 0:
            raise ConfigError(f"steps must be >= 0, got {self.steps}")


def test_values_parse_for_their_declared_types():
    cfg = apply_overrides(Outer(), ["steps=1e3", "on=yes", "inner.levels=8,8,6,5", "inner.pair=(2, 0.25)",
                                    "inner.names=[p, q]", "inner.limit=7", "inner.scale=none", "name=a=b"])
    assert cfg == Outer(name="a=b", steps=1000, on=True,
                        inner=Inner(levels=(8, 8, 6, 5), pair=(2, 0.25), names=["p", "q"], limit=7, scale=None))
    assert apply_overrides(cfg, ["inner.limit=None", "inner.levels=[]"]).inner.limit is None
    assert apply_overrides(cfg, ["inner.levels=[]"]).inner.levels == ()
    assert parse_value("3", Optional[float], "k") == 3.0 and parse_value("null", Optional[float], "k") is None


@pytest.mark.parametrize("bad, msg", [
    ("inner.levls=8", "did you mean 'inner.levels'"), ("iner.levels=8", "did you mean 'inner'"),
    ("steps=2.5", "expected an integer"), ("inner.levels=8,x", "expected an integer"),
    ("inner.pair=1", "expected 2 comma-separated values"), ("inner.limit=lots", "expected an integer"),
    ("on=maybe", "expected a boolean"), ("inner=1", "is a group"), ("steps.x=1", "is a value"),
    ("steps", "expected key=value"), ("steps=-1", "steps must be >= 0"),
])
def test_bad_overrides_name_the_key(bad, msg):
    with pytest.raises(ConfigError, match=msg.replace("(", r"\(").replace(")", r"\)")):
        apply_overrides(Outer(), [bad])


def test_dict_round_trip_through_json():
    cfg = apply_overrides(Outer(), ["inner.levels=7,5,5,5,5", "inner.limit=3", "on=true"])
    doc = json.loads(json.dumps({**to_dict(cfg), "params": 123}))  # config.json holds extra keys
    assert doc["inner"]["levels"] == [7, 5, 5, 5, 5]
    back = from_dict(Outer, doc)
    assert back == cfg and isinstance(back.inner.levels, tuple) and isinstance(back.inner.pair, tuple)
    assert from_dict(Outer, {"steps": 3}) == Outer(steps=3)  # missing keys take the defaults
    with pytest.raises(ConfigError, match="inner.limit"):
        from_dict(Outer, {"inner": {"limit": "many"}})


def test_presets_and_shared_flags():
    import argparse

    presets = {"tiny": 1, "small": 2}
    assert get_preset(presets, "small") == 2
    with pytest.raises(ConfigError, match="unknown preset 'smal' \\(did you mean 'small'\\?\\); choose from tiny, small"):
        get_preset(presets, "smal")
    p = argparse.ArgumentParser()
    add_config_args(p, presets, default="tiny")
    a = p.parse_args(["--set", "a=1", "--set", "b=2", "--print-config"])
    assert (a.preset, a.set, a.print_config) == ("tiny", ["a=1", "b=2"], True)


def test_unknown_family_is_a_clear_error(capsys):
    from handx_jax.cli import main
    from handx_jax.families import FAMILIES, get_family

    with pytest.raises(ValueError, match="unknown model family 'difusion' \\(did you mean 'diffusion'\\?\\)"):
        get_family("difusion")
    assert main(["train", "difusion", "--out", "x"]) == 2
    assert "did you mean 'diffusion'" in capsys.readouterr().err
    assert main(["params", "nope"]) == 2
    assert "families: " + ", ".join(FAMILIES) in capsys.readouterr().err
    # Every registered family exposes the whole interface.
    for name in FAMILIES:
        fam = get_family(name)
        assert fam.FAMILY == name and dataclasses.is_dataclass(fam.Config) and fam.PRESETS
        for attr in ("make_config", "train", "load", "numbers", "add_train_args", "config_from_args",
                     "add_params_args", "params_from_args", "add_generate_args", "load_for_generate"):
            assert callable(getattr(fam, attr)), (name, attr)


def test_run_records_the_size_it_has():
    from handx_jax.families.diffusion import make_config
    from handx_jax.models.dit import PRESETS

    assert make_config("paper-4L").preset == "paper-4L"
    big = make_config("paper-4L", ["model.layers=12", "model.dim=768", "model.heads=12", "model.ff=3072"])
    assert big.preset == "L12-d768" and big.model == PRESETS["L12-d768"]
    odd = make_config("tiny", ["model.layers=3"])
    assert odd.preset == "L3-d64-H4-F128"
    assert make_config("tiny", ["model.dropout=0.0"]).preset == "tiny"  # not a size change
    # Table B's ladder (paper App., reference §3.3): (L, d, H, FF).
    assert [(c.layers, c.dim, c.heads, c.ff) for n, c in PRESETS.items() if n.startswith("L")] == [
        (2, 256, 4, 1024), (4, 256, 4, 1024), (4, 384, 6, 1536), (8, 384, 6, 1536), (8, 512, 8, 2048),
        (12, 512, 8, 2048), (12, 768, 12, 3072)]


def test_params_command_takes_presets_and_size_flags(capsys):
    from handx_jax.cli import main
    from handx_jax.families.diffusion import make_config, numbers

    assert main(["params", "diffusion", "--preset", "L8-d384", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out == numbers(make_config("L8-d384"))
    assert main(["params", "diffusion", "--preset", "tiny", "--layers", "8", "--dim", "384", "--heads", "6",
                 "--ff", "1536", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == out
    assert main(["params", "diffusion", "--preset", "L8-d38"]) == 2
    assert "did you mean 'L8-d384'" in capsys.readouterr().err
