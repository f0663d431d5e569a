"""AR family end to end on a 32-clip corpus: `handx train tokenizer`, `handx data tokens`, `handx train ar`,
`handx generate` (official .npz layout, text2motion and prediction), `handx params ar` (Table C)."""

import json

import numpy as np
import pytest

from handx_jax.cli import main
from handx_jax.infra.readers import read_jsonl
from tests.diffusion_fixtures import ENCODER, make_dataset

LOOP = ["--set", "train.batch_size=8", "--set", "train.log_every=2", "--set", "train.ckpt_every=4",
        "--set", "train.wandb=disabled", "--set", "train.optim.warmup_steps=0", "--set", "train.optim.lr=2e-3"]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("ar")
    data = make_dataset(root, joined=True)
    tok, run = root / "tok", root / "lm"
    # One residual block per stack and a one-layer LM: these tests check the commands' plumbing (records, logs,
    # caches, layouts, refusals), not model quality, and the programs of the 3-block tokenizer and the 2-layer LM
    # cost ~10 CPU-s more to trace and compile (test_fsq.py and test_prefix_lm.py check those models). 20-frame
    # windows: the tokenizer's initial state and train step are then the programs of test_fsq.py's fit (same
    # model, loss, optimiser and batch shape), compiled once in a session for both files.
    assert main(["train", "tokenizer", "--data", str(data), "--set", "model.codebook=256", "--set", "model.depth=1",
                 "--set", "data.window=20", "--preset", "tiny", "--quiet",
                 "--set", "train.steps=4", "--set", "train.eval_every=2", *LOOP, "--out", str(tok)]) == 0
    assert main(["data", "tokens", "--tokenizer", str(tok), "--data", str(data)]) == 0
    assert main(["train", "ar", "--data", str(data), "--encoder", str(ENCODER), "--tokenizer", str(tok),
                 "--preset", "tiny", "--quiet", "--set", "train.steps=8", *LOOP, "--set", "train.ckpt_every=8",
                 "--set", "model.layers=1", "--set", "model.dim=32", "--set", "model.heads=2",  # test_ar_sweep's 1L-32
                 "--out", str(run)]) == 0  # one checkpoint: an orbax save costs ~1 CPU-s
    return data, tok, run


def test_tokenizer_run_records_codebook_and_logs_validation(built):
    _, tok, _ = built
    cfg = json.loads((tok / "config.json").read_text())
    assert (cfg["family"], cfg["codebook"], cfg["nb_code"], cfg["levels"]) == ("tokenizer", 256, 240, [8, 6, 5])
    ev = [r for r in read_jsonl(tok / "metrics.jsonl") if "eval/mpjpe_mm" in r]
    assert [r["step"] for r in ev] == [0, 2, 4]  # the loop also evaluates the initial weights
    for r in ev:
        assert 0 < r["eval/mpjpe_mm"] < 1e4 and 0 < r["eval/usage"] <= 1 and 1 <= r["eval/perplexity"] <= 240


def test_token_cache_holds_every_clip_and_matches_the_encoder(built):
    from handx_jax.dataset.format import Dataset
    from handx_jax.families import tokenizer as T

    data, tok, _ = built
    cache = T.open_token_cache(data, tok)
    ds = Dataset.open(data)
    assert cache.codes.shape == (len(ds), 30) and cache.codes.min() >= 0 and cache.codes.max() < 240
    run = T.load(tok)
    # every clip, as `handx data tokens` encoded them: the same encoding program (one batch of 32)
    np.testing.assert_array_equal(run.encode_clips(np.asarray(ds.motion)), cache.codes)
    assert cache.meta["tokenizer_fingerprint"] == run.fingerprint and cache.meta["nb_code"] == 240


def test_lm_run_records_tokenizer_provenance_and_vocabulary(built):
    _, tok, run = built
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["family"] == "ar" and cfg["model"]["nb_code"] == 240 and (cfg["codebook"], cfg["nb_code"]) == (256, 240)
    assert cfg["tokenizer"]["tokenizer_path"] == str(tok.absolute())
    assert cfg["text_cache"]["fields"] == "joined" and cfg["flops_per_sample"] > 0
    # Held-out token NLL on the val split: at init (step 0) ≈ uniform over 240 codes + END, at the end (step 8)
    # below it; training's loss falls too (the first logged row is step 2's batch, after one update).
    ev = [r for r in read_jsonl(run / "metrics.jsonl") if "eval/nll" in r]
    assert [r["step"] for r in ev] == [0, 8]
    assert ev[0]["eval/nll"] == pytest.approx(np.log(241), rel=0.15) and ev[1]["eval/nll"] < ev[0]["eval/nll"]
    assert 0 <= ev[1]["eval/acc"] <= 1
    rows = [r for r in read_jsonl(run / "metrics.jsonl") if "loss" in r]
    assert rows[-1]["loss"] < rows[0]["loss"]


def test_generate_writes_the_official_layout(built, tmp_path):
    from handx_jax.interop.handx_npz import read_handx_npz

    data, _, run = built
    out = tmp_path / "gen.npz"
    assert main(["generate", "--run", str(run), "--data", str(data), "--split", "test", "--limit", "3",
                 "--samples", "2", "--temperature", "1.0", "--top-k", "20", "--encoder", str(ENCODER),
                 "--out", str(out)]) == 0
    clips = read_handx_npz(out)
    assert len(clips) == 6
    for c in clips:
        assert c.motion.shape == (60, 2, 21, 3) and np.all(np.isfinite(c.motion))
        np.testing.assert_allclose(c.motion[0, 1, 0], 0.0, atol=1e-6)  # right wrist of frame 0 at the origin


def test_prediction_keeps_the_observed_start(built, tmp_path):
    from handx_jax.dataset.format import Dataset
    from handx_jax.families import load_run
    from handx_jax.families.ar import GenerateOptions
    from handx_jax.generation import split_prompts

    data, _, run_dir = built
    ds = Dataset.open(data)
    run = load_run(run_dir)
    # The clip, sample count and observed frames of test_eval_prediction_scores_an_ar_run below: the same
    # decoding program (2 rows, 10 prefilled tokens), compiled once for the two tests.
    _, prompts, (src,) = split_prompts(ds, "test", 1)
    j = run.generate(prompts, GenerateOptions(observed_frames=20), samples=2, task="prediction", sources=[src])
    assert j.shape == (1, 2, 60, 2, 21, 3)
    # The observed frames come back as given (issue 41: they were the tokenizer's reconstruction, up to
    # 399 mm off), and the continuation starts where they end: its first frame's wrists are where the
    # last observed frame's were moved by the decoded step, not a tokenizer's jump away.
    assert 1000 * np.abs(j[0, :, :20] - src[:20]).max() < 1.0
    assert 1000 * np.linalg.norm(j[0, :, 20, :, 0] - src[19, :, 0], axis=-1).max() < 60.0
    # The first 10 tokens are the tokenizer's codes of the observed 20 frames (prefilled, not sampled).
    obs = run.tokenizer.encode_clips(src[None, :20])
    assert obs.shape == (1, 10)


@pytest.mark.parametrize("argv,expected", [
    (["--preset", "8L-512", "--codebook", "2048"], 29_633_024),
    (["--layers", "12", "--dim", "768", "--heads", "12", "--codebook", "4096"], 92_266_752),
    (["--preset", "16L-1024", "--codebook", "4096"], 215_305_216)])
def test_params_command_reproduces_table_c(argv, expected, capsys):
    assert main(["params", "ar", *argv, "--text-dim", "768", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["params"] == expected
    assert set(out) >= {"params", "params_non_embedding", "flops_per_sample", "text_flops_per_sample"}
    assert out["flops_per_sample"] > 2 * out["params_non_embedding"] * 31  # at least 2·N per motion slot


def test_bad_generate_input_against_a_trained_run(built, tmp_path, capsys):
    """Issue 31: a typed prompt longer than the joined prefix's window is refused naming the field (it was
    cut silently, so the other two prompts had no effect), before any decoding."""
    _, _, run = built
    out = tmp_path / "gen.npz"
    long = "the left hand taps its index finger on the thumb " * 2200  # ~108k characters
    rc = main(["generate", "--run", str(run), "--left", long, "--right", "the right hand rests", "--interaction",
               "apart", "--encoder", str(ENCODER), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("handx generate: error: --left is ") and f"({len(long):,} characters)" in err
    assert "the three prompts joined are" in err and "more than the 128 the run's text encoder reads" in err
    assert "\n" not in err and not out.exists()
    # Typed prompts only: the dataset's own captions (batch mode) are cut at the window as in training
    # (test_generate_writes_the_official_layout: their joined prefixes are longer than 128 tokens).


@pytest.mark.parametrize("damage", ["outside"])  # truncated: tests/test_bad_input_ar_data.py
def test_a_bad_token_cache_is_refused_before_training_with_no_run_folder(built, tmp_path, capsys, damage):
    """Issue 31: codes outside the codebook trained to a NaN loss at step 5 and left a run folder behind; a
    truncated cache said "Failed to read all data for array" without the file. Both are refused when the
    cache is opened, before any step, naming codes.npy; the run folder is not created."""
    import shutil

    data, tok, _ = built
    copy = tmp_path / "ds"
    shutil.copytree(data, copy)
    (codes_path,) = (copy / "token_cache").glob("*/codes.npy")
    codes = np.load(codes_path)
    if damage == "outside":
        codes[4, 9] = 240 + 17  # the tokenizer's real codebook has 240 codes
        np.save(codes_path, codes)
    else:
        codes_path.write_bytes(codes_path.read_bytes()[:-100])
    out = tmp_path / "lm"
    rc = main(["train", "ar", "--data", str(copy), "--encoder", str(ENCODER), "--tokenizer", str(tok),
               "--preset", "tiny", "--quiet", "--set", "train.steps=8", *LOOP, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith(f"handx train ar: error: file {codes_path}: "), err
    words = ("1 codes outside the codebook [0, 240)", "the first 257 at clip 4, token 9") if damage == "outside" \
        else ("unreadable or truncated token cache",)
    assert all(w in err for w in words) and "\n" not in err
    assert not out.exists()


def test_eval_prediction_scores_an_ar_run(built, tmp_path):
    data, _, run = built
    out = tmp_path / "pred.json"
    assert main(["eval", "prediction", "--run", str(run), "--observed-frames", "20", "--limit", "1", "--samples", "2",
                 "--temperature", "1.0", "--encoder", str(ENCODER), "--evaluator", "none", "--json",
                 "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["_meta"]["family"] == "ar" and res["_meta"]["horizons"] == ["21-36", "37-52", "53-60"]
    assert res["_meta"]["generation"].startswith("T=1.0")  # the family's own flag reached its options
    # The observed frames come back exactly (stitched: families.ar.stitch); sampled continuations differ.
    assert res["observed"]["max_joint_error_mm"] < 1.0 and res["predicted"]["apd_both"] > 0


def test_stitch_keeps_the_observation_and_joins_the_continuation_at_its_last_frame():
    """families.ar.stitch on known arrays: the observed frames are the source's; every predicted frame's
    wrists move by the source's minus the decoded wrist at the last observed frame (for good); the pose
    relative to the wrist starts at the source's (frame f − 1's offset, weight frames/(frames + 1) at frame f)
    and is the decoded one's own from ``frames`` frames after the observation; 0 frames: no pose pull."""
    from handx_jax.families.ar import stitch

    rng = np.random.default_rng(0)
    dec = rng.normal(0, 0.05, (3, 60, 2, 21, 3)).astype(np.float32)
    src = rng.normal(0, 0.05, (3, 60, 2, 21, 3)).astype(np.float32)
    f, L = 16, 8
    out = stitch(dec, src, f, L)
    np.testing.assert_array_equal(out[:, :f], src[:, :f])
    rel = lambda x: x - x[..., :1, :]  # noqa: E731
    wrist_off = src[:, f - 1, :, :1] - dec[:, f - 1, :, :1]
    np.testing.assert_allclose(out[:, f:, :, :1], dec[:, f:, :, :1] + wrist_off[:, None], atol=1e-6)
    pose_off = rel(src[:, f - 1]) - rel(dec[:, f - 1])
    for k in range(1, 60 - f + 1):  # frame f + k − 1
        w = max(0.0, 1 - k / (L + 1))
        np.testing.assert_allclose(rel(out[:, f + k - 1]), rel(dec[:, f + k - 1]) + w * pose_off, atol=1e-6)
    np.testing.assert_allclose(rel(out[:, f + L:]), rel(dec[:, f + L:]), atol=1e-6)
    np.testing.assert_allclose(rel(stitch(dec, src, f, 0)[:, f:]), rel(dec[:, f:]), atol=1e-6)
    np.testing.assert_array_equal(stitch(dec, src, f, -1), stitch(dec, src, f, 60 - f))  # the rest of the clip
