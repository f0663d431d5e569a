"""One way to name an evaluator (handx_jax/standard/naming.py; issue 51 items 4-5, issue 54 items 2 and 4): every
command that takes ``--evaluator`` resolves it with ``resolve_evaluator`` and refuses, in one line and exit 2
before any work, a folder that is not a finished evaluator (saying what it is) and a dataset the evaluator
does not score (a corpus-v3 prefix under v8, a corpus-v5 prefix under standard-v6). No training here: the
corpora are 100-clip prefixes, and every refusal comes before a model is trained, sampled or scored."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from handx_jax import standard
from handx_jax.infra.errors import DataError
from handx_jax.standard import assets as standard_assets

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def corpora(tmp_path_factory):
    """(v5, v3): the first 100 clips of `handx data synth` without recipe flags (corpus v5, v8's), and of
    corpus v3 (v6's recipe, read back from v6's card)."""
    from handx_jax.cli import main

    root = tmp_path_factory.mktemp("naming")
    assert main(["data", "synth", "--clips", "100", "--out", str(root / "v5"), "--workers", "1", "--quiet"]) == 0
    v3 = standard.Recipe.from_card(standard.read_card(standard.archived(6))["recipe"])
    standard.build_standard_corpus(root / "v3", 100, recipe=v3, assets=root / "none", workers=1, progress=False)
    return root / "v5", root / "v3"


def test_data_synth_without_flags_builds_a_prefix_of_the_standard_corpus(corpora, capsys):
    from handx_jax.cli import main

    capsys.readouterr()
    assert main(["standard", "check", "--data", str(corpora[0])]) == 0
    assert "a prefix of the standard corpus, 100 clips" in capsys.readouterr().out
    assert main(["standard", "check", "--data", str(corpora[1])]) == 2  # corpus v3: v6's, not v8's
    assert "score it with --evaluator standard-v6" in capsys.readouterr().err


def test_names_and_paths_resolve_to_one_evaluator(tmp_path, monkeypatch):
    r = standard.resolve_evaluator
    v8 = r("standard")
    assert v8.assets == standard.ASSETS and v8.name == "standard-v8" and v8.standard
    assert r(None) == r("standard-v8") == r(standard.ASSETS) == r(standard.ASSETS / "evaluator") == v8
    v6 = r("standard-v6")
    assert v6.assets == REPO / "evaluators/standard-v6" and v6.folder == v6.assets / "evaluator"
    assert r(REPO / "evaluators/standard-v6") == r(REPO / "evaluators/standard-v6/evaluator") == v6
    # The archived versions hold no encoder: theirs is the packaged one, checked against their own card.
    for v in (4, 5, 6, 7):
        a = standard.archived(v)
        assert not (a / "encoder").exists() and standard.encoder_dir(a) == standard.ASSETS / "encoder"
        assert {k for k in standard.read_card(a)["sha256"] if k.startswith("encoder/")} == {
            f"encoder/{p.name}" for p in (standard.ASSETS / "encoder").iterdir()}
    # From an installed wheel (no evaluators/ beside the package), an old name says where it lives.
    monkeypatch.setattr(standard_assets, "ARCHIVE", tmp_path / "not-a-clone" / "evaluators")
    with pytest.raises(DataError, match=r"standard-v6: no such standard evaluator; at hand: standard-v8; the earlier "
                                        r"ones are kept in a clone's evaluators/ folder"):
        r("standard-v6")


def test_the_package_ships_one_evaluator():
    assert [p.name for p in (REPO / "handx_jax/assets").iterdir()] == ["standard"]
    data = (REPO / "pyproject.toml").read_text().split("[tool.setuptools.package-data]")[1].split("[")[0:3]
    assert "standard-v" not in "".join(data)
    index = (REPO / "evaluators/README.md").read_text()
    assert all(f"[v{v}](standard-v{v}/CARD.md)" in index for v in (4, 5, 6, 7))


def _bad_folders(root: Path, data: Path) -> dict:
    ghtt = root / "ghtt-run"  # a G-HTT run folder (what `handx train ghtt` writes first)
    (ghtt / "checkpoints").mkdir(parents=True, exist_ok=True)
    (ghtt / "config.json").write_text(json.dumps({"family": "ghtt"}))
    unfinished = root / "evaluator-training"  # `handx train evaluator` stopped before its evaluator.json
    (unfinished / "checkpoints").mkdir(parents=True, exist_ok=True)
    (unfinished / "config.json").write_text(json.dumps({"trainable": "evaluator"}))
    incomplete = root / "incomplete"
    incomplete.mkdir(exist_ok=True)
    (incomplete / "evaluator.json").write_text(json.dumps({"format": "handx-jax-evaluator", "format_version": 1}))
    return {root / "missing": "no such folder",
            ghtt: "a training run of model family 'ghtt', not an evaluator",
            unfinished: "an evaluator whose training has not finished (no evaluator.json): rerun the same "
                        "`handx train evaluator` command to finish it",
            incomplete: "an incomplete evaluator folder (no params.msgpack)",
            data: "a dataset, not an evaluator"}


def _commands(root: Path, data: Path, ev: str) -> dict:
    """Every command that takes --evaluator, as argv, up to its evaluator and dataset."""
    run = root / "ghtt-run"
    enc = str(standard.encoder_dir())
    return {
        "eval run": ["eval", "run", "--ground-truth", "--data", str(data), "--evaluator", ev],
        "eval prediction": ["eval", "prediction", "--baseline", "last-frame", "--data", str(data),
                            "--observed-frames", "16", "--samples", "2", "--evaluator", ev],
        "eval recognition": ["eval", "recognition", "--run", str(run), "--data", str(data), "--evaluator", ev],
        "standard validity": ["standard", "validity", "--data", str(data), "--out", str(root / "validity"),
                              "--evaluator", ev],
        "sweep run": ["sweep", "run", "sweeps/diffusion_cpu_study.py", "--preset", "demo", "--data", str(data),
                      "--encoder", enc, "--evaluator", ev, "--out", str(root / "sweep")],
        "sweep rescore": ["sweep", "rescore", "--out", str(root / "sweep"), "--data", str(data), "--evaluator", ev],
        "standard package": ["standard", "package", "--data", str(data), "--encoder", enc, "--evaluator", ev,
                             "--out", str(root / "package")],
    }


COMMANDS = ("eval run", "eval prediction", "eval recognition", "standard validity", "sweep run", "sweep rescore",
            "standard package")


def _refused(argv, capsys) -> str:
    from handx_jax.cli import main

    capsys.readouterr()
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, (argv, err)
    assert len(err.splitlines()) == 1, err
    return err


@pytest.mark.parametrize("command", COMMANDS)
def test_a_folder_that_is_not_an_evaluator_is_named_for_what_it_is(command, corpora, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(REPO)  # the sweep file's path
    for folder, what in _bad_folders(tmp_path, corpora[0]).items():
        err = _refused(_commands(tmp_path, corpora[0], str(folder))[command], capsys)
        assert f"--evaluator {folder}: {what}" in err, err
        assert "Traceback" not in err
    # nothing was written: no validity report, no sweep folder, no package
    assert not any((tmp_path / n).exists() for n in ("validity", "sweep", "package"))


@pytest.mark.parametrize("command", [c for c in COMMANDS if c != "standard package"])
def test_every_command_refuses_the_same_dataset_evaluator_pairs(command, corpora, tmp_path, monkeypatch, capsys):
    """A corpus-v3 prefix under v8 and a corpus-v5 prefix under standard-v6, refused by every command with the
    one message of ``standard.check_reference`` (eval recognition included: it used to print the ground
    truth's rows), before any model is trained, sampled or scored."""
    monkeypatch.chdir(REPO)
    monkeypatch.setenv("HANDX_CACHE_DIR", str(tmp_path / "cache"))
    _bad_folders(tmp_path, corpora[0])  # the G-HTT run folder eval recognition reads
    v5, v3 = corpora
    for data, ev, right in ((v3, "standard", "standard-v6"), (v5, "standard-v6", "standard-v8")):
        err = _refused(_commands(tmp_path, data, ev)[command], capsys)
        assert f"not the standard recipe: build option(s)" in err and f"score it with --evaluator {right}" in err, err
    assert not any((tmp_path / n).exists() for n in ("validity", "sweep"))
    assert not (tmp_path / "ghtt-run" / "eval_recognition.json").exists()
