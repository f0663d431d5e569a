"""Frozen-encoder embedding cache: every caption of a dataset encoded once, memory-mapped on read.

Layout of ``DATA/text_cache/<fingerprint>/`` (written atomically with ``infra.atomic.atomic_dir``):

    meta.json    fingerprints (dataset, encoder weights, tokenizer), shapes, dtype, truncation count,
                 analytic encoder FLOPs per caption, build speed
    hidden.npy   (M, Lmax, D) float16|float32: last hidden states of the M distinct caption texts
    mask.npy     (M, Lmax) bool: real tokens (eos included)
    index.json   clip ids, fields, levels, ``rows`` (N, 3, levels) → row of hidden/mask, and ``texts``

Identical texts share one row (template captions repeat a lot). The fingerprint hashes encoder
weights + config, tokenizer model, dataset content and the cache options, so a cache can only be
opened for the exact encoder and data that made it; anything else is refused with a clear error.
Generator training reads this cache and never runs the text encoder inside its step.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from handx_jax.infra.atomic import atomic_dir, atomic_write_json
from handx_jax.infra.diskspace import check_free_space
from handx_jax.infra.errors import DataError
from handx_jax.infra.npy_writer import NpyWriter
from handx_jax.infra.readers import read_format_meta

FORMAT, FORMAT_VERSION = "handx-jax-text-cache", 1
CACHE_DIRNAME = "text_cache"
DTYPES = ("float16", "float32")


JOINED = "joined"  # the three prompts in one sequence (evaluator text side, AR prefix; reference §1.2)


def cache_fingerprint(dataset_fp: str, encoder_fp: str, tokenizer_fp: str, max_len: int, dtype: str,
                      joined: bool = False, levels: Sequence[int] | None = None) -> str:
    """``levels``: a cache of only these caption levels (None: all; the fingerprint of a full cache is the
    same as before level subsets existed)."""
    doc = {"format": FORMAT, "version": FORMAT_VERSION, "dataset": dataset_fp, "encoder": encoder_fp,
           "tokenizer": tokenizer_fp, "max_len": int(max_len), "dtype": dtype}
    if joined:
        doc["fields"] = JOINED
    if levels is not None:
        doc["levels"] = sorted({int(v) for v in levels})
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


MISSING = -1  # rows[clip, field, level] of a level the cache does not hold


def caption_table(texts: Sequence[dict], fields: Sequence[str], levels: Sequence[int] | None = None
                  ) -> tuple[list[str], np.ndarray]:
    """Distinct caption strings (first-appearance order) and ``rows[clip, field, level]`` into them; with
    ``levels``, only those levels are listed and the others' rows are :data:`MISSING`."""
    n_levels = len(texts[0][fields[0]]) if texts else 0
    keep = range(n_levels) if levels is None else sorted({int(v) for v in levels})
    rows = np.full((len(texts), len(fields), n_levels), MISSING, np.int32)
    uniq: dict[str, int] = {}
    for i, t in enumerate(texts):
        for f, name in enumerate(fields):
            if len(t[name]) != n_levels:
                raise DataError(f"{len(t[name])} levels, expected {n_levels}", clip=t.get("id", i), field=name)
            for j in keep:
                rows[i, f, j] = uniq.setdefault(t[name][j], len(uniq))
    return list(uniq), rows


def level_subset(levels: Sequence[int] | None, n_levels: int) -> list[int] | None:
    """``levels`` checked against a dataset of ``n_levels`` caption levels (negative = from the most
    detailed), sorted and de-duplicated; None where they are all of them (a full cache)."""
    if levels is None:
        return None
    out = set()
    for v in levels:
        v = int(v)
        if not -n_levels <= v < n_levels:
            raise ValueError(f"caption level {v} out of range: the dataset has {n_levels} levels "
                             f"(0..{n_levels - 1}, or -{n_levels}..-1)")
        out.add(v % n_levels)
    if not out:
        raise ValueError("levels: give at least one caption level")
    return None if len(out) == n_levels else sorted(out)


def bucket_length(n: int, step: int, cap: int) -> int:
    """``n`` tokens rounded up to a multiple of ``step``, at most ``cap``: the padded length of a batch
    whose longest sequence has n tokens (few distinct shapes → few compiles, little padding)."""
    return int(min(cap, -(-n // step) * step))


def joined_texts(texts: Sequence[dict]) -> list[dict]:
    """Per clip and level, ``<extra_id_0> L <extra_id_1> R <extra_id_2> I <extra_id_3>`` (reference §1.2,
    with real T5 sentinels: the reference's evaluator writes ``<extra_id0>``, which T5 reads as text)."""
    from handx_jax.text.tokenizer import join_fields, sentinel

    return [{"id": t.get("id"), JOINED: [f"{join_fields(l, r, i)} {sentinel(3)}"
                                        for l, r, i in zip(t["left"], t["right"], t["interaction"])]}
            for t in texts]


CHUNK_BYTES = 256 << 20  # RAM staging of the cache build: rows per chunk = this / (Lmax · d_model · itemsize)


def build_cache(data_dir: str | os.PathLike, encoder_dir: str | os.PathLike, *, max_len: int = 128,
                dtype: str = "float16", batch_size: int = 128, overwrite: bool = False, joined: bool = False,
                levels: Sequence[int] | None = None, log: Callable[[str], None] = print) -> Path:
    """Encode every caption of the dataset at ``data_dir`` with the encoder folder; return the cache dir.

    ``joined`` caches one sequence per (clip, level) holding the three prompts behind separators
    (field name ``"joined"``) instead of one row per field. ``levels`` encodes only those caption levels
    (an evaluator trained and scored at level 0 needs a fifth of the full joined cache: 120k clips' full
    cache took 149 s of a GPU lease); a full cache, where one exists, serves such a request too. An
    existing cache with the same fingerprint is complete by construction (atomic write) and is reused
    unless ``overwrite``.
    """
    from handx_jax.dataset.format import TEXT_FIELDS, Dataset, dataset_record
    from handx_jax.text.hf import as_encoder

    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {DTYPES}, got {dtype!r}")
    ds = Dataset.open(data_dir)
    enc = as_encoder(encoder_dir)  # a folder, or an encoder the command already loaded
    levels = level_subset(levels, _dataset_levels(ds))
    full = Path(data_dir) / CACHE_DIRNAME / cache_fingerprint(ds.fingerprint, enc.fingerprint,
                                                              enc.tokenizer.fingerprint, max_len, dtype, joined)
    if levels is not None and full.exists() and not overwrite:
        log(f"text cache {full} (all levels) is up to date")
        return full
    fp = cache_fingerprint(ds.fingerprint, enc.fingerprint, enc.tokenizer.fingerprint, max_len, dtype, joined, levels)
    out = Path(data_dir) / CACHE_DIRNAME / fp
    if out.exists() and not overwrite:
        log(f"text cache {out} is up to date")
        return out

    fields = (JOINED,) if joined else TEXT_FIELDS
    texts, rows = caption_table(joined_texts(ds.texts) if joined else ds.texts, fields, levels)
    seqs = [enc.tokenizer.encode_one(t) for t in texts]
    lengths = np.array([len(s) for s in seqs], np.int64)
    L = int(min(max_len, lengths.max(initial=1)))
    num_truncated = int((lengths > L).sum())
    kept = np.minimum(lengths, L)
    D = enc.cfg.d_model
    t0 = time.perf_counter()
    # Appending writes, not memory maps: on a full disk a write fails with ENOSPC (a DiskFullError naming the
    # file; atomic_dir removes the partial folder) where a memory-mapped store dies by SIGBUS, silently.
    check_free_space(out, len(texts) * L * (D * np.dtype(dtype).itemsize + 1))
    with atomic_dir(out, overwrite=overwrite) as tmp, \
            NpyWriter(tmp / "hidden.npy", dtype, (len(texts), L, D)) as hidden, \
            NpyWriter(tmp / "mask.npy", np.bool_, (len(texts), L)) as mask:
        # Masking and the cast to the cache dtype run on the device inside the encoder's jit: the host then
        # copies half the bytes and does no float work per batch (an exact 0/1 product and an IEEE
        # round-to-nearest cast, so the stored values are the same as doing it in numpy).
        import jax
        import jax.numpy as jnp

        encode = jax.jit(enc.stored_forward(dtype))
        # Rows are encoded in consecutive chunks that are staged in RAM and appended to the files in
        # order: scattering each batch's rows over the whole file made the kernel write the same pages
        # back again and again (a 60k-clip joined cache, 9.8 GB, had written 180 GB after 19 minutes).
        # Within a chunk, longest first, padded to a multiple of 16 tokens: few distinct shapes (few
        # compiles), little padding.
        chunk = max(batch_size, CHUNK_BYTES // max(L * D * np.dtype(dtype).itemsize, 1))
        for c0 in range(0, len(texts), chunk):
            c1 = min(c0 + chunk, len(texts))
            h_buf = np.zeros((c1 - c0, L, D), dtype)
            m_buf = np.zeros((c1 - c0, L), np.bool_)
            order = c0 + np.argsort(-kept[c0:c1], kind="stable")
            for s in range(0, len(order), batch_size):
                sel = order[s:s + batch_size]
                Lb = bucket_length(int(kept[sel].max()), 16, L)
                ids = np.zeros((batch_size, Lb), np.int32)
                m = np.zeros((batch_size, Lb), np.int32)
                ids[len(sel):, 0] = 1  # filler rows: a lone eos, so no row is fully masked
                m[len(sel):, 0] = 1
                for r, k in enumerate(sel):
                    seq = seqs[k] if len(seqs[k]) <= L else seqs[k][:L - 1] + [1]
                    ids[r, :len(seq)] = seq
                    m[r, :len(seq)] = 1
                # Padded positions are stored as exact zeros.
                h_buf[sel - c0, :Lb] = np.asarray(encode(enc.params, jnp.asarray(ids), jnp.asarray(m)))[:len(sel)]
                m_buf[sel - c0, :Lb] = m[:len(sel)].astype(bool)
            hidden.append(h_buf)
            mask.append(m_buf)
        hidden.close()
        mask.close()
        wall = time.perf_counter() - t0
        flops = enc.flops(kept)
        meta = {
            "format": FORMAT, "format_version": FORMAT_VERSION, "fingerprint": fp,
            "dataset_fingerprint": ds.fingerprint, "dataset": dataset_record(ds), "encoder_fingerprint": enc.fingerprint,
            "tokenizer_fingerprint": enc.tokenizer.fingerprint, "encoder_path": str(Path(enc.path or encoder_dir).absolute()),
            "encoder_config": dataclasses.asdict(enc.cfg), "max_len": int(max_len), "Lmax": L,
            "d_model": D, "dtype": dtype, "num_rows": len(texts), "num_captions": int((rows != MISSING).sum()),
            "num_clips": int(rows.shape[0]), "levels": int(rows.shape[2]), "fields": list(fields),
            "cached_levels": list(range(rows.shape[2])) if levels is None else levels,
            "num_truncated": num_truncated, "mean_tokens": float(kept.mean()) if len(kept) else 0.0,
            "encoder_flops_per_caption": {
                "mean": float(flops.mean()) if len(kept) else 0.0, "at_Lmax": int(enc.flops(L)),
                "counting": "analytic matmul FLOPs of one forward at the caption's own length (t5.encoder_flops)"},
            "build_seconds": wall, "captions_per_s": len(texts) / max(wall, 1e-9),
        }
        atomic_write_json(tmp / "index.json", {"fields": list(fields), "levels": int(rows.shape[2]),
                                               "clip_ids": ds.ids, "rows": rows.tolist(), "texts": texts}, indent=None)
        atomic_write_json(tmp / "meta.json", meta)
    log(f"text cache {out}: {len(texts)} distinct of {int((rows != MISSING).sum())} captions"
        f"{'' if levels is None else f' (levels {levels})'}, Lmax {L} ({num_truncated} truncated), "
        f"{len(texts) / max(wall, 1e-9):.1f} captions/s")
    return out


def _dataset_levels(ds) -> int:
    return int(ds.meta.get("levels") or (len(ds.texts[0]["left"]) if len(ds.texts) else 0))


@dataclass
class TextCache:
    """An opened cache. ``hidden``/``mask`` are memory-mapped; ``rows[clip, field, level]`` → row."""

    root: Path
    meta: dict
    hidden: np.ndarray
    mask: np.ndarray
    rows: np.ndarray
    texts: list[str]
    fields: tuple[str, ...]

    @classmethod
    def open(cls, root: str | os.PathLike, *, dataset_fingerprint: str | None = None,
             encoder_fingerprint: str | None = None, tokenizer_fingerprint: str | None = None,
             dataset=None) -> "TextCache":
        """Open a cache folder; refuse it if it was built for another dataset, encoder or tokenizer.

        With ``dataset`` (an open Dataset) the check is data.dataset.check_compatible on the clip ids
        and captions, the only part of a dataset the cache depends on: a rebuild whose motion differs by
        float rounding keeps its cache; other captions or clips are refused.
        """
        root = Path(root)
        meta = read_format_meta(root / "meta.json", FORMAT, FORMAT_VERSION,
                                missing="not a text cache (missing meta.json); build one with `handx text cache`",
                                upgrade="; rebuild it with `handx text cache`")
        if dataset is not None:
            from handx_jax.dataset.format import check_compatible

            check_compatible(meta.get("dataset", {"fingerprint": meta.get("dataset_fingerprint")}), dataset,
                             what=f"text cache {root}", parts=("ids", "captions"),
                             fix="rebuild it with `handx text cache`")
        for what, want in (("dataset", dataset_fingerprint), ("encoder", encoder_fingerprint),
                           ("tokenizer", tokenizer_fingerprint)):
            have = meta.get(f"{what}_fingerprint")
            if want is not None and have != want:
                raise DataError(f"text cache fingerprint mismatch: built for {what} {have}, but the {what} in use is "
                                f"{want}; rebuild it with `handx text cache`", path=root)
        from handx_jax.infra.readers import read_json, read_npy

        hidden = read_npy(root / "hidden.npy", mmap=True)
        mask = read_npy(root / "mask.npy", mmap=True)
        index = read_json(root / "index.json", expect=dict)
        rows = np.asarray(index["rows"], np.int32).reshape(meta["num_clips"], len(index["fields"]), index["levels"])
        if hidden.shape != (meta["num_rows"], meta["Lmax"], meta["d_model"]) or mask.shape != hidden.shape[:2]:
            raise DataError(f"arrays {hidden.shape}/{mask.shape} do not match meta.json", path=root)
        return cls(root, meta, hidden, mask, rows, index["texts"], tuple(index["fields"]))

    @property
    def fingerprint(self) -> str:
        return self.meta["fingerprint"]

    def row(self, clip, field: str, level) -> np.ndarray:
        r = np.asarray(self.rows[clip, self.fields.index(field), level])
        if (r == MISSING).any():  # a level subset's cache: never hand out row -1 (the last text)
            lv = sorted({int(v) % self.rows.shape[2] for v in np.broadcast_to(np.asarray(level), r.shape)[r == MISSING]})
            raise DataError(f"caption level(s) {lv} are not in this text cache (it holds levels {self.cached_levels}); "
                            f"build one with `handx text cache` (without --levels for all of them)", path=self.root)
        return r

    @property
    def cached_levels(self) -> list[int]:
        return list(self.meta.get("cached_levels", range(self.rows.shape[2])))

    def lookup(self, clip, field: str, level) -> tuple[np.ndarray, np.ndarray]:
        """(hidden (…, Lmax, D), mask (…, Lmax)) for clip indices, one field, level indices."""
        r = self.row(clip, field, level)
        flat = r.reshape(-1)
        order = np.argsort(flat, kind="stable")  # sorted reads are kinder to a memory map
        h = np.empty((len(flat),) + self.hidden.shape[1:], self.hidden.dtype)
        m = np.empty((len(flat),) + self.mask.shape[1:], bool)
        h[order], m[order] = self.hidden[flat[order]], self.mask[flat[order]]
        return h.reshape(r.shape + h.shape[1:]), m.reshape(r.shape + m.shape[1:])


def open_cache(data_dir: str | os.PathLike, encoder_dir: str | os.PathLike, *, max_len: int = 128,
               dtype: str = "float16", joined: bool = False, levels: Sequence[int] | None = None) -> TextCache:
    """The cache for this dataset + encoder folder, verified; a clear error if there is none. ``levels``:
    the caption levels the caller reads; the full cache serves them, else one built for exactly them."""
    from handx_jax.dataset.format import Dataset
    from handx_jax.text.hf import as_encoder

    ds = Dataset.open(data_dir)
    enc = as_encoder(encoder_dir)  # a folder, or an encoder the command already loaded
    fp = cache_fingerprint(ds.fingerprint, enc.fingerprint, enc.tokenizer.fingerprint, max_len, dtype, joined)
    root = Path(data_dir) / CACHE_DIRNAME / fp
    levels = level_subset(levels, _dataset_levels(ds))
    if not root.exists() and levels is not None:
        root = Path(data_dir) / CACHE_DIRNAME / cache_fingerprint(
            ds.fingerprint, enc.fingerprint, enc.tokenizer.fingerprint, max_len, dtype, joined, levels)
    if not root.exists():
        others = sorted(p.name for p in (Path(data_dir) / CACHE_DIRNAME).glob("*") if p.is_dir()
                        and not p.name.startswith(".")) if (Path(data_dir) / CACHE_DIRNAME).is_dir() else []
        # the AR family and the evaluator read the joined cache: the command says so (issue 43)
        flags = (" --joined" if joined else "") + (f" --max-len {max_len}" if max_len != 128 else "") + \
            (f" --dtype {dtype}" if dtype != "float16" else "")
        raise DataError(f"no text cache for this dataset + encoder {enc.fingerprint} (max_len {max_len}, {dtype}"
                        f"{', joined' if joined else ''}); existing caches {others} were built for other encoders, "
                        f"data or options; run `handx text cache --data {data_dir} --encoder {enc.path or encoder_dir}"
                        f"{flags}`", path=root.parent)
    return TextCache.open(root, dataset=ds, encoder_fingerprint=enc.fingerprint,
                          tokenizer_fingerprint=enc.tokenizer.fingerprint)


def neighbour_accuracy(cache: TextCache, clips: Sequence[int], n: int = 1000, seed: int = 0) -> dict:
    """How well the embeddings tell captions apart (issue acceptance check).

    Samples ``n`` (clip, field, level) captions, mean-pools each over its tokens, and finds each one's
    cosine nearest neighbour among the sample. A hit is the caption itself or one with identical text.
    Also reports the highest cosine to a caption with different text (1.0 = indistinguishable).
    """
    clips = np.asarray(clips)
    rng = np.random.default_rng(seed)
    levels = np.asarray(cache.cached_levels)  # a level subset's cache holds only those
    F, K = cache.rows.shape[1], len(levels)
    total = len(clips) * F * K
    pick = rng.choice(total, size=min(n, total), replace=False)
    c, f, k = clips[pick // (F * K)], (pick // K) % F, levels[pick % K]
    r = cache.rows[c, f, k]
    uniq, inv = np.unique(r, return_inverse=True)
    h = np.asarray(cache.hidden[uniq], np.float32)
    m = np.asarray(cache.mask[uniq], np.float32)
    pooled = (h * m[..., None]).sum(1) / m.sum(1, keepdims=True)
    pooled /= np.linalg.norm(pooled, axis=1, keepdims=True) + 1e-12
    e = pooled[inv]
    sim = e @ e.T
    nn_ = sim.argmax(1)
    texts = np.asarray([cache.texts[i] for i in r], dtype=object)
    hit = (nn_ == np.arange(len(r))) | (texts[nn_] == texts)
    diff = np.where(texts[:, None] != texts[None, :], sim, -np.inf)
    worst = diff.max(1)
    worst = worst[np.isfinite(worst)]
    return {"n": int(len(r)), "accuracy": float(hit.mean()), "distinct_texts": int(len(uniq)),
            "max_cos_to_different_text": float(worst.max()) if len(worst) else None,
            "mean_nearest_cos_to_different_text": float(worst.mean()) if len(worst) else None}
