"""The on-disk dataset format (format_version 1) and its reader.

A dataset is a directory (see docs/architecture.md for the table):

    meta.json     format, version, fps, clip_len, num_clips, levels, skeleton, source, fingerprint
    motion.npy    float32 (N, 60, 2, 21, 3), memory-mapped on read
    texts.jsonl   {"id", "left": [...], "right": [...], "interaction": [...]} per clip
    events.jsonl  structured event record per clip (optional)
    splits.json   {"train": [...], "val": [...], "test": [...], "fractions": {"0.05": [...], ...}}
    stats.npz     normalisation statistics of the train split
    report.json   what the build or import cut, and why

Writers fill a temporary directory and rename it into place (``io.atomic_dir``), so a dataset on disk
is always complete. Readers validate on open and raise ``DataError`` naming the file and clip.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.data.parallel import map_ordered
from handx_jax.io import DataError, atomic_dir, atomic_write_json, read_format_meta, read_jsonl

FORMAT = "handx-jax-dataset"
FORMAT_VERSION = 1
TEXT_FIELDS = ("left", "right", "interaction")
SPLITS = ("train", "val", "test")
DEFAULT_FRACTIONS = (0.05, 0.2, 1.0)


def fraction_key(f: float) -> str:
    return f"{float(f):g}"


def nested_fractions(train_idx: np.ndarray, fractions: Sequence[float], seed: int) -> dict[str, list[int]]:
    """Nested uniform subsets of the train split: one fixed permutation, prefixes of it.

    Because every subset is a prefix of the same permutation, 5% ⊂ 20% ⊂ 100% by construction, and
    the validation split is untouched by the choice of fraction.
    """
    perm = np.random.default_rng([seed, 0x5EED]).permutation(np.asarray(train_idx))
    out = {}
    for f in sorted(fractions):
        if not 0 < f <= 1:
            raise ValueError(f"data fraction must be in (0, 1], got {f}")
        n = max(1, int(round(f * len(perm)))) if len(perm) else 0
        out[fraction_key(f)] = sorted(perm[:n].tolist())
    return out


def validate_texts(texts: Sequence[dict], path: str | os.PathLike = "texts") -> None:
    for i, t in enumerate(texts):
        for k in TEXT_FIELDS:
            v = t.get(k)
            if not isinstance(v, list) or not v:
                raise DataError("missing or empty annotation list", path=path, clip=t.get("id", i), field=k)
            if not all(isinstance(s, str) and s.strip() for s in v):
                raise DataError("annotations must be non-empty strings", path=path, clip=t.get("id", i), field=k)
        n = {k: len(t[k]) for k in TEXT_FIELDS}
        if len(set(n.values())) != 1:
            raise DataError(f"annotation lists differ in length {n}", path=path, clip=t.get("id", i))


def validate_motion(motion: np.ndarray, path: str | os.PathLike = "motion", ids: Sequence[str] | None = None) -> None:
    if motion.ndim != 5 or motion.shape[2:] != (2, sk.NUM_JOINTS, 3):
        raise DataError(f"expected shape (N, T, 2, 21, 3), got {motion.shape}", path=path)
    # Check finiteness chunk-wise so a memory-mapped array never has to fit in memory.
    for s in range(0, motion.shape[0], 4096):
        ok = np.isfinite(np.asarray(motion[s:s + 4096])).reshape(min(4096, motion.shape[0] - s), -1).all(1)
        if not ok.all():
            i = s + int(np.flatnonzero(~ok)[0])
            raise DataError("motion contains NaN or inf", path=path, clip=ids[i] if ids else i)


def _sha256_file(path: Path, h: "hashlib._Hash") -> None:
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)


def compute_fingerprint(root: Path) -> str:
    """Content hash of motion, texts and splits: what a cache or evaluator must match."""
    h = hashlib.sha256(f"{FORMAT}/{FORMAT_VERSION}".encode())
    for name in ("motion.npy", "texts.jsonl", "splits.json"):
        _sha256_file(root / name, h)
    return h.hexdigest()[:16]


def write_dataset(
    out: str | os.PathLike,
    motion: np.ndarray,
    texts: Sequence[dict],
    *,
    splits: dict[str, Sequence[int]] | None = None,
    events: Sequence[dict] | None = None,
    source: dict | None = None,
    report: dict | None = None,
    fractions: Sequence[float] = DEFAULT_FRACTIONS,
    seed: int = 0,
    overwrite: bool = False,
    stats: bool = True,
    workers: int = 1,
) -> Path:
    """Write a complete dataset atomically. ``motion`` may be a memory-mapped array.

    Without ``splits`` every clip goes to train. Fractions are nested subsets of train. ``workers``
    processes compute the normalisation statistics (the numbers do not depend on it).
    """
    motion = np.asarray(motion) if not isinstance(motion, np.memmap) else motion
    n = motion.shape[0]
    ids = [t.get("id", str(i)) for i, t in enumerate(texts)]
    if len(texts) != n:
        raise DataError(f"{n} motion clips but {len(texts)} text records")
    if events is not None and len(events) != n:
        raise DataError(f"{n} motion clips but {len(events)} event records")
    validate_motion(motion, ids=ids)
    validate_texts(texts)
    splits = {k: list(map(int, splits.get(k, []))) for k in SPLITS} if splits else {
        "train": list(range(n)), "val": [], "test": []}
    seen = np.zeros(n, np.int64)
    for k in SPLITS:
        idx = np.asarray(splits[k], np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= n):
            raise DataError(f"split {k!r} has indices outside [0, {n})")
        np.add.at(seen, idx, 1)
    if (seen > 1).any():
        raise DataError(f"clip {ids[int(np.flatnonzero(seen > 1)[0])]} appears in more than one split")
    split_doc = dict(splits)
    split_doc["fractions"] = nested_fractions(np.asarray(splits["train"]), fractions, seed)
    levels = len(texts[0]["left"]) if n else 0

    out = Path(out)
    with atomic_dir(out, overwrite=overwrite) as tmp:
        mm = np.lib.format.open_memmap(tmp / "motion.npy", mode="w+", dtype=np.float32, shape=motion.shape)
        for s in range(0, n, 4096):
            mm[s:s + 4096] = motion[s:s + 4096]
        mm.flush()
        del mm
        _write_lines(tmp / "texts.jsonl", texts)
        if events is not None:
            _write_lines(tmp / "events.jsonl", events)
        atomic_write_json(tmp / "splits.json", split_doc, indent=None)
        if report is not None:
            atomic_write_json(tmp / "report.json", report)
        if stats and split_doc["train"]:
            _write_stats(tmp, split_doc["train"], workers)
        meta = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "fps": sk.FPS,
            "clip_len": int(motion.shape[1]),
            "num_clips": int(n),
            "levels": levels,
            "split_sizes": {k: len(split_doc[k]) for k in SPLITS},
            "skeleton": {"joint_names": list(sk.JOINT_NAMES), "chains": {k: list(v) for k, v in sk.CHAINS.items()},
                         "hands": list(sk.HAND_NAMES), "units": "m"},
            "source": source or {},
            "fingerprint": compute_fingerprint(tmp),
        }
        atomic_write_json(tmp / "meta.json", meta)
    return out


def _write_lines(path: Path, rows: Sequence[Any]) -> None:
    # Streamed (the file is inside a temporary directory that is renamed only when complete).
    with open(path, "w", encoding="utf-8") as f:
        for r in rows:
            f.write(json.dumps(r, separators=(",", ":"), ensure_ascii=False) + "\n")


STATS_CHUNK = 2048  # clips per statistics task; fixed, so the float64 sums are added in one order


def _write_stats(root: Path, train_idx: Sequence[int], workers: int = 1) -> None:
    """stats.npz: mean/std of each representation over the train split (§1.8), in clip chunks whose
    float64 moments are summed in chunk order, so ``workers`` changes the time but not one bit."""
    from handx_jax import representation as rep

    idx = np.asarray(sorted(train_idx))
    tasks = (idx[s:s + STATS_CHUNK] for s in range(0, len(idx), STATS_CHUNK))
    totals: dict[str, tuple] = {}
    for moments in map_ordered(functools.partial(_chunk_moments, str(root / "motion.npy")), tasks, workers):
        for name, m in moments.items():
            totals[name] = m if name not in totals else tuple(a + b for a, b in zip(totals[name], m))
    arrays = {}
    for name, (s, ss, n) in totals.items():
        st = rep.stats_from_moments(name, s, ss, n)
        arrays[f"{name}_mean"] = st.mean
        arrays[f"{name}_std"] = st.std
    np.savez(root / "stats.npz", **arrays)


def _chunk_moments(motion_path: str, idx: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, int]]:
    from handx_jax import representation as rep

    m = np.asarray(np.load(motion_path, mmap_mode="r")[idx], dtype=np.float64)
    return {name: rep.preset_moments(name, fn(m))
            for name, fn in (("diffusion", rep.to_diffusion), ("ar", rep.to_ar), ("evaluator", rep.to_evaluator))}


@dataclass
class Dataset:
    """A dataset directory opened for reading. ``motion`` is memory-mapped."""

    root: Path
    meta: dict
    motion: np.ndarray
    texts: list[dict]
    splits: dict[str, np.ndarray]
    fractions: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def open(cls, root: str | os.PathLike) -> "Dataset":
        root = Path(root)
        if not root.is_dir():
            raise DataError("dataset directory does not exist", path=root)
        meta = read_format_meta(root / "meta.json", FORMAT, FORMAT_VERSION,
                                missing="missing meta.json: not a handx-jax dataset")
        try:
            motion = np.load(root / "motion.npy", mmap_mode="r")
        except FileNotFoundError:
            raise DataError("missing motion.npy", path=root) from None
        except ValueError as e:
            raise DataError(f"corrupt or truncated array ({e})", path=root / "motion.npy") from None
        n = meta["num_clips"]
        if motion.shape != (n, meta["clip_len"], 2, sk.NUM_JOINTS, 3):
            raise DataError(f"shape {motion.shape} does not match meta.json (num_clips={n})",
                            path=root / "motion.npy")
        texts = read_jsonl(root / "texts.jsonl")
        if len(texts) != n:
            raise DataError(f"{len(texts)} text records for {n} clips", path=root / "texts.jsonl")
        validate_texts(texts, root / "texts.jsonl")
        sp = json.loads((root / "splits.json").read_text())
        splits = {k: np.asarray(sp.get(k, []), np.int64) for k in SPLITS}
        fractions = {k: np.asarray(v, np.int64) for k, v in sp.get("fractions", {}).items()}
        return cls(root=root, meta=meta, motion=motion, texts=texts, splits=splits, fractions=fractions)

    def __len__(self) -> int:
        return self.motion.shape[0]

    @property
    def fingerprint(self) -> str:
        return self.meta["fingerprint"]

    @property
    def ids(self) -> list[str]:
        return [t["id"] for t in self.texts]

    def verify(self) -> None:
        """Recompute the content hash; raise if the files changed since they were written."""
        fp = compute_fingerprint(self.root)
        if fp != self.fingerprint:
            raise DataError(f"content fingerprint {fp} does not match meta.json ({self.fingerprint}): "
                            "the dataset was modified after it was written", path=self.root)

    def split(self, name: str, fraction: float = 1.0) -> np.ndarray:
        """Clip indices of a split; for train, the nested data-fraction subset."""
        if name not in SPLITS:
            raise KeyError(f"unknown split {name!r}; choose from {SPLITS}")
        if name == "val" and not len(self.splits["val"]) and self.meta.get("source", {}).get("val_is_test"):
            return self.splits["test"]  # official releases validate on the test file (reference §1.4)
        if name != "train" or fraction == 1.0:
            return self.splits[name]
        key = fraction_key(fraction)
        if key not in self.fractions:
            raise KeyError(f"data fraction {fraction} was not built; available: {sorted(self.fractions)}")
        return self.fractions[key]

    @cached_property
    def events(self) -> list[dict] | None:
        p = self.root / "events.jsonl"
        return read_jsonl(p) if p.exists() else None

    @cached_property
    def stats(self) -> dict[str, np.ndarray]:
        p = self.root / "stats.npz"
        if not p.exists():
            raise DataError("missing stats.npz (dataset has no train split?)", path=self.root)
        with np.load(p, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    @cached_property
    def report(self) -> dict:
        p = self.root / "report.json"
        return json.loads(p.read_text()) if p.exists() else {}

    def captions(self, level: int = -1) -> list[tuple[str, str, str]]:
        """(left, right, interaction) per clip at one level (−1 = most detailed)."""
        return [(t["left"][level], t["right"][level], t["interaction"][level]) for t in self.texts]
