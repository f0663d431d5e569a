"""Embedding cache: read-back equals direct encoding, fingerprint checks, FLOPs record, CLI."""

import argparse
import json

import jax.numpy as jnp
import numpy as np
import pytest

from random_params import random_params

from handx_jax.dataset.format import TEXT_FIELDS, Dataset
from handx_jax.infra.errors import DataError
from handx_jax.text import cli
from handx_jax.text import tokenizer as tk
from handx_jax.text.cache import TextCache, build_cache, neighbour_accuracy, open_cache
from handx_jax.text.hf import load_hf_t5_encoder, save_hf_t5_encoder
from handx_jax.text.t5 import T5Config, T5EncoderModel, encoder_flops
from handx_jax.text.toy import write_toy_dataset


def _random_encoder(path, tok, seed):
    cfg = T5Config(vocab_size=tok.vocab_size, d_model=32, d_kv=8, d_ff=64, num_layers=2, num_heads=4,
                   feed_forward_proj="gated-gelu")
    ids = jnp.ones((1, 4), jnp.int32)
    params = random_params(lambda r: T5EncoderModel(cfg).init(r, ids, ids), seed)["params"]  # no compiled init
    return save_hf_t5_encoder(path, cfg, params, tok)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("cache")
    data = write_toy_dataset(root / "data", num_clips=24)
    tok = tk.train_for_dataset(data, vocab_size=200)
    return data, _random_encoder(root / "enc_a", tok, 0), _random_encoder(root / "enc_b", tok, 1)


def test_cache_reads_back_direct_encoding(setup):
    data, enc_dir, _ = setup
    root = build_cache(data, enc_dir, dtype="float32", batch_size=32, log=lambda s: None)
    assert root.parent.name == "text_cache" and root.parent.parent == data
    cache = open_cache(data, enc_dir, dtype="float32")
    ds, enc = Dataset.open(data), load_hf_t5_encoder(enc_dir)
    L = cache.meta["Lmax"]
    for f in TEXT_FIELDS:
        for level in (0, 4):
            clips = np.arange(len(ds))
            h, m = cache.lookup(clips, f, np.full(len(clips), level))
            e, direct = enc.encode([t[f][level] for t in ds.texts], max_len=L)
            np.testing.assert_array_equal(m, e.mask_BxL.astype(bool))
            assert np.abs(h - direct * e.mask_BxL[..., None]).max() < 1e-5
            assert [cache.texts[r] for r in cache.row(clips, f, level)] == [t[f][level] for t in ds.texts]
    # identical texts share one row
    assert cache.meta["num_rows"] == len({c for t in ds.texts for f in TEXT_FIELDS for c in t[f]})
    assert cache.meta["num_captions"] == len(ds) * 3 * 5
    # analytic FLOPs per caption recorded at each caption's own length
    lengths = cache.mask.sum(1)
    assert cache.meta["encoder_flops_per_caption"]["mean"] == pytest.approx(encoder_flops(enc.cfg, lengths).mean())
    assert cache.meta["encoder_flops_per_caption"]["at_Lmax"] == encoder_flops(enc.cfg, L)
    # the acceptance check runs; a random encoder still separates distinct texts
    assert neighbour_accuracy(cache, ds.split("val"), 200)["accuracy"] >= 0.9


def test_float16_and_determinism(setup):
    data, enc_dir, _ = setup
    # captions cut to 32 tokens: two padded lengths (16, 32) to compile per dtype and batch size, not four
    a = TextCache.open(build_cache(data, enc_dir, dtype="float32", max_len=32, batch_size=32, log=lambda s: None))
    b = TextCache.open(build_cache(data, enc_dir, dtype="float16", max_len=32, batch_size=32, log=lambda s: None))
    assert b.hidden.dtype == np.float16 and a.fingerprint != b.fingerprint
    assert np.abs(np.asarray(b.hidden, np.float32) - a.hidden).max() < 1e-2
    # the cast is round-to-nearest of the float32 value (at most half a float16 step away), padding exact zeros
    step = np.spacing(np.abs(a.hidden).astype(np.float16)).astype(np.float32)
    assert (np.abs(np.asarray(b.hidden, np.float32) - a.hidden) <= 0.5 * step + 1e-6).mean() > 0.999
    assert not np.asarray(b.hidden)[~np.asarray(b.mask)].any() and not np.asarray(a.hidden)[~np.asarray(a.mask)].any()
    before = np.array(a.hidden)
    again = TextCache.open(build_cache(data, enc_dir, dtype="float32", max_len=32, batch_size=32, overwrite=True,
                                       log=lambda s: None))
    assert again.root == a.root
    np.testing.assert_array_equal(again.hidden, before)  # same settings, same numbers
    other = TextCache.open(build_cache(data, enc_dir, dtype="float32", max_len=32, batch_size=8, overwrite=True,
                                       log=lambda s: None))
    assert np.abs(other.hidden - before).max() < 1e-5  # batch composition: float rounding only


def test_chunked_build_writes_every_row_in_place(setup, monkeypatch):
    """Rows staged in RAM chunk by chunk (tiny chunks here: one batch each) land in their own rows."""
    from handx_jax.text import cache as cache_mod

    data, enc_dir, _ = setup
    # test_float16_and_determinism's batch-8 float32 shapes (max_len 32): the programs it compiled serve here
    whole = TextCache.open(build_cache(data, enc_dir, dtype="float32", max_len=32, batch_size=8, overwrite=True,
                                       log=lambda s: None))
    before_h, before_m = np.array(whole.hidden), np.array(whole.mask)
    monkeypatch.setattr(cache_mod, "CHUNK_BYTES", 1)  # chunk = batch_size rows
    chunked = TextCache.open(build_cache(data, enc_dir, dtype="float32", max_len=32, batch_size=8, overwrite=True,
                                         log=lambda s: None))
    assert len(before_h) > 3 * 8  # several chunks, the last one partial
    np.testing.assert_array_equal(np.asarray(chunked.mask), before_m)
    assert np.abs(np.asarray(chunked.hidden) - before_h).max() < 1e-5


def test_fingerprint_mismatch_refused(setup, tmp_path):
    data, enc_a, enc_b = setup
    root = build_cache(data, enc_a, dtype="float32", log=lambda s: None)
    ds, eb = Dataset.open(data), load_hf_t5_encoder(enc_b)
    with pytest.raises(DataError, match="fingerprint mismatch: built for encoder"):
        TextCache.open(root, dataset_fingerprint=ds.fingerprint, encoder_fingerprint=eb.fingerprint)
    with pytest.raises(DataError, match="fingerprint mismatch: built for dataset"):
        TextCache.open(root, dataset_fingerprint="0" * 16)
    with pytest.raises(DataError, match="no text cache for this dataset"):
        open_cache(data, enc_b, dtype="float32")
    # another dataset with the same encoder: no cache either
    other = write_toy_dataset(tmp_path / "other", num_clips=24, seed=5)
    with pytest.raises(DataError, match="no text cache"):
        open_cache(other, enc_a, dtype="float32")
    with pytest.raises(DataError, match="not a text cache"):
        TextCache.open(tmp_path)


def test_cli_cache_and_encode(setup, capsys):
    data, enc_dir, _ = setup
    p = argparse.ArgumentParser()
    cli.add_parser(p.add_subparsers())
    a = p.parse_args(["text", "cache", "--data", str(data), "--encoder", str(enc_dir), "--nn-check", "100",
                      "--max-len", "32", "--batch-size", "32"])  # test_float16_and_determinism's float16 shapes
    assert a.func(a) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    assert lines[0]["rows"] > 0 and lines[0]["dtype"] == "float16" and "captions_per_s" in lines[0]
    assert lines[1]["nearest_neighbour_check"] == "val" and 0 <= lines[1]["accuracy"] <= 1

    texts = ["left thumb taps", tk.join_fields("left hand waves", "right hand rests", "hands touch")]
    a = p.parse_args(["text", "encode", "--encoder", str(enc_dir), "--json", *texts])
    assert a.func(a) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc) == {"ids", "hidden"}
    enc = load_hf_t5_encoder(enc_dir)
    e, h = enc.encode(texts)
    for i, t in enumerate(texts):
        n = int(e.lengths_B[i])
        assert doc["ids"][i] == enc.tokenizer.encode_one(t) == e.ids_BxL[i, :n].tolist()
        np.testing.assert_allclose(np.array(doc["hidden"][i]), h[i, :n], atol=1e-6)


def test_full_disk_is_a_clean_error_and_leaves_nothing(setup, monkeypatch):
    """Issue 14.8: the cache was written through memory maps, so a full disk killed `text cache` by
    SIGBUS and left a hidden temporary folder. Now: a DiskFullError naming the file, nothing left."""
    import errno

    from handx_jax.infra import diskspace, npy_writer

    data, enc_dir, _ = setup
    root = data / "text_cache"
    monkeypatch.setattr(diskspace, "free_bytes", lambda path: 100)
    with pytest.raises(diskspace.DiskFullError, match=r"writing .*text_cache/[0-9a-f]{16}; it needs .* 100 B free"):
        build_cache(data, enc_dir, dtype="float32", max_len=48, batch_size=32, overwrite=True, log=lambda s: None)
    monkeypatch.setattr(diskspace, "free_bytes", lambda path: None)

    def append(self, rows):  # the disk fills up during the build
        with diskspace.disk_full_as_error(self.path, self.nbytes):
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(npy_writer.NpyWriter, "append", append)
    with pytest.raises(diskspace.DiskFullError, match=r"writing .*text_cache/[0-9a-f]{16}/hidden\.npy; it needs"):
        build_cache(data, enc_dir, dtype="float32", max_len=48, batch_size=32, overwrite=True, log=lambda s: None)
    assert not [p for p in root.iterdir() if p.name.startswith(".")]


def test_cache_follows_check_compatible_on_captions(setup, tmp_path):
    """Issue 14.5: the cache depends only on the clip ids and captions, so a dataset whose motion
    differs by float rounding keeps it (dataset.check_compatible, parts ids + captions); other
    captions are refused."""
    from handx_jax.dataset.format import write_dataset

    data, enc_dir, _ = setup
    root = build_cache(data, enc_dir, dtype="float32", max_len=48, batch_size=32, log=lambda s: None)
    ds = Dataset.open(data)
    splits = {k: ds.splits[k].tolist() for k in ("train", "val", "test")}
    jitter = np.float32(1e-6) * np.sign(np.random.default_rng(0).normal(size=ds.motion.shape)).astype(np.float32)
    write_dataset(tmp_path / "rounded", np.asarray(ds.motion) + jitter, ds.texts, splits=splits, stats=False)
    rounded = Dataset.open(tmp_path / "rounded")
    assert rounded.fingerprint != ds.fingerprint
    assert TextCache.open(root, dataset=rounded).meta["dataset"]["fingerprint"] == ds.fingerprint
    texts = [dict(t) for t in ds.texts]
    texts[1] = dict(texts[1], left=["something else"] * len(texts[1]["left"]))
    write_dataset(tmp_path / "recaptioned", ds.motion, texts, splits=splits, stats=False)
    with pytest.raises(DataError, match="the captions differ"):
        TextCache.open(root, dataset=Dataset.open(tmp_path / "recaptioned"))


def test_level_subset_cache_equals_the_full_cache_on_its_levels(setup, tmp_path, capsys):
    """``levels``: only those caption levels are encoded; their rows read back exactly what the full cache
    holds (direct encoding), other levels are refused by name, the subset has its own fingerprint, and a full
    cache, once it exists, serves a subset request instead of a second build."""
    import shutil

    data = tmp_path / "data"
    shutil.copytree(setup[0], data, ignore=shutil.ignore_patterns("text_cache"))
    enc_dir = setup[1]
    ds = Dataset.open(data)
    sub_root = build_cache(data, enc_dir, dtype="float32", joined=True, levels=[4, 0, -1], log=lambda s: None)
    sub = TextCache.open(sub_root)
    assert sub.cached_levels == [0, 4] and sub.meta["num_captions"] == 2 * len(ds)
    from handx_jax.text.cache import joined_texts

    assert sub.meta["num_rows"] == len({x["joined"][lv] for x in joined_texts(ds.texts) for lv in (0, 4)})
    with pytest.raises(DataError, match=r"caption level\(s\) \[2\] are not in this text cache \(it holds levels \[0, 4\]\)"):
        sub.lookup(np.arange(3), "joined", np.array([0, 2, 4]))
    with pytest.raises(DataError, match=r"level\(s\) \[1\]"):
        sub.row(0, "joined", 1)
    # the same rows as a full joined cache, to float32 rounding of the one encoder (different padded length)
    full = TextCache.open(build_cache(data, enc_dir, dtype="float32", joined=True, log=lambda s: None))
    assert full.fingerprint != sub.fingerprint and full.cached_levels == [0, 1, 2, 3, 4]
    clips = np.arange(len(ds))
    for lv in (0, 4):
        hs, ms = sub.lookup(clips, "joined", np.full(len(clips), lv))
        hf, mf = full.lookup(clips, "joined", np.full(len(clips), lv))
        n = min(hs.shape[1], hf.shape[1])
        np.testing.assert_array_equal(ms[:, :n], mf[:, :n])
        assert not ms[:, n:].any() and not mf[:, n:].any()
        assert np.abs(hs[:, :n] - hf[:, :n]).max() < 1e-5
        assert [sub.texts[r] for r in sub.row(clips, "joined", lv)] == [full.texts[r] for r in full.row(clips, "joined", lv)]
    # both exist: open_cache with levels prefers the full one; build_cache with levels reuses it
    assert open_cache(data, enc_dir, dtype="float32", joined=True, levels=[0]).fingerprint == full.fingerprint
    assert build_cache(data, enc_dir, dtype="float32", joined=True, levels=[0], log=lambda s: None) == full.root
    shutil.rmtree(full.root)
    assert open_cache(data, enc_dir, dtype="float32", joined=True, levels=[0, 4]).fingerprint == sub.fingerprint
    with pytest.raises(DataError, match="no text cache"):
        open_cache(data, enc_dir, dtype="float32", joined=True, levels=[1])
    with pytest.raises(ValueError, match="caption level 5 out of range"):
        build_cache(data, enc_dir, dtype="float32", joined=True, levels=[5], log=lambda s: None)
    assert neighbour_accuracy(sub, ds.split("val"), 50)["n"] > 0  # samples only the levels it holds
    # the CLI: --levels, and a bad value is one line with exit 2
    p = argparse.ArgumentParser()
    cli.add_parser(p.add_subparsers())
    for bad, msg in (("x", "expected comma-separated caption levels"), ("7", "caption level 7 out of range")):
        a = p.parse_args(["text", "cache", "--data", str(data), "--encoder", str(enc_dir), "--levels", bad])
        assert a.func(a) == 2
        assert msg in capsys.readouterr().err
    a = p.parse_args(["text", "cache", "--data", str(data), "--encoder", str(enc_dir), "--joined", "--levels", "0",
                      "--dtype", "float32", "--nn-check", "0"])
    assert a.func(a) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["captions"] == len(ds)
