"""The versioned evaluator checkpoint folder (format ``handx-jax-evaluator`` v1): read, load, save.

Folder ``E``, complete once ``evaluator.json`` exists:

    evaluator.json   format, version, evaluator config, text policy, dataset fingerprint + path,
                     encoder folder + fingerprint, tokenizer fingerprint, text-cache fingerprint/dtype/Lmax,
                     training summary (steps, batch, lr, wall time, final losses)
    params.msgpack   Flax-serialised evaluator parameters (final step)
    norm_stats.npz   evaluator_mean/std/eps used to normalise motion features
    eval.json        the Ground Truth row on the training dataset's test split (schema metric names)
    config.json, metrics.jsonl, checkpoints/   the training run (handx_jax.train; resumable)
    reference_cache/ text and GT-motion embeddings of evaluated reference clips, one file per key
                     (``evaluation.reference``; safe to delete, rebuilt on the next evaluation)

:func:`load_evaluator` refuses a folder of another format/version, an encoder whose weights changed,
and (through :meth:`TrainedEvaluator.check_dataset`) a reference dataset other than the one trained on.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from pathlib import Path
from typing import Mapping

import jax
import numpy as np

from handx_jax import representation as rep
from handx_jax.evaluation.features import TextPolicy
from handx_jax.evaluation.model import TrainedEvaluator, param_shapes
from handx_jax.infra.atomic import atomic_write_bytes, atomic_write_json
from handx_jax.infra.checksums import sha256_file
from handx_jax.infra.errors import DataError
from handx_jax.infra.param_files import read_params_msgpack, write_params_msgpack
from handx_jax.infra.readers import read_format_meta, read_npz
from handx_jax.models.evaluator import EvaluatorConfig

FORMAT, FORMAT_VERSION = "handx-jax-evaluator", 1
META_FILE, PARAMS_FILE, STATS_FILE, EVAL_FILE = "evaluator.json", "params.msgpack", "norm_stats.npz", "eval.json"


def _policy_from_json(d: Mapping) -> TextPolicy:
    tl = d.get("train_levels")
    return TextPolicy(max_len=int(d["max_len"]), train_levels=None if tl is None else tuple(int(x) for x in tl),
                      eval_level=int(d["eval_level"]), cache_dtype=str(d.get("cache_dtype", "float16")),
                      caption=str(d.get("caption", "sentinels")))


def read_meta(root: str | os.PathLike) -> dict:
    root = Path(root)
    hint = (" (training has not finished: rerun the same `handx train evaluator` command to resume)"
            if (root / "checkpoints").is_dir() else "")
    return read_format_meta(root / META_FILE, FORMAT, FORMAT_VERSION,
                            missing=f"not an evaluator checkpoint: missing {META_FILE}{hint}",
                            upgrade="; retrain it with `handx train evaluator`")


def evaluator_id(root: str | os.PathLike) -> str:
    """The identity of the scoring function an evaluator folder holds, from its files alone (no JAX, no
    weights loaded): its config and text policy, its text encoder's and tokenizer's fingerprints, the
    bytes of ``params.msgpack`` and the values of ``norm_stats.npz``. Two folders with the same id score
    any motion identically (a copy, the packaged standard evaluator, a moved folder); a retrained one
    gets a new id. ``eval.json`` records it (``_meta.evaluator_id``), so a sweep relaunched with another
    evaluator knows which of its scores are stale (sweeps/launcher.py). The stats are hashed by value
    because ``np.savez`` stamps the write time into the file."""
    root = Path(root)
    meta = read_meta(root)
    h = hashlib.sha256(json.dumps({"config": meta["evaluator_config"], "text": meta["text"],
                                   "encoder": meta["encoder"]["fingerprint"],
                                   "tokenizer": meta["encoder"]["tokenizer_fingerprint"]}, sort_keys=True).encode())
    for name in (PARAMS_FILE, STATS_FILE):
        if not (root / name).is_file():
            raise DataError(f"evaluator folder has no {name}", path=root)
    h.update(sha256_file(root / PARAMS_FILE).encode())
    z = read_npz(root / STATS_FILE)  # garbage, truncated or object arrays: one line naming the file
    for k in sorted(z):
        h.update(k.encode())
        h.update(np.ascontiguousarray(z[k]).tobytes())
    return h.hexdigest()[:16]


def load_evaluator(root: str | os.PathLike, *, encoder=None, batch_size: int = 256) -> TrainedEvaluator:
    """Open an evaluator folder. The encoder folder recorded in it (or ``encoder``: a folder, e.g. after
    a move, or an already loaded FrozenEncoder) must have the recorded weight fingerprint; anything
    else is refused."""
    from handx_jax.text.hf import as_encoder

    root = Path(root)
    meta = read_meta(root)
    cfg_d = dict(meta["evaluator_config"])
    stored_dim = cfg_d.pop("motion_dim", None)  # written by earlier versions; now derived from motion_input
    cfg = EvaluatorConfig(**cfg_d)
    if stored_dim is not None and stored_dim != cfg.motion_dim:
        raise DataError(f"evaluator_config.motion_dim is {stored_dim}, but motion_input {cfg.motion_input!r} has "
                        f"{cfg.motion_dim} features", path=root / META_FILE)
    policy = _policy_from_json(meta["text"])
    enc_dir = Path(meta["encoder"]["path"])  # relative: inside the folder (an imported official evaluator's t5/)
    enc = as_encoder(encoder if encoder is not None else enc_dir if enc_dir.is_absolute() else root / enc_dir)
    enc_path = enc.path
    want = meta["encoder"]["fingerprint"]
    if enc.fingerprint != want:
        raise DataError(f"encoder fingerprint mismatch: this evaluator was trained with text encoder {want}, but "
                        f"{enc_path} has fingerprint {enc.fingerprint} (different weights or config); use the "
                        f"encoder folder it was trained with (--encoder), or retrain the evaluator", path=enc_path)
    if enc.tokenizer.fingerprint != meta["encoder"]["tokenizer_fingerprint"]:
        raise DataError(f"tokenizer fingerprint mismatch: trained with {meta['encoder']['tokenizer_fingerprint']}, "
                        f"{enc_path} has {enc.tokenizer.fingerprint}", path=enc_path)
    stats = rep.NormStats.read(root / STATS_FILE, "evaluator")
    template = param_shapes(cfg, policy.max_len)
    params = read_params_msgpack(root / PARAMS_FILE, template)  # checksum verified; bad files name themselves
    return TrainedEvaluator(cfg=cfg, params=params, stats=stats, encoder=enc, policy=policy, meta=meta, root=root,
                            batch_size=batch_size)


def save_evaluator(root: str | os.PathLike, ev: TrainedEvaluator) -> Path:
    """Write params, stats and (last, marking completeness) evaluator.json into ``root``."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    write_params_msgpack(root / PARAMS_FILE, ev.params)  # with params.msgpack.sha256
    buf = io.BytesIO()
    np.savez(buf, **ev.stats.to_npz_dict("evaluator"))
    atomic_write_bytes(root / STATS_FILE, buf.getvalue())
    atomic_write_json(root / META_FILE, ev.meta)
    ev.root = root
    return root

