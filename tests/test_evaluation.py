"""Evaluator pipeline: checkpoint round trip, fingerprint refusals, generated-file layout, CLI JSON keys,
the Ground Truth row, and a few training steps lowering InfoNCE. Tiny fixtures, seconds on CPU."""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from analysis.schema import METRICS
from handx_jax.dataset.format import Dataset
from handx_jax.interop.handx_npz import HandXClip, read_handx_npz, write_handx_npz
from handx_jax.evaluation import (JOINED, REFERENCE_CACHE_DIR, TextPolicy, TrainingData, align_generated,
                                  evaluate_generated, evaluate_ground_truth, evaluator_stats, load_evaluator,
                                  reference_embeddings, train_evaluator, write_reference_cache)
from handx_jax.infra.errors import DataError
from handx_jax.metrics import MetricConfig

ENCODER = Path(__file__).parent / "fixtures" / "t5_tiny_gated"

TINY = ("train.steps=40", "train.batch_size=8", "train.optim.lr=1e-3", "train.optim.warmup_steps=0",
        "train.log_every=5", "train.wandb=disabled", "text.max_len=64", "text.train_levels=none", "text.eval_level=0",
        "final_eval=false")


def tiny_evaluator(data, *overrides):
    from handx_jax.evaluation import make_evaluator_config

    return make_evaluator_config("tiny", TINY + overrides, data=str(data), encoder=str(ENCODER))


CFG = MetricConfig(replications=4, rprec_block=4)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    from handx_jax.dataset.build import BuildConfig, build_corpus

    root = tmp_path_factory.mktemp("evaluation")
    data = build_corpus(root / "ds", BuildConfig(clips=32, seed=5, workers=1, val_fraction=0.2, test_fraction=0.25),
                        progress=False)
    E = train_evaluator(root / "E", tiny_evaluator(data, *TRAINED), log=lambda s: None)
    return root, data, E


# Enough for the tiny evaluator to match its training pairs well above chance on the rigid-hand corpus. Measured
# on the train split at block 10 (top-1 / top-3 against the 3-sigma bounds 0.385 / 0.735): 600 steps at lr 1e-3
# 0.725 / 0.850 (joints) and 0.850 / 1.000 (hand_frames); 300 steps at 3e-3 0.725 / 0.950 and 0.625 / 1.000, for
# ~10 s less CPU per training; 200 steps at 3e-3 is too close (hand_frames top-3 0.750).
TRAIN_STEPS = 300
TRAINED = (f"train.steps={TRAIN_STEPS}", "train.optim.lr=3e-3")


def assert_beats_chance(res, block: int):
    """R-Precision top-1 and top-3 above chance (k / block) by 3 binomial standard deviations of a hit
    rate over the n prompts scored per replication: √(p(1−p)/n)."""
    n = res.meta["prompts"] // min(block, res.meta["prompts"]) * min(block, res.meta["prompts"])
    for k in (1, 3):
        p = k / min(block, res.meta["prompts"])
        got = res.metrics[f"rprec_top{k}"][0]
        assert got > p + 3 * np.sqrt(p * (1 - p) / n), (k, got, p, n)


def test_checkpoint_round_trip_and_versioned_meta(setup):
    root, data, E = setup
    meta = json.loads((E / "evaluator.json").read_text())
    assert meta["format"] == "handx-jax-evaluator" and meta["format_version"] == 1
    ds = Dataset.open(data)
    assert meta["dataset"]["fingerprint"] == ds.fingerprint
    assert meta["text"]["max_len"] == 64 and meta["text"]["train_levels"] == [0, 1, 2, 3, 4]
    for key in ("path", "fingerprint", "tokenizer_fingerprint"):
        assert meta["encoder"][key]
    ev = load_evaluator(E)
    np.testing.assert_array_equal(ev.stats.mean, ds.stats["evaluator_mean"])
    clips = ds.split("test")
    m1, t1 = ev.embed_motion(ds.motion[clips]), ev.embed_text(*ev.captions(ds, clips))
    assert m1.shape == (len(clips), 32) and t1.shape == m1.shape
    ev2 = load_evaluator(E)
    np.testing.assert_array_equal(ev2.embed_motion(ds.motion[clips]), m1)
    np.testing.assert_array_equal(ev2.embed_text(*ev2.captions(ds, clips)), t1)
    # batching does not change an embedding
    np.testing.assert_allclose(ev.embed_motion(ds.motion[clips[:1]]), m1[:1], atol=1e-5)
    # on-the-fly text encoding reproduces the cached features the evaluator was trained on
    from handx_jax.text.cache import open_cache

    cache = open_cache(data, ENCODER, joined=True, max_len=64)
    td = TrainingData(ds, cache, evaluator_stats(ds), clips, [0], 0)
    b = td.batch(np.arange(len(clips)), np.zeros(len(clips), int))
    import jax

    from handx_jax.models.evaluator import Evaluator

    # jitted: eagerly, each op of the text branch is its own dispatch and compile
    encode_text = jax.jit(lambda p, h, m: Evaluator(ev.cfg).apply(p, h, m, method=Evaluator.encode_text)[0])
    mu_t = encode_text(ev.params, b["text"], b["text_mask"])
    np.testing.assert_allclose(np.asarray(mu_t), t1, atol=2e-3)
    assert cache.texts[cache.row(clips[0], JOINED, 0)].startswith("<extra_id_0> ")


def test_refuses_other_dataset_and_changed_encoder(setup, tmp_path):
    root, data, E = setup
    from handx_jax.dataset.format import write_dataset

    ds = Dataset.open(data)
    other = write_dataset(tmp_path / "other", np.asarray(ds.motion[:8]) * 1.01, ds.texts[:8],
                          splits={"train": list(range(6)), "val": [], "test": [6, 7]})
    ev = load_evaluator(E)
    with pytest.raises(DataError, match="dataset fingerprint mismatch: this evaluator was trained on dataset"):
        evaluate_ground_truth(ev, Dataset.open(other), CFG)
    # an encoder folder whose weights changed is refused at load time
    enc = shutil.copytree(ENCODER, tmp_path / "enc")
    from safetensors.numpy import load_file, save_file

    w = load_file(str(enc / "model.safetensors"))
    k = sorted(w)[0]
    w[k] = w[k] + 1e-3
    save_file(w, str(enc / "model.safetensors"), metadata={"format": "pt"})
    with pytest.raises(DataError, match="encoder fingerprint mismatch"):
        load_evaluator(E, encoder=enc)
    # an unfinished or foreign folder is refused with a clear message
    with pytest.raises(DataError, match="not an evaluator checkpoint"):
        load_evaluator(tmp_path)


def test_npz_optional_fields_round_trip(tmp_path):
    m = np.zeros((60, 2, 21, 3), np.float32)
    clips = [HandXClip("0", m, ["l"], ["r"], ["i"], source_clip="synth-7", group=2),
             HandXClip("1", m + 1, ["l"], ["r"], ["i"])]
    p = write_handx_npz(tmp_path / "g.npz", clips)
    back = read_handx_npz(p)
    assert back[0].source_clip == "synth-7" and back[0].group == 2
    assert back[1].source_clip is None and back[1].group is None
    raw = np.load(p, allow_pickle=True)["0"].item()  # what the official loaders see: extra keys only
    assert raw["source_clip"] == "synth-7" and raw["group"] == 2 and raw["motion"].shape == (60, 2, 21, 3)
    bad = [HandXClip("0", m, ["l"], ["r"], ["i"], group=-1)]
    with pytest.raises(DataError, match="group"):
        write_handx_npz(tmp_path / "bad.npz", bad)


def _generated(ds, groups=2, noise=0.0, with_source=True):
    clips = ds.split("test")
    rng = np.random.default_rng(0)
    out = []
    for g in range(groups):
        for c in clips:
            t = ds.texts[c]
            out.append(HandXClip(str(len(out)), ds.motion[c] + noise * rng.normal(size=(60, 2, 21, 3)),
                                 t["left"], t["right"], t["interaction"],
                                 source_clip=t["id"] if with_source else None, group=g if with_source else None))
    return out


def test_ground_truth_row_and_self_evaluation(setup):
    root, data, E = setup
    ds = Dataset.open(data)
    ev = load_evaluator(E)
    gt = evaluate_ground_truth(ev, ds, CFG)
    assert gt.metrics["fid"][0] == pytest.approx(0.0, abs=1e-4)
    assert gt.metrics["mpjpe"][0] == 0.0
    for k in ("contact_f1_intra", "contact_f1_inter"):
        assert gt.metrics[k][0] in (0.0, pytest.approx(1.0, abs=1e-6))
    assert "multimodality" not in gt.metrics
    # the trained evaluator matches its training pairs far above chance (one block of all 10 clips)
    assert_beats_chance(evaluate_ground_truth(ev, ds, MetricConfig(replications=4, rprec_block=10), split="train",
                                              cache=False), block=10)
    # the dataset evaluated against itself as a generation of 2 groups: FID 0, R-Precision equal to GT's
    same = evaluate_generated(ev, _generated(ds), ds, CFG)
    assert same.metrics["fid"][0] == pytest.approx(0.0, abs=1e-4)
    assert same.metrics["multimodality"][0] == pytest.approx(0.0, abs=1e-5)
    assert same.metrics["mpjpe"][0] == 0.0
    # entries without source_clip are matched by order to the test split
    by_order = evaluate_generated(ev, _generated(ds, with_source=False), ds, CFG)
    assert by_order.metrics["rprec_top1"] == same.metrics["rprec_top1"]
    noisy = evaluate_generated(ev, _generated(ds, noise=0.02), ds, CFG)
    # isotropic N(0, σ²) noise on every coordinate: E‖n‖ = σ·√(8/π) = 31.9 mm for σ = 2 cm
    assert noisy.metrics["fid"][0] > 0 and noisy.metrics["mpjpe"][0] == pytest.approx(20 * np.sqrt(8 / np.pi), rel=0.02)
    assert noisy.meta["ci_method"]["fid"] == "groups" and gt.meta["ci_method"]["fid"] == "bootstrap_prompts"


def _evaluator_copy(E, dst):
    """The evaluator folder without its training run and caches: each test sees its own reference cache."""
    return shutil.copytree(E, dst, ignore=shutil.ignore_patterns("checkpoints", "wandb", REFERENCE_CACHE_DIR))


def test_reference_cache_is_reused_and_changes_no_value(setup, tmp_path):
    root, data, E = setup
    ds = Dataset.open(data)
    ev = load_evaluator(_evaluator_copy(E, tmp_path / "E"))
    folder = ev.root / REFERENCE_CACHE_DIR
    off = evaluate_ground_truth(ev, ds, CFG, cache=False)
    assert off.meta["reference_cache"] == "off" and not folder.exists()
    first = evaluate_ground_truth(ev, ds, CFG)
    assert first.meta["reference_cache"] == "miss" and len(list(folder.glob("*.npz"))) == 1
    again = evaluate_ground_truth(load_evaluator(ev.root), ds, CFG)  # as a later `handx eval run` would
    assert again.meta["reference_cache"] == "hit"
    assert off.flat() == first.flat() == again.flat()
    # generations of the same prompts reuse the GT row's file, with the same numbers as without it
    gen = _generated(ds, noise=0.01)
    cached, uncached = evaluate_generated(ev, gen, ds, CFG), evaluate_generated(ev, gen, ds, CFG, cache=False)
    assert cached.meta["reference_cache"] == "hit" and cached.flat() == uncached.flat()
    assert len(list(folder.glob("*.npz"))) == 1


def test_reference_cache_key_separates_dataset_level_params_and_clips(setup, tmp_path):
    import jax

    root, data, E = setup
    ds = Dataset.open(data)
    clips = np.sort(ds.split("test"))
    gt = np.asarray(ds.motion[clips], np.float32)
    prov = {"dataset": ds.fingerprint, "eval_level": 0}

    def ref(ev, sel=slice(None), **provenance):
        prompts = tuple(p[sel] for p in ev.captions(ds, clips))
        return reference_embeddings(ev, prompts, gt[sel], provenance={**prov, **provenance}, cache=tmp_path)

    ev = load_evaluator(E)
    base = ref(ev)
    hit = ref(load_evaluator(E))
    assert (base.status, hit.status) == ("miss", "hit") and hit.path == base.path
    np.testing.assert_array_equal(hit.text_NxD, base.text_NxD)
    np.testing.assert_array_equal(hit.motion_NxD, base.motion_NxD)
    stored = json.loads(str(np.load(base.path)["key"]))
    assert stored["provenance"] == prov and stored["evaluator"] == ev.fingerprint

    assert ref(ev, dataset="another-dataset").status == "miss"
    assert ref(ev, sel=slice(1, None)).status == "miss"  # a subset of the clips
    level = load_evaluator(E)
    level.policy = dataclasses.replace(level.policy, eval_level=2)
    by_level = ref(level, eval_level=2)
    assert by_level.status == "miss" and not np.array_equal(by_level.text_NxD, base.text_NxD)
    tuned = dataclasses.replace(ev, params=jax.tree_util.tree_map(lambda p: p * 1.01, ev.params))
    by_params = ref(tuned)
    assert by_params.status == "miss" and not np.array_equal(by_params.motion_NxD, base.motion_NxD)
    assert ref(dataclasses.replace(ev, batch_size=8)).status == "miss"  # chunking moves float rounding
    assert len(list(tmp_path.glob("*.npz"))) == 6


def test_reference_cache_corrupt_stale_or_unwritable_files(setup, tmp_path):
    root, data, E = setup
    ds = Dataset.open(data)
    ev = load_evaluator(E)
    clips = np.sort(ds.split("test"))
    gt = np.asarray(ds.motion[clips], np.float32)

    def ref(cache=tmp_path):
        return reference_embeddings(ev, ev.captions(ds, clips), gt, provenance={"dataset": ds.fingerprint},
                                    cache=cache)

    base = ref()
    good = base.path.read_bytes()
    for bad in (b"not an npz", good[: len(good) // 2]):  # garbage, a truncated write
        base.path.write_bytes(bad)
        again = ref()
        assert again.status == "miss" and again.path.read_bytes() == good and ref().status == "hit"
        np.testing.assert_array_equal(again.text_NxD, base.text_NxD)
    # stale: a readable file under this name whose key is another one (e.g. another code version)
    key = json.loads(str(np.load(base.path)["key"]))
    write_reference_cache(base.path, {**key, "version": -1}, base.text_NxD + 1, base.motion_NxD)
    again = ref()
    assert again.status == "miss" and ref().status == "hit"
    np.testing.assert_array_equal(again.text_NxD, base.text_NxD)
    # a folder that cannot be written (read-only evaluator): computed, reported, not an error
    (tmp_path / "file").write_text("x")
    blocked = ref(cache=tmp_path / "file" / "cache")
    assert blocked.status == "unwritable"
    np.testing.assert_array_equal(blocked.motion_NxD, base.motion_NxD)


def test_misaligned_generations_are_refused(setup):
    root, data, E = setup
    ds = Dataset.open(data)
    gen = _generated(ds, groups=2)
    with pytest.raises(DataError, match="group 1 lacks 1"):
        align_generated(gen[:-1], ds)
    wrong = gen[0]
    gen[0] = HandXClip(wrong.key, wrong.motion, ["another prompt"], wrong.right, wrong.interaction,
                       source_clip=wrong.source_clip, group=0)
    with pytest.raises(DataError, match="captions differ"):
        align_generated(gen, ds)


def test_cli_run_json_keys_and_eval_json(setup, tmp_path, capsys):
    from analysis.schema import row_from_run_dir  # noqa: F401  (the contract eval.json must satisfy)
    from handx_jax.cli import main

    root, data, E = setup
    ds = Dataset.open(data)
    g = write_handx_npz(tmp_path / "gen.npz", _generated(ds, groups=2, noise=0.01))
    rc = main(["eval", "run", "--evaluator", str(E), "--generated", str(g), "--data", str(data), "--json",
               "--replications", "3", "--block", "4", "--out", str(tmp_path / "run")])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    base = {k for k in out if not k.endswith("_ci")}
    assert base == set(METRICS)
    assert all(f"{k}_ci" in out for k in base)
    ev_json = json.loads((tmp_path / "run" / "eval.json").read_text())
    assert ev_json["_meta"]["groups"] == 2
    # which evaluator scored, from its files: a copy elsewhere is the same evaluator, other weights are not
    from handx_jax.evaluation import evaluator_id

    assert ev_json["_meta"]["evaluator_id"] == evaluator_id(E) and "evaluator_name" not in ev_json["_meta"]
    shutil.copytree(E, tmp_path / "E_copy", ignore=shutil.ignore_patterns("reference_cache", "checkpoints"))
    assert evaluator_id(tmp_path / "E_copy") == evaluator_id(E)
    p = tmp_path / "E_copy" / "params.msgpack"
    p.write_bytes(p.read_bytes()[:-1] + bytes([p.read_bytes()[-1] ^ 1]))
    assert evaluator_id(tmp_path / "E_copy") != evaluator_id(E)
    between = {"multimodality", "apd_left", "apd_right"}  # one value per prompt, not per group
    assert ev_json["_meta"]["ci_method"] == {k: ("bootstrap_prompts" if k in between else "groups") for k in base}
    from analysis.schema.run_folder import _eval_values

    assert set(_eval_values(ev_json, tmp_path / "run" / "eval.json")) == set(out)
    rc = main(["eval", "run", "--evaluator", str(E), "--ground-truth", "--data", str(data),
               "--replications", "3", "--block", "4"])
    text = capsys.readouterr().out
    assert rc == 0 and "Ground Truth" in text and "Top-1" in text and "FID" in text
    rc = main(["eval", "run", "--evaluator", str(E), "--ground-truth", "--data", str(tmp_path / "nope")])
    assert rc == 2
    # --level scores against another caption level (same numbers as the API at that level);
    # --no-reference-cache neither reads nor writes the cache and changes no value.
    ev = load_evaluator(E)
    ev.policy = dataclasses.replace(ev.policy, eval_level=-1)
    want = evaluate_ground_truth(ev, ds, MetricConfig(rprec_block=4, replications=3), cache=False).flat()
    default = evaluate_ground_truth(load_evaluator(E), ds, MetricConfig(rprec_block=4, replications=3)).flat()
    assert abs(want["mm_dist"] - default["mm_dist"]) > 1e-4  # the level really changes the captions
    for extra in ([], ["--no-reference-cache"]):
        rc = main(["eval", "run", "--evaluator", str(E), "--ground-truth", "--data", str(data), "--json",
                   "--replications", "3", "--block", "4", "--level", "-1", *extra])
        assert rc == 0
        assert json.loads(capsys.readouterr().out) == pytest.approx(want, abs=1e-6)


def infonce_init_and_trained(ev, batch) -> tuple[float, float]:
    """InfoNCE on a fixed batch (deterministic forward) of the evaluator's initial parameters (train seed 42,
    fold_in 0, as train_evaluator draws them) and of its trained ones, in one compiled program: run
    eagerly, every op of the init and of the two forwards is its own dispatch and compile (~5 CPU-s)."""
    import jax

    from handx_jax.evaluation import _init_params
    from handx_jax.models.evaluator import Evaluator, evaluator_loss

    model = Evaluator(ev.cfg)

    @jax.jit
    def both(key, params, batch):
        infonce = lambda p: evaluator_loss(model, p, batch, jax.random.PRNGKey(0), False)[1]["infonce"]  # noqa: E731
        return infonce(_init_params(ev.cfg, 64, key)), infonce(params)

    before, after = both(jax.random.fold_in(jax.random.PRNGKey(42), 0), ev.params, batch)
    return float(before), float(after)


def test_training_lowers_infonce_and_refuses_overwrite(setup):
    from handx_jax.text.cache import open_cache

    root, data, E = setup  # trained with TRAINED from the init below (train seed 42, fold_in 0)
    ev = load_evaluator(E)
    ds = Dataset.open(data)
    cache = open_cache(data, ENCODER, joined=True, max_len=64)
    td = TrainingData(ds, cache, evaluator_stats(ds), ds.split("train"), [0], 0)
    batch = td.batch(np.arange(len(td)), np.zeros(len(td), int))  # a fixed batch, deterministic forward
    before, after = infonce_init_and_trained(ev, batch)
    assert after < before - 0.5, (before, after)
    with pytest.raises(FileExistsError, match="already holds a trained evaluator"):
        train_evaluator(E, tiny_evaluator(data), log=lambda s: None)


def test_resuming_with_a_different_config_is_refused(setup, tmp_path, monkeypatch):
    """The evaluator trains through handx_jax.train, which refuses to resume a folder with another config.
    A training run loads (and hashes) the T5 encoder once, for the text cache and the checkpoint alike."""
    from handx_jax.text import hf

    loads = []
    real = hf.load_hf_t5_encoder
    monkeypatch.setattr(hf, "load_hf_t5_encoder", lambda folder: loads.append(folder) or real(folder))
    root, data, _ = setup
    E = tmp_path / "E"
    train_evaluator(E, tiny_evaluator(data), stop_at=10, log=lambda s: None)  # "killed" before the end
    assert len(loads) == 1
    assert (E / "config.json").exists() and not (E / "evaluator.json").exists()
    with pytest.raises(DataError, match="different configuration"):
        train_evaluator(E, tiny_evaluator(data, "train.optim.lr=2e-3"), log=lambda s: None)
    with pytest.raises(ValueError, match="did you mean 'train.optim.lr'"):
        tiny_evaluator(data, "train.optim.lrr=1")
    # The evaluator is a trainable, not a model family: its config.json says "trainable". A run written
    # before issue 42 said "family": "evaluator"; it resumes, and its config.json is rewritten.
    doc = json.loads((E / "config.json").read_text())
    assert doc["trainable"] == "evaluator" and "family" not in doc
    doc["family"] = doc.pop("trainable")
    (E / "config.json").write_text(json.dumps(doc))
    train_evaluator(E, tiny_evaluator(data), log=lambda s: None)
    doc = json.loads((E / "config.json").read_text())
    assert doc["trainable"] == "evaluator" and "family" not in doc and (E / "evaluator.json").exists()


def test_item_levels_are_a_function_of_the_batch(setup):
    root, data, _ = setup
    ds = Dataset.open(data)
    from handx_jax.text.cache import open_cache

    cache = open_cache(data, ENCODER, joined=True, max_len=64)
    td = TrainingData(ds, cache, evaluator_stats(ds), ds.split("train"), [0, 2, 4], seed=3)
    idx = np.arange(8)
    a, b = td.item_levels(idx), td.item_levels(idx)
    np.testing.assert_array_equal(a, b)
    assert set(td.item_levels(np.arange(len(td)))) <= {0, 2, 4}
    batch = td.batch(idx)
    assert batch["motion"].shape == (8, 60, 126) and batch["text"].shape[:2] == batch["text_mask"].shape
    assert batch["text"].shape[1] % 16 == 0 or batch["text"].shape[1] == cache.meta["Lmax"]


def test_hand_frames_input_with_patches_trains_saves_and_reloads(setup, tmp_path):
    """The derived-feature input (307 per frame) and 2-frame tokens: own statistics, stored and reused."""
    from handx_jax import representation as rep
    from handx_jax.text.cache import open_cache

    root, data, _ = setup
    ds = Dataset.open(data)
    cfg = tiny_evaluator(data, "model.motion_input=hand_frames", "model.motion_patch=2", *TRAINED)
    E = train_evaluator(tmp_path / "E", cfg, log=lambda s: None)
    ev = load_evaluator(E)
    assert ev.cfg.motion_input == "hand_frames" and ev.cfg.motion_patch == 2 and ev.cfg.motion_dim == 307
    # statistics are the train split's, per feature; constant features (middle MCP local y, z) get std 1
    train = np.sort(ds.split("train"))
    x = rep.to_evaluator_hand_frames(np.asarray(ds.motion[train], np.float32)).reshape(-1, 307).astype(np.float64)
    np.testing.assert_allclose(ev.stats.mean, x.mean(0), rtol=1e-5, atol=1e-6)
    mid = 126 + 3 * 3  # left hand, joint 4 (middle MCP) in the local block: x, y, z
    assert ev.stats.std[mid + 1] == 1.0 and ev.stats.std[mid + 2] == 1.0 and ev.stats.std[mid] < 1.0
    clips = ds.split("test")
    m1 = ev.embed_motion(ds.motion[clips])
    np.testing.assert_array_equal(load_evaluator(E).embed_motion(ds.motion[clips]), m1)
    # training lowered the contrastive loss on a fixed batch of the same input
    cache = open_cache(data, ENCODER, joined=True, max_len=64)
    td = TrainingData(ds, cache, ev.stats, ds.split("train"), [0], 0, motion_input="hand_frames")
    batch = td.batch(np.arange(len(td)), np.zeros(len(td), int))
    assert batch["motion"].shape == (len(td), 60, 307)
    before, after = infonce_init_and_trained(ev, batch)
    assert after < before - 0.5, (before, after)
    res = evaluate_ground_truth(ev, ds, CFG, cache=False)
    assert res.metrics["fid"][0] == pytest.approx(0.0, abs=1e-4)
    assert_beats_chance(evaluate_ground_truth(ev, ds, MetricConfig(replications=4, rprec_block=10), split="train",
                                              cache=False), block=10)


def test_evaluator_config_checks_and_legacy_meta(setup, tmp_path):
    from handx_jax.models.evaluator import EvaluatorConfig

    with pytest.raises(ValueError, match="unknown evaluator motion_input 'joints'"):
        EvaluatorConfig(motion_input="joints")
    with pytest.raises(ValueError, match="motion_patch 7 must be"):
        EvaluatorConfig(motion_patch=7)
    root, data, E = setup
    # folders written before motion_input existed stored motion_dim: 126 loads, anything else is refused
    old = shutil.copytree(E, tmp_path / "old", ignore=shutil.ignore_patterns(REFERENCE_CACHE_DIR))
    meta = json.loads((old / "evaluator.json").read_text())
    del meta["evaluator_config"]["motion_input"], meta["evaluator_config"]["motion_patch"]
    meta["evaluator_config"]["motion_dim"] = 126
    (old / "evaluator.json").write_text(json.dumps(meta))
    ds = Dataset.open(data)
    clips = ds.split("test")
    np.testing.assert_array_equal(load_evaluator(old).embed_motion(ds.motion[clips]),
                                  load_evaluator(E).embed_motion(ds.motion[clips]))
    meta["evaluator_config"]["motion_dim"] = 130
    (old / "evaluator.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match="motion_dim is 130"):
        load_evaluator(old)


def test_training_encodes_only_the_levels_it_reads(setup, tmp_path):
    """Trained on level 0 and scored at level 4, the run builds a joined cache of exactly those two levels
    (not all five), and its training reads nothing else."""
    import shutil

    from handx_jax.text.cache import CACHE_DIRNAME, TextCache, open_cache

    root, data, _ = setup
    mine = tmp_path / "ds"
    shutil.copytree(data, mine, ignore=shutil.ignore_patterns(CACHE_DIRNAME))
    cfg = tiny_evaluator(mine, "train.steps=4", "text.train_levels=0", "text.eval_level=-1")
    E = train_evaluator(tmp_path / "E", cfg, log=lambda s: None)
    caches = [TextCache.open(p) for p in (mine / CACHE_DIRNAME).iterdir() if p.is_dir()]
    assert [c.cached_levels for c in caches] == [[0, 4]] and caches[0].meta["fields"] == [JOINED]
    assert json.loads((E / "evaluator.json").read_text())["text_cache"]["fingerprint"] == caches[0].fingerprint
    with pytest.raises(DataError, match="no text cache"):  # no full cache was built
        open_cache(mine, ENCODER, joined=True, max_len=64)
