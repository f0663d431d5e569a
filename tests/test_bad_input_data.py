"""Bad input tried as a new user would (issue 14.8): each is a range or data error naming the argument,
file or clip, on stderr with a non-zero exit, never a traceback.

Bad input to the commands that build, read and derive datasets (issue 54): ``data synth``, ``standard corpus``,
``data reverse``, ``data stats``, ``standard check`` and ``eval prediction --baseline``. Every refusal is one
line and exit 2 before any work, and nothing is written: a numeric flag out of range (``infra.values``), split
fractions that leave a split empty, an ``--out`` that is (inside, or holds) the ``--data`` it reads
(``infra.outputs``), a damaged meta.json or splits.json and a symlink loop (``infra.readers``). In-process, an
8-clip dataset written directly: no synthesis, no training."""

import json
import os
import re

import numpy as np
import pytest

from handx_jax.cli import main
from handx_jax.cli import main as handx
from handx_jax.dataset.format import Dataset, write_dataset
from handx_jax.infra.errors import DataError
from handx_jax.interop.handx_npz import HandXClip, write_handx_npz
from tiny_dataset import write_tiny_dataset


def _clips(levels):
    rng = np.random.default_rng(0)
    return [HandXClip(str(i), rng.normal(0, 0.05, (60, 2, 21, 3)), [f"l{i} {k}" for k in range(lv)],
                      [f"r{i} {k}" for k in range(lv)], [f"i{i} {k}" for k in range(lv)])
            for i, lv in enumerate(levels)]


def test_import_refuses_uneven_caption_levels(tmp_path, capsys):
    """Clip 0 has 3 levels, clip 2 has 2: the import accepted it (count from clip 0) and `data stats`
    then died with an IndexError."""
    npz = write_handx_npz(tmp_path / "train_x.npz", _clips([3, 3, 2, 3]))
    assert handx(["data", "import-handx", str(npz), "--no-events", "--out", str(tmp_path / "ds")]) == 2
    err = capsys.readouterr().err
    assert "train_x.npz, clip 2: 2 caption levels, but clip train_x.npz:0 has 3" in err
    assert not (tmp_path / "ds").exists()


def test_show_level_out_of_range(tmp_path, capsys):
    t = [{"id": f"c{i}", "left": ["a", "b"], "right": ["c", "d"], "interaction": ["e", "f"]} for i in range(2)]
    write_dataset(tmp_path / "ds", np.zeros((2, 60, 2, 21, 3), np.float32) + 0.01 * np.arange(21)[:, None], t,
                  stats=False)
    for level in (9, 2, -3):
        assert handx(["data", "show", "--data", str(tmp_path / "ds"), "--clip", "0", "--out", str(tmp_path / "x.gif"),
                      "--level", str(level)]) == 2
        assert re.fullmatch(rf"handx: error: --level {level} out of range: .* has 2 caption levels \(0\.\.1, or "
                            rf"-2\.\.-1 from the most detailed\)", capsys.readouterr().err.strip())
    for clip, why in (("7", "clip index 7 out of range (dataset has 2 clips)"), ("nope", "no clip with id 'nope' in")):
        assert handx(["data", "show", "--data", str(tmp_path / "ds"), "--clip", clip, "--out",
                      str(tmp_path / "x.gif")]) == 2
        assert capsys.readouterr().err.startswith("handx: error: " + why)
    assert not (tmp_path / "x.gif").exists()


def test_eval_run_replications_must_be_positive(tmp_path, capsys):
    for flags, why in ((["--ground-truth", "--replications", "0"], "--replications must be at least 1, got 0"),
                       (["--ground-truth", "--samples", "1"], "--samples (APD's K) must be at least 2, got 1"),
                       ([], "give exactly one of --generated G.npz or --ground-truth")):
        assert handx(["eval", "run", "--evaluator", str(tmp_path / "E"), "--data", str(tmp_path / "D"), *flags]) == 2
        assert capsys.readouterr().err.strip() == "handx: error: " + why  # one line, exit 2


def test_empty_text_is_refused_everywhere(tmp_path, capsys):
    """One decision: an empty prompt is refused by `text encode` (it crashed) and by `generate` (it
    generated from it); both say so in --help."""
    from handx_jax.text.prompts import check_texts

    enc = str(__import__("pathlib").Path(__file__).parent / "fixtures" / "t5_tiny_relu")
    assert handx(["text", "encode", "--encoder", enc, "hello", "  "]) == 2
    assert "TEXT 2 of 2 is empty ('  ')" in capsys.readouterr().err
    rc = handx(["generate", "--run", str(tmp_path / "run"), "--left", "", "--right", "a", "--interaction", "b",
                "--out", str(tmp_path / "g.npz")])
    out = capsys.readouterr()
    assert rc == 2 and "--left is empty ('')" in out.out + out.err and not (tmp_path / "g.npz").exists()
    check_texts(["the left hand stays still"])  # non-empty text passes
    with pytest.raises(DataError, match="--right 2 of 2 is empty"):
        check_texts(["a", "\n"], "--right")
    for argv in (["text", "encode", "--help"], ["generate", "--help"]):
        try:
            assert handx(argv) == 0  # `generate --help` prints its own help (family options too) and returns
        except SystemExit as e:  # argparse's help exits
            assert e.code == 0
        assert "must not" in capsys.readouterr().out.replace("\n", " ")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return write_tiny_dataset(tmp_path_factory.mktemp("tiny") / "D")


def _refused(argv, capsys) -> str:
    """Run ``handx ARGV``; it must exit 2 without a traceback. Returns the last line of stderr."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:  # argparse refused a flag while parsing (before any handler ran)
        rc = e.code
    cap = capsys.readouterr()
    assert rc == 2 and "Traceback" not in cap.err and cap.out == "", (rc, cap.err)
    return cap.err.strip().splitlines()[-1]


WHOLE = "must be a whole number"
FRACTION = "must be a finite number > 0 and < 1"


@pytest.mark.parametrize("flags, words", [
    (["--clips", "0"], f"argument --clips: {WHOLE} >= 1, got '0'"),
    (["--clips", "-1"], f"argument --clips: {WHOLE} >= 1, got '-1'"),
    (["--clips", "2.5"], f"argument --clips: {WHOLE} >= 1, got '2.5'"),
    (["--seed", "-1"], f"argument --seed: {WHOLE} >= 0, got '-1'"),
    (["--workers", "-1"], f"argument --workers: {WHOLE} >= 0, got '-1'"),
    (["--val-fraction", "nan"], f"argument --val-fraction: {FRACTION}, got 'nan'"),
    (["--val-fraction", "1.5"], f"argument --val-fraction: {FRACTION}, got '1.5'"),
    (["--test-fraction", "-0.1"], f"argument --test-fraction: {FRACTION}, got '-0.1'"),
    (["--val-fraction", "0.6", "--test-fraction", "0.6"],
     "handx data synth: error: --val-fraction 0.6 + --test-fraction 0.6 = 1.2 leaves the train split no clips: "
     "together they must be < 1"),
])
def test_data_synth_refuses_a_bad_number_before_any_work(tmp_path, capsys, flags, words):
    out = tmp_path / "S"
    argv = ["data", "synth", "--out", out, "--clips", "4", *flags] if flags[0] != "--clips" else \
        ["data", "synth", "--out", out, *flags]
    assert words in _refused(argv, capsys)
    assert list(tmp_path.iterdir()) == []


def test_the_build_config_refuses_the_same_from_python(tmp_path):
    from handx_jax.config import ConfigError
    from handx_jax.dataset.build import BuildConfig, build_corpus

    for cfg, words in ((BuildConfig(clips=0), "clips must be a whole number >= 1, got 0"),
                       (BuildConfig(clips=4, seed=-1), "seed must be a whole number >= 0, got -1"),
                       (BuildConfig(clips=4, val_fraction=float("nan")), "val_fraction must be a finite number"),
                       (BuildConfig(clips=4, val_fraction=0.5, test_fraction=0.5), "leaves the train split no clips")):
        with pytest.raises(ConfigError, match=words):
            build_corpus(tmp_path / "S", cfg, progress=False)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("flags, words", [(["--workers", "-1"], f"argument --workers: {WHOLE} >= 0, got '-1'"),
                                          (["--clips", "0"], f"argument --clips: {WHOLE} >= 1, got '0'")])
def test_standard_corpus_refuses_a_bad_count(tmp_path, capsys, flags, words):
    assert words in _refused(["standard", "corpus", "--out", tmp_path / "C", *flags], capsys)
    assert list(tmp_path.iterdir()) == []


def test_data_reverse_never_writes_over_the_dataset_it_reads(tiny, tmp_path, capsys):
    before = {p.name: p.read_bytes() for p in tiny.iterdir()}
    err = _refused(["data", "reverse", "--data", tiny, "--out", tiny, "--force"], capsys)
    assert err == f"handx: error: --out {tiny} is the dataset it reads, --data {tiny}; choose another --out outside it"
    link = tmp_path / "link"
    link.symlink_to(tiny)  # the same folder under another name
    assert "is the dataset it reads" in _refused(["data", "reverse", "--data", tiny, "--out", link, "--force"], capsys)
    err = _refused(["data", "reverse", "--data", tiny, "--out", tiny / "R"], capsys)
    assert err == (f"handx: error: --out {tiny / 'R'} is inside the dataset it reads, --data {tiny}; choose another "
                   "--out outside it")
    err = _refused(["data", "reverse", "--data", tiny, "--out", tiny.parent, "--force"], capsys)
    assert err == (f"handx: error: --out {tiny.parent} contains the dataset it reads, --data {tiny} (writing --out "
                   "replaces that folder, and the dataset in it); choose another --out outside it")
    assert {p.name: p.read_bytes() for p in tiny.iterdir()} == before


@pytest.mark.parametrize("family", ["tokenizer", "ghtt-pose", "evaluator"])
def test_train_never_writes_its_run_into_the_dataset_it_reads(tiny, capsys, family):
    """A run folder on or inside --data would add its files to the dataset's (and `data verify` then calls it
    damaged): refused in one line before anything is written, by the family commands and the trainables alike."""
    before = sorted(p.relative_to(tiny) for p in tiny.rglob("*"))
    from handx_jax import standard

    enc = ["--encoder", str(standard.encoder_dir())] if family == "evaluator" else []
    for out, why in ((tiny / "runs" / "R", "is inside"), (tiny, "is")):
        err = _refused(["train", family, "--data", tiny, *enc, "--preset", "tiny", "--out", out], capsys)
        assert err == (f"handx train {family}: error: --out {out} {why} the dataset it reads, --data {tiny}; "
                       "choose another --out outside it")
    assert sorted(p.relative_to(tiny) for p in tiny.rglob("*")) == before


@pytest.mark.parametrize("clips", ["0", "-2"])
def test_data_reverse_refuses_no_clips_with_exit_2(tiny, tmp_path, capsys, clips):
    err = _refused(["data", "reverse", "--data", tiny, "--out", tmp_path / "R", "--clips", clips], capsys)
    assert err.endswith(f"argument --clips: {WHOLE} >= 1, got '{clips}'")
    assert list(tmp_path.iterdir()) == []


def test_data_reverse_refuses_an_existing_out_before_reading_anything(tmp_path, capsys):
    (tmp_path / "R").mkdir()
    # --data is no dataset at all: the refusal of --out comes first, so no work was done before it
    err = _refused(["data", "reverse", "--data", tmp_path / "nothing", "--out", tmp_path / "R"], capsys)
    assert err == f"handx: error: --out {tmp_path / 'R'} already exists; pass --force (overwrite=True) to replace it"


def _damaged(tiny, root, what):
    d = root / f"D-{what}"
    d.mkdir()
    for p in tiny.iterdir():
        (d / p.name).write_bytes(p.read_bytes())
    if what == "meta":
        meta = json.loads((d / "meta.json").read_text())
        del meta["num_clips"]
        (d / "meta.json").write_text(json.dumps(meta))
    else:
        (d / "splits.json").write_bytes((d / "splits.json").read_bytes()[:20])
    return d


COMMANDS = {"standard check": ["standard", "check"], "data stats": ["data", "stats"],
            "standard validity": ["standard", "validity", "--no-evaluator", "--out", "{out}"],
            "data reverse": ["data", "reverse", "--out", "{out}"]}


@pytest.mark.parametrize("command", sorted(COMMANDS))
@pytest.mark.parametrize("what", ["meta", "splits"])
def test_a_damaged_meta_or_splits_file_is_named(tiny, tmp_path, capsys, command, what):
    d = _damaged(tiny, tmp_path, what)
    argv = [a.format(out=tmp_path / "OUT") for a in COMMANDS[command]] + ["--data", d]
    err = _refused(argv, capsys)
    if what == "meta":
        assert err.startswith(f"handx: error: file {d / 'meta.json'}, field 'num_clips': missing (the file holds ")
    else:
        assert err == (f"handx: error: file {d / 'splits.json'}: corrupt JSON (Expecting value at line 1 column 21: "
                       "truncated or damaged)")
    assert not (tmp_path / "OUT").exists()


def test_splits_that_are_not_clip_indices_are_named(tiny, tmp_path):
    d = _damaged(tiny, tmp_path, "meta")
    (d / "meta.json").write_bytes((tiny / "meta.json").read_bytes())
    for doc, field in (([], None), ({"train": [0, 99]}, "train"), ({"test": "0,1"}, "test"),
                       ({"fractions": {"0.05": [True]}}, "fractions['0.05']")):
        (d / "splits.json").write_text(json.dumps(doc))
        with pytest.raises(DataError) as e:
            Dataset.open(d)
        assert str(e.value).startswith(f"file {d / 'splits.json'}" + (f", field {field!r}" if field else "")), e.value


@pytest.mark.parametrize("argv", [["standard", "check"], ["data", "reverse", "--out", "{out}"],
                                  ["eval", "prediction", "--baseline", "last-frame", "--observed-frames", "10"]])
def test_a_symlink_loop_as_data_is_called_one(tmp_path, capsys, argv):
    loop = tmp_path / "loop"
    os.symlink(loop, loop)
    err = _refused([a.format(out=tmp_path / "OUT") for a in argv] + ["--data", loop], capsys)
    assert err.endswith(f"error: file {loop}: dataset directory is a symlink loop (a link that points back to "
                        "itself); point it at a real file or folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loop"]


def test_export_and_import_never_write_over_what_they_read(tiny, tmp_path, capsys):
    before = (tiny / "motion.npy").read_bytes()
    err = _refused(["data", "export-handx", "--data", tiny, "--out", tiny / "motion.npy"], capsys)
    assert err == f"handx: error: --out {tiny / 'motion.npy'} is inside the dataset it reads, --data {tiny}; choose " \
                  "another --out outside it"
    assert (tiny / "motion.npy").read_bytes() == before
    src = tmp_path / "official"
    src.mkdir()
    npz = src / "train_can_pos_all_wotextfeat.npz"
    assert main(["data", "export-handx", "--data", str(tiny), "--out", str(npz)]) == 0
    capsys.readouterr()
    err = _refused(["data", "import-handx", npz, "--out", src, "--force"], capsys)
    assert err == (f"handx: error: --out {src} contains the dataset it reads, the input file {npz} (writing --out "
                   "replaces that folder, and the dataset in it); choose another --out outside it")
    assert sorted(p.name for p in src.iterdir()) == [npz.name]
