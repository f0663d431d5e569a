"""Bad input to ``handx generate`` and to any command's ``--out`` (issue 31 items 5, 6): decoding options
out of range, ``--observed-frames`` that cannot be, prompts longer than the text encoder's window, and
``--out`` paths that cannot be written (a read-only file system, an existing directory) are one line
each, exit non-zero, with nothing left behind. The decoding options are checked in one place
(``DecodeOptions``), so the CLI and the API refuse the same values; the CLI refuses them before a run is
read, so a folder that only names its family is enough here. Milliseconds each; the checks against a
trained run are in tests/test_ar_family.py (its module fixture)."""

import errno
import math

import numpy as np
import pytest

from handx_jax.cli import main
from handx_jax.families.ar import GenerateOptions, decode
from handx_jax.generation import Prompt
from handx_jax.text.prompts import check_window

PROMPT = ["--left", "the left hand waves", "--right", "the right hand rests", "--interaction", "the hands stay apart"]


@pytest.fixture
def ar_run(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text('{"family": "ar"}')
    return run


CASES = {
    "--top-p 1.5": "top_p (--top-p) must be in (0, 1] (1 = off), got 1.5",
    "--top-p 0": "top_p (--top-p) must be in (0, 1] (1 = off), got 0.0",
    "--top-p nan": "top_p (--top-p) must be in (0, 1] (1 = off), got nan",
    "--top-k -5": "top_k (--top-k) must be a whole number >= 0 (0 = off), got -5",
    "--temperature -1": "temperature (--temperature) must be a finite number >= 0 (0 = greedy), got -1.0",
    "--temperature nan": "temperature (--temperature) must be a finite number >= 0 (0 = greedy), got nan",
    "--temperature inf": "temperature (--temperature) must be a finite number >= 0 (0 = greedy), got inf",
    "--task prediction --source clip.npz --observed-frames 61": "--observed-frames must be even and in (0, 60), got 61",
    "--task prediction --source clip.npz --observed-frames 60": "--observed-frames must be even and in (0, 60), got 60",
}


@pytest.mark.parametrize("flags", sorted(CASES))
def test_out_of_range_options_are_one_line_before_the_run_is_read(ar_run, tmp_path, capsys, flags):
    out = tmp_path / "gen.npz"
    rc = main(["generate", "--run", str(ar_run), *PROMPT, *flags.split(), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == f"handx generate: error: {CASES[flags]}"
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["run"]


@pytest.mark.parametrize("kw, words", [({"temperature": -1.0}, "temperature"), ({"temperature": math.nan}, "temperature"),
                                       ({"top_k": -5}, "top_k"), ({"top_k": 2.5}, "top_k"), ({"top_p": 1.5}, "top_p")])
def test_the_api_refuses_the_same_decoding_options(kw, words):
    with pytest.raises(ValueError, match=f"^{words} "):
        decode.DecodeOptions(**kw)


def test_edges_of_the_ranges_and_traced_options_are_accepted():
    with pytest.raises(ValueError, match="--observed-frames"):
        GenerateOptions(observed_frames=7)
    # Defaults and the edges of each range are accepted; JAX rebuilding the options with tracers is too
    # (the loop's jit: a traced field is not checked).
    decode.DecodeOptions(temperature=0.0, top_k=0, top_p=1.0)
    decode.DecodeOptions(temperature=2.0, top_k=1, top_p=1e-3)
    import jax

    assert jax.jit(lambda o: o.top_p * 2)(decode.DecodeOptions(top_p=0.5)) == 1.0


def test_a_run_config_with_bad_sample_options_is_refused():
    from handx_jax.config import ConfigError
    from handx_jax.families.ar import make_config

    with pytest.raises(ConfigError, match=r"sample\.top_p \(--top-p\) must be in \(0, 1\]"):
        make_config("tiny", ["sample.top_p=1.5"]).validate()


class _Tok:
    """A stand-in tokenizer: one token per word, plus the end token (as encode_one counts)."""

    def encode_one(self, text):
        return text.split() + ["</s>"]


def test_a_prompt_longer_than_the_window_is_refused_naming_its_field():
    long = Prompt("wave " * 200, "rest", "apart")
    with pytest.raises(ValueError, match=r"^--left is 201 tokens \(1,000 characters\), more than the 64 the run's "
                                         r"text encoder reads \(its text max_len\): refused rather than cut"):
        check_window(_Tok(), [long], 64)
    # Joined (the AR prefix): the longest field is named, with the joined length that overflows.
    with pytest.raises(ValueError, match=r"^--right \(prompt 2 of 2\) is 63 tokens .* the three prompts joined are "
                                         r"66 tokens, more than the 64"):
        check_window(_Tok(), [Prompt("a", "b", "c"), Prompt("x", "y " * 62, "z")], 64,
                     joined=lambda p: f"{p.left} {p.right} {p.interaction} <s3>")
    check_window(_Tok(), [Prompt("wave " * 62, "b", "c")], 64)  # 63 tokens fit
    check_window(_Tok(), [Prompt("a " * 20, "b " * 20, "c " * 20)], 64, joined=lambda p: f"{p.left} {p.right}")


def test_the_real_tokenizer_counts_what_the_encoder_would_cut():
    """With the tiny T5 fixture's SentencePiece model: a prompt is refused exactly when Tokenizer.encode
    would truncate it (its num_truncated)."""
    from pathlib import Path

    from handx_jax.text.tokenizer import Tokenizer

    tok = Tokenizer.load(Path(__file__).parent / "fixtures" / "t5_tiny_gated")
    for words in (5, 60, 200):
        text = " ".join(["fingers"] * words)
        cut = tok.encode([text], 64).num_truncated == 1
        try:
            check_window(tok, [Prompt(text, "b", "c")], 64)
            refused = False
        except ValueError:
            refused = True
        assert refused == cut, words


# --out that cannot be written: the one place is handx_jax/cli.py (main), for every command.


def test_out_naming_an_existing_directory_is_one_line(tmp_path, capsys):
    d = tmp_path / "table.md"
    d.mkdir()
    assert main(["analyze", "table", "paper:B", "--out", str(d)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"handx: error: cannot write --out {d}: is a directory (choose another --out)"
    assert list(d.iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == ["table.md"]  # no temp file


def test_out_on_a_read_only_file_system_is_one_line(tmp_path, capsys, monkeypatch):
    import tempfile

    def read_only(*a, dir=None, **kw):  # what mkstemp raises on a read-only mount (errno 30)
        raise OSError(errno.EROFS, "Read-only file system", f"{dir}/{kw.get('prefix', '')}k2x9{kw.get('suffix', '')}")

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    out = tmp_path / "t.md"
    assert main(["analyze", "table", "paper:B", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"handx: error: cannot write --out {out}: read-only file system (choose another --out)"
    assert not out.exists()


def test_out_under_a_file_is_one_line(tmp_path, capsys):
    f = tmp_path / "a_file"
    f.write_text("x")
    out = f / "sub" / "t.md"
    assert main(["analyze", "table", "paper:B", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"handx: error: cannot write --out {out}: not a directory (choose another --out)"
    assert f.read_text() == "x" and sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


@pytest.mark.parametrize("family", ["diffusion", "ar"])
def test_each_family_checks_typed_prompts_against_its_own_window(family):
    """Diffusion encodes each field alone (a field over the window is refused); the AR family joins the
    three (their sum is what must fit). Called by each family's load_for_generate on the typed prompts."""
    from types import SimpleNamespace

    from handx_jax.families import get_family

    cls = {"diffusion": "DiffusionRun", "ar": "ARRun"}[family]
    run = SimpleNamespace(encoder=SimpleNamespace(tokenizer=_Tok()), cfg=SimpleNamespace(data=SimpleNamespace(
        text_max_len=64)))
    check = getattr(get_family(family), cls).check_prompts
    three_halves = Prompt("a " * 30, "b " * 30, "c " * 30)  # 31 tokens each: each fits, joined does not
    if family == "diffusion":
        check(run, [three_halves])
    else:
        with pytest.raises(ValueError, match="^--left is 31 tokens .* the three prompts joined are"):
            check(run, [three_halves])
    with pytest.raises(ValueError, match="^--interaction is 101 tokens"):
        check(run, [Prompt("a", "b", "c " * 100)])


# Contact guidance (issue 43): a spec's frames are checked in one place (guidance.parse_contacts, against
# the clip's frames), and --contact caption refuses a prompt whose record names no contact instead of
# saying it guides while doing nothing. A diffusion run imported from the official fixture (no training).


@pytest.fixture(scope="module")
def diffusion_run(tmp_path_factory):
    from pathlib import Path

    import numpy as np

    from handx_jax.interop import official_diffusion as od

    fix = Path(__file__).parent / "fixtures" / "official_diffusion"
    root = tmp_path_factory.mktemp("contact")
    np.savez(root / "stats.npz", mean=np.zeros((42, 4), np.float32), std=np.ones((42, 4), np.float32))
    od.import_checkpoint(fix / "model.pt", root / "run", encoder=fix / "t5", heads=4, stats=root / "stats.npz")
    return root / "run"


@pytest.mark.parametrize("frames, says", [
    ("50:70", "frames '50:70' run past the clip's 60 frames (START:END within 0:60, END excluded)"),
    ("0:100000000000000000000000", "frames '0:100000000000000000000000' run past the clip's 60 frames (START:END "
                                   "within 0:60, END excluded)"),
    ("60:70", "frames '60:70' run past the clip's 60 frames (START:END within 0:60, END excluded)"),
    ("0:1e23", "frame '1e23' is not a non-negative integer"),
])
def test_contact_frames_past_the_clip_are_refused_not_cut(diffusion_run, tmp_path, capsys, frames, says):
    out = tmp_path / "gen.npz"
    spec = f"L.thumb-R.thumb@{frames}"
    rc = main(["generate", "--run", str(diffusion_run), *PROMPT, "--contact", spec, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == f"handx generate: error: sample.contact: contact {spec!r}: {says}", err
    assert not out.exists()


def test_contact_caption_on_a_record_without_contacts_says_so(diffusion_run, tmp_path, capsys):
    from diffusion_fixtures import make_dataset

    ds = make_dataset(tmp_path)
    out = tmp_path / "gen.npz"
    rc = main(["generate", "--run", str(diffusion_run), "--source", str(ds), "--clip", "synth-3-0000000-0060",
               "--contact", "caption", "--set", "sample.steps=2", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == (
        "handx generate: error: --contact caption: the prompt's record names no contact (no fingertip touch among the "
        "events its captions were written from), so there is nothing to guide toward; give a written spec such as "
        "L.thumb-R.thumb@20:40, or leave --contact off"), err
    assert not out.exists()


def test_contact_caption_says_how_many_prompts_of_a_batch_it_guides(capsys):
    from handx_jax.families.diffusion import guidance as Gd
    from handx_jax import metrics as M

    named = M.NamedContacts(*(np.asarray(v, np.int64) for v in ([0, 0, 2], [1, 2, 3], [0, 5, 9], [10, 20, 30])))
    Gd.check_named(named, 4)
    assert capsys.readouterr().err == ("handx: --contact caption guides 2 of the 4 prompts; the records of the other 2 "
                                       "name no contact\n")
    Gd.check_named(M.NamedContacts(*(v[:2] for v in (named.clip_E, named.channel_E, named.start_E, named.end_E))), 1)
    # every prompt guided (one prompt, two contacts): nothing to say
    assert capsys.readouterr().err == ""


# Issue 54: a family–task pair is refused the same way by every command, before the run is read, and a
# step family says what it is for (never an empty list); a flag the task does not read is refused.


def _run_of(tmp_path, family):
    run = tmp_path / family
    run.mkdir()
    (run / "config.json").write_text(f'{{"family": "{family}"}}')
    return run


STEP = ("family ghtt-pose does not do {what}: it is G-HTT's pose block P, the step a G-HTT run is trained from, "
        "which generates nothing; use the ghtt run trained on it")


@pytest.mark.parametrize("family, argv, says", [
    ("ghtt-pose", ["generate", *PROMPT], STEP.format(what="--task text2motion")),
    ("ghtt-pose", ["eval", "prediction", "--observed-frames", "16"], STEP.format(what="--task prediction")),
    ("ghtt-pose", ["eval", "recognition"], STEP.format(what="recognition")),
    ("ghtt", ["generate", *PROMPT], "family ghtt does not do --task text2motion; it does prediction, recognition"),
    ("diffusion", ["eval", "recognition"], "family diffusion does not do recognition; it does text2motion, inbetween, "
                                           "keyframes, wrist, reaction, long, prediction"),
    ("tokenizer", ["generate", "--task", "prediction", "--source", "x.npz"],
     "family tokenizer does not do --task prediction: it is the FSQ motion tokenizer of the AR family (paper §5.2), "
     "which generates nothing; use the ar run trained on it"),
])
def test_every_command_refuses_a_task_the_family_does_not_serve_alike(tmp_path, capsys, family, argv, says):
    run = _run_of(tmp_path, family)
    cmd = " ".join(argv[:2]) if argv[0] == "eval" else argv[0]
    rc = main([*argv[:2 if argv[0] == "eval" else 1], "--run", str(run), *argv[2 if argv[0] == "eval" else 1:],
               "--out", str(tmp_path / "out.json")])
    assert (rc, capsys.readouterr().err.strip()) == (2, f"handx {cmd}: error: {says}")
    assert not (tmp_path / "out.json").exists()


def test_observed_frames_without_the_prediction_task_is_refused(tmp_path, capsys):
    run = _run_of(tmp_path, "diffusion")
    out = tmp_path / "gen.npz"
    assert main(["generate", "--run", str(run), *PROMPT, "--observed-frames", "16", "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip() == (
        "handx generate: error: --observed-frames is read by --task prediction only (the observed start of each "
        "clip); --task text2motion would ignore it")
    assert not out.exists()


@pytest.mark.parametrize("limit", ["0", "-1"])
def test_generate_limit_below_one_is_refused(tmp_path, capsys, limit):
    run = _run_of(tmp_path, "diffusion")
    assert main(["generate", "--run", str(run), "--data", str(tmp_path), "--limit", limit,
                 "--out", str(tmp_path / "g.npz")]) == 2
    assert capsys.readouterr().err.strip() == (f"handx generate: error: --limit must be a whole number >= 1, got "
                                               f"{limit} (or left out: every clip)")
