"""Bad input to ``handx eval run`` (issue 31 items 5, 6): finite but huge motion (×1e30 ended in numpy's
LinAlgError inside FID) and motion in millimetres are caught by the evaluation's range check, one line
naming the file, the clip and the field, before any model is loaded and with nothing written; the API
(``align_generated``, under ``evaluate_generated``) runs the same check. No evaluator is trained: the
check comes first, so these take milliseconds."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from handx_jax.cli import main
from handx_jax.data.handx_npz import HandXClip, write_handx_npz
from handx_jax.evaluation import align_generated
from handx_jax.evaluation.scoring import MAX_ABS_METRES, check_motion_range
from handx_jax.io import DataError


def _motion(seed: int) -> np.ndarray:
    """A plausible clip: joints within 0.3 m of the origin, in metres."""
    return np.random.default_rng(seed).uniform(-0.3, 0.3, size=(60, 2, 21, 3)).astype(np.float32)


def _clips(scale_clip: int, scale: float) -> list[HandXClip]:
    out = []
    for i in range(3):
        m = _motion(i) * (scale if i == scale_clip else 1.0)
        out.append(HandXClip(f"c{i}", m, ["left"], ["right"], ["both"], source_clip=f"c{i}", group=0))
    return out


@pytest.mark.parametrize("scale, words", [(1e30, "joint coordinates up to {m:.3g} m (first in frame 0)"),
                                          (1e3, "up to {m:.3g} m (first in frame 0); the evaluator scores motion in "
                                                "metres within ±100 m of the origin: is it in millimetres")])
@pytest.mark.parametrize("evaluator", [["--evaluator", "E-not-loaded"], []])  # a folder, or the standard one
def test_huge_motion_is_one_line_naming_file_clip_and_field(tmp_path, capsys, scale, words, evaluator):
    clips = _clips(1, scale)
    g = write_handx_npz(tmp_path / "gen.npz", clips)
    words = words.format(m=float(np.abs(clips[1].motion.astype(np.float64)).max()))
    rc = main(["eval", "run", *evaluator, "--generated", str(g), "--data", str(tmp_path / "ds"),
               "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith(f"handx: error: file {g}: clip c1, field 'motion': ") and words in err, err
    assert "\n" not in err and sorted(p.name for p in tmp_path.iterdir()) == ["gen.npz"]  # no run folder


def test_motion_in_range_passes_the_check():
    check_motion_range(_motion(0))
    check_motion_range(np.full((60, 2, 21, 3), MAX_ABS_METRES, np.float32))  # the bound itself is allowed


@pytest.mark.parametrize("bad, words", [(np.nan, "1 non-finite (NaN/inf) values, the first in frame 7"),
                                        (np.inf, "1 non-finite (NaN/inf) values, the first in frame 7"),
                                        (-1e6, "joint coordinates up to 1e+06 m (first in frame 7)")])
def test_the_api_refuses_the_same_motion(bad, words):
    """``align_generated`` (what ``evaluate_generated`` calls) runs the range check on every entry."""
    ds = SimpleNamespace(ids=["c0", "c1", "c2"], split=lambda s: np.arange(3),
                         texts=[{"id": f"c{i}", "left": ["left"], "right": ["right"], "interaction": ["both"]}
                                for i in range(3)])
    clips = _clips(-1, 1.0)
    assert align_generated(clips, ds).motion.shape == (1, 3, 60, 2, 21, 3)  # the good clips align
    m = np.array(clips[2].motion)
    m[7, 1, 4, 2] = bad
    clips[2] = HandXClip("c2", m, ["left"], ["right"], ["both"], source_clip="c2", group=0)
    with pytest.raises(DataError) as e:
        align_generated(clips, ds)
    assert str(e.value).startswith("clip c2, field 'motion': ") and words in str(e.value)


# The standard evaluator: its checksums on every load, card included, naming the file that changed.


@pytest.fixture
def assets_copy(tmp_path):
    import shutil

    from handx_jax import standard

    return Path(shutil.copytree(standard.ASSETS, tmp_path / "assets"))


def _flip(path, at=None):
    data = bytearray(path.read_bytes())
    data[len(data) // 2 if at is None else at] ^= 1
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("name, words", [("evaluator/params.msgpack", "standard evaluator file corrupt: sha256 "
                                          "differs from card.json"),
                                         ("encoder/model.safetensors", "standard evaluator file corrupt"),
                                         ("card.json", "standard evaluator card changed or unverifiable: checksum "
                                          "mismatch"),
                                         ("card.json.sha256", "standard evaluator card changed or unverifiable")])
def test_a_flipped_byte_in_any_standard_file_is_refused_by_name_on_load(assets_copy, name, words):
    from handx_jax import standard

    assert standard.verify_assets(assets_copy)["version"] == standard.VERSION  # the intact copy verifies
    _flip(assets_copy / name, at=0 if name.endswith(".sha256") else None)
    with pytest.raises(DataError) as e:
        standard.load(assets=assets_copy)  # the API: refused before anything is read
    target = assets_copy / (name[:-len(".sha256")] if name.endswith(".sha256") else name)
    assert str(e.value).startswith(f"file {target}: {words}"), str(e.value)


def test_a_missing_card_checksum_is_refused(assets_copy):
    from handx_jax import standard

    (assets_copy / "card.json.sha256").unlink()
    with pytest.raises(DataError, match=r"card\.json: standard evaluator card changed or unverifiable: missing "
                                        r"checksum card\.json\.sha256"):
        standard.load(assets=assets_copy)


def test_eval_run_refuses_a_changed_standard_evaluator_in_one_line(assets_copy, monkeypatch, tmp_path, capsys):
    from handx_jax import standard

    _flip(assets_copy / "evaluator" / "params.msgpack")
    monkeypatch.setattr(standard, "ASSETS", assets_copy)
    rc = main(["eval", "run", "--ground-truth", "--data", str(tmp_path / "ds"), "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == (f"handx: error: file {assets_copy / 'evaluator' / 'params.msgpack'}: standard evaluator "
                               "file corrupt: sha256 differs from card.json (reinstall the package)")
    assert not (tmp_path / "run").exists()
