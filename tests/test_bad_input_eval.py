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
from handx_jax.interop.handx_npz import HandXClip, write_handx_npz
from handx_jax.evaluation import align_generated
from handx_jax.evaluation.scoring import MAX_ABS_METRES, check_motion_range
from handx_jax.infra.errors import DataError


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
    from handx_jax.standard import assets as standard_assets

    _flip(assets_copy / "evaluator" / "params.msgpack")
    monkeypatch.setattr(standard_assets, "ASSETS", assets_copy)
    rc = main(["eval", "run", "--ground-truth", "--data", str(tmp_path / "ds"), "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == (f"handx: error: file {assets_copy / 'evaluator' / 'params.msgpack'}: standard evaluator "
                               "file corrupt: sha256 differs from card.json (reinstall the package)")
    assert not (tmp_path / "run").exists()


# Honest metrics (issue 43 item 5). R-Precision on fewer prompts than the block is computed on one block of
# all of them and says so (eval.json's rprec_block is the block used, with the requested one, the chance
# level and a warning; the printed header says that block). An evaluator with a NaN weight is refused on
# load, naming the parameter, before a reference cache could be written; the reference cache is written
# from finite values only, and a cache holding NaN is recomputed.


def test_r_precision_on_fewer_prompts_than_the_block_is_labelled_with_the_block_used(tmp_path):
    import json

    from handx_jax.evaluation import format_table, write_eval_json
    from handx_jax.evaluation.scoring import evaluate_embeddings_and_motion
    from handx_jax.metrics import MetricConfig

    rng = np.random.default_rng(0)
    text = rng.normal(size=(20, 8)).astype(np.float32)
    ev = SimpleNamespace(root=None, policy=SimpleNamespace(eval_level=0))
    gt = np.stack([_motion(i) for i in range(20)])
    cfg = MetricConfig(rprec_block=32, replications=2, bootstrap=20, diversity_pairs=10)
    res = evaluate_embeddings_and_motion(ev, text, gt[None], gt, cfg, gt_NxD=text, gen_GxNxD=text[None] + 0.01)
    m = res.meta
    assert (m["rprec_block"], m["rprec_block_requested"], m["rprec_chance"]) == (20, 32, [0.05, 0.1, 0.15])
    assert m["warnings"] == [
        "20 prompts, fewer than the R-Precision block of 32: R-Precision is computed on one block of 20 (top-1/2/3 "
        "chance 0.050/0.100/0.150, not 0.031/0.062/0.094), so it does not compare with block-32 scores; score at "
        "least 32 prompts, or pass --block 20 to ask for this block"]
    assert "R-Precision (block 20)" in format_table([("gen", res)], block=m["rprec_block"]).splitlines()[0]
    doc = json.loads(write_eval_json(tmp_path / "eval.json", res).read_text())
    assert doc["_meta"]["rprec_block"] == 20 and doc["_meta"]["rprec_block_requested"] == 32
    full = evaluate_embeddings_and_motion(ev, text, gt[None], gt, MetricConfig(rprec_block=16, replications=2,
                                                                               bootstrap=20, diversity_pairs=10),
                                          gt_NxD=text, gen_GxNxD=text[None])
    assert full.meta["rprec_block"] == 16 and "warnings" not in full.meta and "rprec_block_requested" not in full.meta


def test_the_eval_help_documents_the_block_policy(capsys):
    with pytest.raises(SystemExit):
        main(["eval", "run", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "With fewer prompts than the block, R-Precision is computed on one block of all of them" in out


@pytest.fixture(scope="module")
def nan_evaluator(tmp_path_factory):
    """The official evaluator imported, then one weight set to NaN in its params.msgpack (checksum rewritten,
    as a folder written by code that did not check would be)."""
    from flax import serialization

    from handx_jax.interop import official_evaluator as oe
    from handx_jax.infra.checksums import write_checksum

    fix = Path(__file__).parent / "fixtures" / "official_evaluator"
    ev = tmp_path_factory.mktemp("nan_ev") / "ev"
    oe.import_checkpoint(fix / "epoch=269.ckpt", ev, mean=fix / "mean_can_pos.npy", std=fix / "std_can_pos.npy",
                         encoder=fix / "t5")
    tree = serialization.msgpack_restore((ev / "params.msgpack").read_bytes())
    k = tree["params"]["motion_in"]["kernel"]
    k = np.array(k)
    k[2, 3] = np.nan
    tree["params"]["motion_in"]["kernel"] = k
    (ev / "params.msgpack").write_bytes(serialization.msgpack_serialize(tree))
    write_checksum(ev / "params.msgpack")
    return ev


def test_eval_run_with_a_nan_evaluator_is_refused_naming_the_parameter(nan_evaluator, tmp_path, capsys):
    g = write_handx_npz(tmp_path / "gen.npz", _clips(-1, 1.0))
    rc = main(["eval", "run", "--evaluator", str(nan_evaluator), "--generated", str(g), "--data",
               str(tmp_path / "ds"), "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == (f"handx: error: file {nan_evaluator / 'params.msgpack'}: parameter ['params']"
                               "['motion_in']['kernel'] holds 1 non-finite value(s) (NaN or inf) of 8064: the weights "
                               "are broken (a diverged run?) and every output would be NaN"), err
    assert not (nan_evaluator / "reference_cache").exists() and not (tmp_path / "run").exists()


def test_the_reference_cache_holds_only_finite_values_and_a_nan_one_is_recomputed(tmp_path, capsys):
    from handx_jax.evaluation import reference as R

    calls = []

    def embed(*a):
        calls.append(1)
        return np.ones((3, 4), np.float32)

    tok = SimpleNamespace(fingerprint="tok")
    ev = SimpleNamespace(root=tmp_path, fingerprint="ev", encoder=SimpleNamespace(fingerprint="enc", tokenizer=tok),
                         policy=SimpleNamespace(max_len=16, cache_dtype="float32", caption="sentinels"), batch_size=8,
                         cfg=SimpleNamespace(latent=4), embed_text=embed, embed_motion=lambda gt: embed())
    prompts = (["l"] * 3, ["r"] * 3, ["i"] * 3)
    gt = np.zeros((3, 60, 2, 21, 3), np.float32)
    first = R.reference_embeddings(ev, prompts, gt)
    assert first.status == "miss" and len(calls) == 2 and first.path.exists()
    assert R.reference_embeddings(ev, prompts, gt).status == "hit" and len(calls) == 2
    key = R.reference_key(ev, ["x"], gt)  # any key: a NaN file is never written
    assert not R.write_reference_cache(tmp_path / "nan.npz", key, np.full((3, 4), np.nan), np.ones((3, 4)))
    assert not (tmp_path / "nan.npz").exists()
    with np.load(first.path) as z:  # a cache file written with NaN (by older code, or damaged): recomputed
        d = dict(z)
    d["motion_NxD"][1, 2] = np.nan
    np.savez(first.path, **d)
    capsys.readouterr()
    again = R.reference_embeddings(ev, prompts, gt)
    assert again.status == "miss" and len(calls) == 4
    assert capsys.readouterr().err == f"handx: reference cache {first.path} holds non-finite values; recomputing it\n"
    assert R.reference_embeddings(ev, prompts, gt).status == "hit"
    ev.embed_motion = lambda gt: np.full((3, 4), np.nan, np.float32)  # an evaluator yielding NaN: refused, not cached
    with pytest.raises(DataError, match="the evaluator's embeddings of the reference ground-truth motion are not"):
        R.reference_embeddings(ev, prompts, gt, cache=tmp_path / "other")
    assert not (tmp_path / "other").exists()


def test_a_second_writer_of_one_evaluator_folder_is_refused(tmp_path, capsys):
    """``handx train evaluator --out EV`` holds EV's output lock (runlock.RunLock.for_output): here held by
    a live process that is not ours (a sleeping child: pid 1 would count as our parent when the test
    process is an orphan), so a second trainer is refused at once, naming the holder."""
    import json
    import socket
    import subprocess
    import time

    holder = subprocess.Popen(["sleep", "60"])
    try:
        (tmp_path / ".EV.lock").write_text(json.dumps({"pid": holder.pid, "host": socket.gethostname(),
                                                       "started": time.time(), "cmd": "handx train evaluator --out EV"}))
        (tmp_path / "data").mkdir()  # --data must exist to be parsed; the lock is refused before it is read
        rc = main(["train", "evaluator", "--data", str(tmp_path / "data"), "--encoder",
                   str(Path(__file__).parent / "fixtures" / "t5_tiny_gated"), "--out", str(tmp_path / "EV")])
    finally:
        holder.kill()
        holder.wait()
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1
    assert err.startswith(f"handx: error: {tmp_path / 'EV'} is in use by pid {holder.pid} on ")
    assert sorted(p.name for p in tmp_path.iterdir()) == [".EV.lock", "data"]  # nothing written, the lock kept


# Issue 54: a caption level the dataset does not have and a --limit below 1 are one line in both scoring
# commands, before any evaluator or run is read.


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    from diffusion_fixtures import make_dataset

    return make_dataset(tmp_path_factory.mktemp("levels"))


def _recognition_run(tmp_path):
    run = tmp_path / "ghtt"
    run.mkdir()
    (run / "config.json").write_text('{"family": "ghtt"}')  # the family is all that is read before the refusal
    return run


LEVEL = "--level must be in 0..4 or -5..-1 (-1 = the most detailed): the dataset {d} has 5 caption levels, got {v}"


@pytest.mark.parametrize("level", ["99", "-6"])
def test_a_caption_level_the_dataset_lacks_is_one_line(corpus, tmp_path, capsys, level):
    assert main(["eval", "prediction", "--baseline", "last-frame", "--data", str(corpus), "--observed-frames", "16",
                 "--level", level, "--evaluator", "none"]) == 2
    assert capsys.readouterr().err.strip() == "handx eval prediction: error: " + LEVEL.format(d=corpus, v=level)
    run = _recognition_run(tmp_path)
    assert main(["eval", "recognition", "--run", str(run), "--data", str(corpus), "--level", level]) == 2
    assert capsys.readouterr().err.strip() == "handx eval recognition: error: " + LEVEL.format(d=corpus, v=level)
    assert sorted(p.name for p in run.iterdir()) == ["config.json"]
    # eval run too, before anything is scored
    out = tmp_path / "scores"
    assert main(["eval", "run", "--ground-truth", "--data", str(corpus), "--level", level, "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip() == "handx: error: " + LEVEL.format(d=corpus, v=level)
    assert not out.exists()


@pytest.mark.parametrize("limit", ["0", "-1"])
def test_recognition_refuses_a_limit_below_one_like_prediction(tmp_path, capsys, limit):
    run = _recognition_run(tmp_path)
    says = f"--limit must be a whole number >= 1, got {limit} (or left out: every clip)"
    for cmd, extra in (("recognition", []), ("prediction", ["--observed-frames", "16"])):
        assert main(["eval", cmd, "--run", str(run), *extra, "--limit", limit]) == 2
        assert capsys.readouterr().err.strip() == f"handx eval {cmd}: error: {says}"


def test_an_evaluator_norm_stats_of_python_objects_is_one_line_naming_file_and_field(nan_evaluator, tmp_path,
                                                                                     capsys):
    """Issue 54: an evaluator's norm_stats.npz holding object arrays (pickles) is refused from the array's
    header, naming the file and the array; NumPy's own error suggested loading it with allow_pickle."""
    import shutil

    ev = tmp_path / "ev"
    shutil.copytree(nan_evaluator, ev)
    with np.load(ev / "norm_stats.npz") as z:
        arrays = dict(z)
    arrays["evaluator_std"] = np.array([{"x": 1}] * len(arrays["evaluator_std"]), dtype=object)
    np.savez(ev / "norm_stats.npz", **arrays)
    g = write_handx_npz(tmp_path / "gen.npz", _clips(-1, 1.0))
    rc = main(["eval", "run", "--evaluator", str(ev), "--generated", str(g), "--data", str(tmp_path / "ds"),
               "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith(f"handx: error: file {ev / 'norm_stats.npz'}, field 'evaluator_std': holds "
                                      "Python objects"), err
    assert "allow_pickle" not in err and "\n" not in err and not (tmp_path / "run").exists()
