"""The reversed copy of a corpus (``handx data reverse``) and what the evaluator does with it: mixed into
its batches with its own captions (``data.reversed_path``), and fine-tuning from a trained evaluator
(``init_from``). Issue 40: the yardstick must read the order of events."""

import json
from pathlib import Path

import numpy as np
import pytest

from handx_jax.dataset.build import BuildConfig, build_corpus, caption_seed, with_reading
from handx_jax.annotation.caption import TemplateCaptioner
from handx_jax.dataset.format import Dataset
from handx_jax.annotation.events import annotate, annotation_config
from handx_jax.dataset.reverse import build_reversed, pick_clips
from handx_jax.evaluation.features import caption_ids

ENCODER = Path(__file__).parent / "fixtures" / "t5_tiny_gated"
TINY = ("train.steps=6", "train.batch_size=8", "train.optim.lr=1e-3", "train.optim.warmup_steps=0",
        "train.log_every=2", "train.wandb=disabled", "text.max_len=64", "final_eval=false")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("reverse")
    data = build_corpus(root / "ds", with_reading(BuildConfig(clips=40, seed=3, workers=1, val_fraction=0.1,
                                                              test_fraction=0.2), "stable"), progress=False)
    rev = build_reversed(data, root / "rev", workers=1, log=lambda s: None)
    return root, Dataset.open(data), Dataset.open(rev)


def test_reversed_clips_are_the_split_backwards_with_their_own_captions(corpus):
    _, ds, rds = corpus
    train = pick_clips(ds, "train", None)
    assert len(rds) == len(train) and list(rds.split("train")) == list(range(len(train)))
    np.testing.assert_array_equal(np.asarray(rds.motion), np.asarray(ds.motion[train])[:, ::-1])
    assert rds.ids == [ds.ids[c] + "~rev" for c in train]
    src = rds.meta["source"]
    assert src["kind"] == "reversed" and src["of_fingerprint"] == ds.fingerprint and src["annotation"] == "stable"
    # Captions: an independent annotation of the reversed motion, captioned with the SOURCE clip's seed (so
    # an unchanged fact keeps its wording), per-fact wording as the stable corpus.
    x = np.asarray(ds.motion[train], np.float32)[:, ::-1]
    recs = annotate(np.ascontiguousarray(x), annotation_config("stable"))
    cap = TemplateCaptioner("per_fact")
    for i, (rec, c) in enumerate(zip(recs, train)):
        want = cap.caption(rec, seed=caption_seed(3, ds.ids[c]))
        assert [lv["left"] for lv in want] == rds.texts[i]["left"]
        assert [lv["interaction"] for lv in want] == rds.texts[i]["interaction"]
    # Reversal changes what most clips say (the validity suite measures 86% of level-0 captions on the standard
    # prefix); on 30-odd clips, at least half.
    diff = np.mean([rds.texts[i]["left"][0] != ds.texts[c]["left"][0] or
                    rds.texts[i]["right"][0] != ds.texts[c]["right"][0] or
                    rds.texts[i]["interaction"][0] != ds.texts[c]["interaction"][0] for i, c in enumerate(train)])
    assert diff >= 0.5, diff
    assert rds.report["level0_same_as_forward"] == pytest.approx(1 - diff)


def test_a_thin_subset_is_reversed_from_its_own_rows(corpus, monkeypatch):
    """``--clips N`` spreads each chunk over the corpus: its rows are gathered, not read as one span."""
    import handx_jax.dataset.reverse as R

    root, ds, _ = corpus
    monkeypatch.setattr(R, "CHUNK", 2)  # chunks of 2 clips about 7 apart: wider than 4 rows per clip
    picked = pick_clips(ds, "train", 5)
    assert len(picked) == 5 and np.diff(picked).min() > 4
    sub = Dataset.open(build_reversed(ds.root, root / "rev5", limit=5, workers=1, log=lambda s: None))
    np.testing.assert_array_equal(np.asarray(sub.motion), np.asarray(ds.motion[picked])[:, ::-1])
    assert sub.ids == [ds.ids[c] + "~rev" for c in picked]


def test_a_reversed_corpus_reversed_again_keeps_its_recorded_reading(corpus):
    """A reversed corpus records its reading in ``source`` (it has no build recipe): reversing it again reads and
    words it that way (issue 54: it fell back to the reference reading and the shared wording)."""
    root, ds, rds = corpus
    back = Dataset.open(build_reversed(rds.root, root / "revrev", limit=4, workers=1, log=lambda s: None))
    src = back.meta["source"]
    assert (src["annotation"], src["wording"], src["seed"]) == ("stable", "per_fact", 3)
    picked = pick_clips(rds, "train", 4)
    recs = annotate(np.ascontiguousarray(np.asarray(rds.motion[picked], np.float32)[:, ::-1]), annotation_config("stable"))
    cap = TemplateCaptioner("per_fact")
    for i, (rec, c) in enumerate(zip(recs, picked)):
        assert [lv["left"] for lv in cap.caption(rec, seed=caption_seed(3, rds.ids[c]))] == back.texts[i]["left"]


def test_caption_ids_match_identical_captions_across_datasets(corpus):
    _, ds, rds = corpus
    train = pick_clips(ds, "train", None)
    a = caption_ids(ds, train, np.zeros(len(train), np.int64))
    b = caption_ids(rds, np.arange(len(rds)), np.zeros(len(rds), np.int64))
    same = np.array([all(ds.texts[c][f][0] == rds.texts[i][f][0] for f in ("left", "right", "interaction"))
                     for i, c in enumerate(train)])
    np.testing.assert_array_equal(a == b, same)
    assert len(set(a.tolist())) == len({tuple(ds.texts[c][f][0] for f in ("left", "right", "interaction")) for c in train})


def test_batches_mix_in_the_reversed_copy_at_the_share_asked(corpus):
    from handx_jax.evaluation import TrainingData, evaluator_stats
    from handx_jax.evaluation.features import motion_features
    from handx_jax.text.cache import build_cache, open_cache
    from handx_jax.text.hf import as_encoder

    _, ds, rds = corpus
    enc = as_encoder(str(ENCODER))
    caches = []
    for d in (ds, rds):
        build_cache(d.root, enc, joined=True, max_len=64, levels=[0], log=lambda s: None)
        caches.append(open_cache(d.root, enc, joined=True, max_len=64, levels=[0]))
    stats = evaluator_stats(ds)
    clips = ds.split("train")
    plain = TrainingData(ds, caches[0], stats, clips, [0], 7, text_ids=True)
    mixed = TrainingData(ds, caches[0], stats, clips, [0], 7, text_ids=True, companion=(rds, caches[1]),
                         companion_share=0.5)
    idx = np.arange(len(clips))
    a, b = plain.batch(idx), mixed.batch(idx)
    fwd = motion_features(np.asarray(ds.motion[clips], np.float32), stats)
    rev = motion_features(np.asarray(rds.motion, np.float32), stats)
    from_rev = np.array([not np.allclose(b["motion"][i], fwd[i]) for i in range(len(idx))])
    assert 0.25 < from_rev.mean() < 0.75, from_rev.mean()
    np.testing.assert_array_equal(b["motion"][~from_rev], a["motion"][~from_rev])
    # The kept items keep their own text too (only the taken ones are read from the companion).
    L = min(a["text"].shape[1], b["text"].shape[1])
    np.testing.assert_array_equal(b["text"][~from_rev][:, :L], a["text"][~from_rev][:, :L])
    np.testing.assert_array_equal(b["text_mask"][~from_rev][:, :L], a["text_mask"][~from_rev][:, :L])
    assert not a["text_mask"][~from_rev][:, L:].any() and not b["text_mask"][~from_rev][:, L:].any()
    np.testing.assert_array_equal(b["text_id"][~from_rev], a["text_id"][~from_rev])
    for i in np.flatnonzero(from_rev):  # each replaced item is some reversed clip, with that clip's caption id
        j = int(np.argmin(np.abs(rev - b["motion"][i]).reshape(len(rev), -1).max(1)))
        np.testing.assert_allclose(b["motion"][i], rev[j], atol=1e-6)
        assert b["text_id"][i] == caption_ids(rds, np.array([j]), np.array([0]))[0]
    # The reversal negative is dropped exactly where an item's reversal reads as the item itself.
    paired = TrainingData(ds, caches[0], stats, clips, [0], 7, text_ids=True, reversed_copy=True,
                          companion=(rds, caches[1]), companion_share=0.5)
    p = paired.batch(idx)
    np.testing.assert_array_equal(p["motion"], b["motion"])
    cap = lambda d, i: tuple(d.texts[i][f][0] for f in ("left", "right", "interaction"))  # noqa: E731
    for i in range(len(idx)):
        if from_rev[i]:
            j = int(np.argmin(np.abs(rev - p["motion"][i]).reshape(len(rev), -1).max(1)))
            want = cap(rds, j) == cap(ds, int(clips[j]))
        else:
            want = cap(ds, int(clips[i])) == cap(rds, i)  # the companion holds every train clip, in order
        assert bool(p["rev_same_text"][i]) == want, i
    assert p["rev_same_text"].any() or not any(cap(ds, int(c)) == cap(rds, k) for k, c in enumerate(clips))
    # Paired: the batch's last items are the reversals of its first ones, each with its own caption.
    pairs = TrainingData(ds, caches[0], stats, clips, [0], 7, text_ids=True, companion=(rds, caches[1]),
                         companion_share=0.25, companion_pairs=True)
    q = pairs.batch(idx[:16])
    k = 4
    np.testing.assert_array_equal(q["motion"][:12], a["motion"][:12])
    for j in range(k):  # the companion holds every train clip in order: clip j's reversal is companion item j
        np.testing.assert_allclose(q["motion"][12 + j], rev[j], atol=1e-6)
        assert q["text_id"][12 + j] == caption_ids(rds, np.array([j]), np.array([0]))[0]
    again = mixed.batch(idx)  # a pure function of (seed, indices): resume draws the same batch
    np.testing.assert_array_equal(again["motion"], b["motion"])
    np.testing.assert_array_equal(again["text"], b["text"])


def _run(*args):
    """``handx ARGS`` through its entry point (``handx_jax.cli.main``) in this process: what it returns and
    what it wrote to stderr. In process, the second training reuses the first's compiled programs, and no
    run pays for Python's and JAX's imports (as four subprocesses the file took 29.3 CPU-s, in process 23.4)."""
    import contextlib
    import io
    import types

    from handx_jax.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(list(args))
    return types.SimpleNamespace(returncode=rc, stderr=err.getvalue())


def test_fine_tuning_with_the_reversed_copy_through_the_cli(corpus):
    root, ds, rds = corpus
    base = root / "E0"
    r = _run("train", "evaluator", "--data", str(ds.root), "--encoder", str(ENCODER), "--preset", "tiny",
             "--out", str(base), *sum((["--set", s] for s in TINY), []))
    assert r.returncode == 0, r.stderr
    tuned = root / "E1"
    sets = [*TINY, "train.optim.lr=0", f"init_from={base}", f"data.reversed_path={rds.root}",
            "data.reversed_share=0.5", "model.mask_same_text=true"]
    r = _run("train", "evaluator", "--data", str(ds.root), "--encoder", str(ENCODER), "--preset", "tiny",
             "--out", str(tuned), *sum((["--set", s] for s in sets), []))
    assert r.returncode == 0, r.stderr
    from handx_jax.evaluation import load_evaluator

    e0, e1 = load_evaluator(base), load_evaluator(tuned)
    # At learning rate 0 the fine-tuned weights and statistics are exactly the starting evaluator's.
    import jax

    for x, y in zip(jax.tree_util.tree_leaves(e0.params), jax.tree_util.tree_leaves(e1.params)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    np.testing.assert_array_equal(e0.stats.mean, e1.stats.mean)
    meta = json.loads((tuned / "evaluator.json").read_text())
    assert meta["training"]["init_from"]["fingerprint"] == e0.fingerprint
    assert meta["training"]["reversed"]["fingerprint"] == rds.fingerprint
    # A folder that is not a reversed copy of this corpus is refused in one line, naming it.
    r = _run("train", "evaluator", "--data", str(ds.root), "--encoder", str(ENCODER), "--preset", "tiny",
             "--out", str(root / "E2"), *sum((["--set", s] for s in (*TINY, f"data.reversed_path={ds.root}",
                                                                      "data.reversed_share=0.5")), []))
    assert r.returncode == 2 and "not a `handx data reverse` copy" in r.stderr and "Traceback" not in r.stderr
    # A differently shaped starting evaluator is refused before training.
    r = _run("train", "evaluator", "--data", str(ds.root), "--encoder", str(ENCODER), "--preset", "tiny",
             "--out", str(root / "E3"), *sum((["--set", s] for s in (*TINY, f"init_from={base}", "model.latent=48")), []))
    assert r.returncode == 2 and "fine-tuning needs the same shape" in r.stderr and "Traceback" not in r.stderr
