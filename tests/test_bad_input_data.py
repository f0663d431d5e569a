"""Bad input tried as a new user would (issue 14.8): each is a range or data error naming the argument,
file or clip, on stderr with a non-zero exit, never a traceback."""

import numpy as np
import pytest

from handx_jax.cli import main as handx
from handx_jax.dataset.format import write_dataset
from handx_jax.interop.handx_npz import HandXClip, write_handx_npz
from handx_jax.infra.errors import DataError


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


def test_show_level_out_of_range(tmp_path):
    t = [{"id": f"c{i}", "left": ["a", "b"], "right": ["c", "d"], "interaction": ["e", "f"]} for i in range(2)]
    write_dataset(tmp_path / "ds", np.zeros((2, 60, 2, 21, 3), np.float32) + 0.01 * np.arange(21)[:, None], t,
                  stats=False)
    for level in (9, 2, -3):
        with pytest.raises(SystemExit, match=rf"--level {level} out of range: .* has 2 caption levels \(0\.\.1, or -2\.\.-1"):
            handx(["data", "show", "--data", str(tmp_path / "ds"), "--clip", "0", "--out", str(tmp_path / "x.gif"),
                   "--level", str(level)])
    assert not (tmp_path / "x.gif").exists()


def test_eval_run_replications_must_be_positive(tmp_path):
    with pytest.raises(SystemExit, match="--replications must be at least 1, got 0"):
        handx(["eval", "run", "--evaluator", str(tmp_path / "E"), "--data", str(tmp_path / "D"),
               "--ground-truth", "--replications", "0"])


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
