"""Reference embeddings (captions and GT motion of the reference clips), cached in the evaluator folder."""

from __future__ import annotations

import hashlib
import io
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import jax
import numpy as np

from handx_jax.evaluation.features import joined_caption
from handx_jax.evaluation.model import TrainedEvaluator
from handx_jax.infra.atomic import atomic_write_bytes
from handx_jax.infra.errors import DataError

# Every evaluation of a sweep scores against the same reference: the captions of the reference clips at
# the evaluation level and their GT motion. Embedding them (the captions through the frozen T5 on the
# fly) costs far more than embedding the generated motion and computing the metrics, so the first
# evaluation stores them in ``E/reference_cache/<key hash>.npz`` and later ones read them back. The key
# holds everything the embeddings depend on (evaluator and encoder fingerprints, text policy, batch
# size, hashes of the exact captions and GT motion, clip indices, dataset fingerprint, evaluation level,
# JAX backend), so a cached file is bitwise what the uncached computation gives on the machine that
# wrote it, and anything else (another dataset, level, subset, retrained evaluator) misses. The key
# leaves out the host and JAX version on purpose: the CPU nodes of a sweep then share one fixed
# reference instead of each recomputing it up to float rounding.

REFERENCE_CACHE_DIR = "reference_cache"
REFERENCE_CACHE_VERSION = 1


@dataclass
class ReferenceEmbeddings:
    """μ-embeddings ``(N, latent)`` of the reference captions and GT motion of one evaluation.

    ``status``: "hit" (read from the cache), "miss" (computed, then written), "off" (computed, no cache
    folder), "unwritable" (computed; the cache folder could not be written, e.g. a read-only evaluator).
    ``seconds``: {"text", "motion"}; a hit books its key hashing and read time under "text".
    """

    text_NxD: np.ndarray
    motion_NxD: np.ndarray
    status: str
    seconds: dict
    path: Path | None = None


def _digest(*chunks: bytes) -> str:
    h = hashlib.sha256()
    for c in chunks:
        h.update(c)
    return h.hexdigest()[:16]


def reference_key(ev: TrainedEvaluator, texts: Sequence[str], gt_NxTx2x21x3: np.ndarray,
                  provenance: Mapping[str, Any] | None = None) -> dict:
    """The cache key of the reference embeddings of joined captions ``texts`` and GT motion.

    The batch size is part of it because the text side pads each chunk to its own length bucket, which
    moves embeddings by float rounding; ``provenance`` (dataset fingerprint, evaluation level, clips) is
    redundant with the content hashes but makes a file's origin readable and keeps datasets apart.
    """
    return {
        "version": REFERENCE_CACHE_VERSION,
        "evaluator": ev.fingerprint,
        "encoder": ev.encoder.fingerprint,
        "tokenizer": ev.encoder.tokenizer.fingerprint,
        "text_policy": {"max_len": ev.policy.max_len, "cache_dtype": ev.policy.cache_dtype},
        "batch_size": int(ev.batch_size),
        "n": len(texts),
        "captions": _digest(json.dumps(list(texts)).encode()),
        "motion": _digest(np.ascontiguousarray(gt_NxTx2x21x3, np.float32).tobytes()),
        "provenance": dict(provenance or {}),
        "backend": jax.default_backend(),
    }


def _key_json(key: Mapping) -> str:
    return json.dumps(key, sort_keys=True)


def read_reference_cache(path: Path, key: Mapping, latent: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(text, motion) from ``path`` if it holds exactly ``key``; None when absent, unreadable or stale."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != _key_json(key):
                return None
            text, motion = z["text_NxD"], z["motion_NxD"]
    except Exception:  # noqa: BLE001  (missing, truncated, not a zip, missing arrays: all just a miss)
        return None
    want = (int(key["n"]), latent)
    if text.shape != want or motion.shape != want or text.dtype != np.float32 or motion.dtype != np.float32:
        return None
    if not (np.isfinite(text).all() and np.isfinite(motion).all()):  # corrupt (or written by older code from a
        print(f"handx: reference cache {path} holds non-finite values; recomputing it", file=sys.stderr)  # NaN run)
        return None
    return text, motion


def write_reference_cache(path: Path, key: Mapping, text_NxD: np.ndarray, motion_NxD: np.ndarray) -> bool:
    """Atomically write the cache file (concurrent evaluations race harmlessly); False if it cannot be. Only
    finite embeddings are written (a cache is read back as the truth by every later evaluation)."""
    if not (np.isfinite(text_NxD).all() and np.isfinite(motion_NxD).all()):
        return False
    buf = io.BytesIO()
    np.savez(buf, key=np.asarray(_key_json(key)), text_NxD=np.asarray(text_NxD, np.float32),
             motion_NxD=np.asarray(motion_NxD, np.float32))
    try:
        atomic_write_bytes(path, buf.getvalue())
    except OSError:
        return False
    return True


def _cache_folder(ev: TrainedEvaluator, cache: bool | str | os.PathLike) -> Path | None:
    if cache is False or cache is None:
        return None
    if cache is True:
        return None if ev.root is None else Path(ev.root) / REFERENCE_CACHE_DIR
    return Path(cache)


def reference_embeddings(ev: TrainedEvaluator, prompts: tuple[Sequence[str], Sequence[str], Sequence[str]],
                         gt_NxTx2x21x3: np.ndarray, *, provenance: Mapping[str, Any] | None = None,
                         cache: bool | str | os.PathLike = True) -> ReferenceEmbeddings:
    """Text μ of the (left, right, interaction) ``prompts`` and motion μ of their GT clips, cached.

    ``cache``: True = the evaluator folder's ``reference_cache/`` (no cache for an evaluator without a
    folder), False = compute without reading or writing any cache, a path = that folder.
    """
    gt = np.asarray(gt_NxTx2x21x3, np.float32)
    folder = _cache_folder(ev, cache)
    t0 = time.perf_counter()
    key = path = None
    if folder is not None:
        key = reference_key(ev, [joined_caption(*p, ev.policy.caption) for p in zip(*prompts)], gt, provenance)
        path = folder / f"{_digest(_key_json(key).encode())}.npz"
        hit = read_reference_cache(path, key, ev.cfg.latent)
        if hit is not None:
            return ReferenceEmbeddings(hit[0], hit[1], "hit", {"text": time.perf_counter() - t0, "motion": 0.0},
                                       path)
    text = ev.embed_text(*prompts)
    t1 = time.perf_counter()
    motion = ev.embed_motion(gt)
    t2 = time.perf_counter()
    for what, emb in (("captions", text), ("ground-truth motion", motion)):
        if not np.isfinite(emb).all():
            raise DataError(f"the evaluator's embeddings of the reference {what} are not finite (NaN or inf): its "
                            "weights or statistics are broken; nothing was cached", path=ev.root)
    status = "off"
    if path is not None:
        status = "miss" if write_reference_cache(path, key, text, motion) else "unwritable"
    return ReferenceEmbeddings(text, motion, status, {"text": t1 - t0, "motion": t2 - t1}, path)
