"""The on-disk dataset format (format_version 1) and its reader.

A dataset is a directory (docs/architecture.md, "Files on disk"):

    meta.json     format, version, fps, clip_len, num_clips, levels, skeleton, source, fingerprint
    motion.npy    float32 (N, 60, 2, 21, 3), memory-mapped on read
    texts.jsonl   {"id", "left": [...], "right": [...], "interaction": [...]} per clip
    events.jsonl  structured event record per clip (optional)
    splits.json   {"train": [...], "val": [...], "test": [...], "fractions": {"0.05": [...], ...}}
    stats.npz     normalisation statistics of the train split
    report.json   what the build or import cut, and why

Writers fill a temporary directory and rename it into place (``infra.atomic.atomic_dir``), so a dataset on disk
is always complete. Readers validate on open and raise ``DataError`` naming the file and clip.

Identity (issue 14.5). ``fingerprint`` hashes the bytes of motion, texts and splits; a rebuild of the
same recipe on another numpy/BLAS/CPU can move motion floats by rounding and so change it. meta.json
therefore also records the ``recipe`` (what was built: generator version, seed, clip count, options;
for imports the source files' hashes) and an ``identity``: hashes of the discrete content (clip ids,
captions, the clip ids of each split and the data fractions) and per-split motion moments (float64
mean and std of each of the 126 coordinates). :func:`check_compatible` is the one test every trained
artefact (evaluator, text cache) applies to a dataset: identical fingerprint, or same recipe + same
discrete content + motion moments within ``MOTION_ATOL`` (accepted, and reported as a rounding-only
difference); anything else is refused with the reason.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.dataset.parallel import map_ordered
from handx_jax.infra.atomic import atomic_dir, atomic_write_json
from handx_jax.infra.diskspace import check_free_space, disk_full_as_error
from handx_jax.infra.errors import DataError
from handx_jax.infra.npy_writer import NpyWriter
from handx_jax.infra.readers import get_field, read_format_meta, read_json, read_jsonl, read_npy, read_npz, require_dir

if TYPE_CHECKING:
    from handx_jax.representation import NormPreset

FORMAT = "handx-jax-dataset"
IDENTITY_VERSION = 1
# Motion moments of two builds of one recipe may differ by float rounding (~1e-7 m for float32 joints);
# 10 µm is far above that and far below any change of the motion itself.
MOTION_ATOL = 1e-5
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
    """Every clip has the three fields, each a list of the same number of non-empty strings, and every
    clip has as many caption levels as the first (meta.json's ``levels``; level indices must mean
    the same thing on every clip)."""
    levels = None
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
        if levels is None:
            levels, first = n["left"], t.get("id", i)
        elif n["left"] != levels:
            raise DataError(f"{n['left']} caption levels, but clip {first} has {levels}; every clip needs the "
                            "same number of levels", path=path, clip=t.get("id", i))


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


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def _ids_digest(ids: Sequence[str]) -> str:
    return _digest("\n".join(ids).encode("utf-8"))


def _motion_moments(motion: np.ndarray, idx: np.ndarray) -> dict:
    """Float64 mean and std of each of the 2·21·3 coordinates over the clips ``idx`` and their frames."""
    s = np.zeros(motion.shape[2:], np.float64)
    ss = np.zeros_like(s)
    for c in range(0, len(idx), 1024):
        m = np.asarray(motion[np.sort(idx[c:c + 1024])], np.float64)
        s += m.sum((0, 1))
        ss += (m * m).sum((0, 1))
    cnt = max(len(idx) * motion.shape[1], 1)
    mean = s / cnt
    std = np.sqrt(np.maximum(ss / cnt - mean * mean, 0.0))
    return {"clips": int(len(idx)), "mean": [float(f"{v:.9g}") for v in mean.ravel()],
            "std": [float(f"{v:.9g}") for v in std.ravel()]}


def dataset_identity(motion: np.ndarray, texts_jsonl: bytes, ids: Sequence[str], split_doc: dict) -> dict:
    """The identity recorded in meta.json: hashes of the discrete content and the split motion moments."""
    return {
        "version": IDENTITY_VERSION,
        "ids": _ids_digest(ids),
        "captions": _digest(texts_jsonl),
        "splits": {k: _ids_digest([ids[i] for i in split_doc[k]]) for k in SPLITS},
        "fractions": _digest(json.dumps(split_doc.get("fractions", {}), sort_keys=True).encode()),
        "motion": {k: _motion_moments(motion, np.asarray(split_doc[k], np.int64)) for k in SPLITS},
    }


def dataset_record(ds: "Dataset") -> dict:
    """What a trained artefact (evaluator, text cache) records about its dataset for check_compatible."""
    return {"fingerprint": ds.fingerprint, "recipe": ds.meta.get("recipe"), "identity": ds.meta.get("identity")}


@dataclass(frozen=True)
class Compatibility:
    status: str   # "identical" (same bytes) or "rounding" (same recipe and discrete content, floats within tolerance)
    message: str  # empty when identical
    max_motion_diff_m: float = 0.0


COMPAT_PARTS = ("recipe", "ids", "splits", "captions", "motion")


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(d, dict):
        out: dict[str, Any] = {}
        for k, v in d.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: d}


def check_compatible(trained: dict | None, ds: "Dataset", *, what: str = "this model", made: str = "made from",
                     parts: Sequence[str] = COMPAT_PARTS, fix: str = "") -> Compatibility:
    """Is ``ds`` the dataset that ``trained`` (a :func:`dataset_record`) was made from?

    Accepted: the same content fingerprint ("identical"); or, when both carry a recipe and identity,
    the same recipe, clip ids, split membership, data fractions and captions, with per-split motion
    moments within ``MOTION_ATOL`` ("rounding": a rebuild on another numpy/BLAS/CPU; the message says
    by how much). Refused with a ``DataError`` naming the first difference: another recipe, other clips
    or captions, a changed split (a test clip the artefact may have trained on), or motion beyond
    rounding. ``parts`` restricts the comparison (the text cache needs only ids and captions).
    """
    trained = trained or {}
    want, have = trained.get("fingerprint"), ds.fingerprint
    if want is None or want == have:
        return Compatibility("identical", "")
    tid, did = trained.get("identity"), ds.meta.get("identity")
    hint = f"; {fix}" if fix else ""

    def refuse(reason: str) -> DataError:
        return DataError(f"dataset fingerprint mismatch: {what} was {made} dataset {want}, but this dataset is "
                         f"{have}: {reason}{hint}", path=ds.root)

    if not tid or not did or tid.get("version") != did.get("version"):
        raise refuse("the content differs and one of them records no comparable identity (built before "
                     "recipes were recorded), so only identical bytes are accepted")
    if "recipe" in parts:
        tr, dr = trained.get("recipe"), ds.meta.get("recipe")
        if not tr or not dr:
            raise refuse("no recipe recorded, so only identical bytes are accepted")
        a, b = _flat(tr), _flat(dr)
        diff = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        if diff:
            shown = ", ".join(f"{k}: {a.get(k)!r} -> {b.get(k)!r}" for k in diff[:4])
            raise refuse(f"it was built from a different recipe ({shown}{' ...' if len(diff) > 4 else ''})")
    if "ids" in parts and tid["ids"] != did["ids"]:
        raise refuse("the clip ids differ (another clip set: a different build cut or filtered other clips)")
    if "splits" in parts:
        for k in ("test", "val", "train"):
            if tid["splits"][k] != did["splits"][k]:
                raise refuse(f"the {k} split holds other clips than when {what} was made (a changed or "
                             "overlapping test split would score it on clips it may have trained on)")
        if tid["fractions"] != did["fractions"]:
            raise refuse("the data-fraction subsets of the train split differ")
    if "captions" in parts and tid["captions"] != did["captions"]:
        raise refuse("the captions differ")
    worst = 0.0
    if "motion" in parts:
        for k in SPLITS:
            a, b = tid["motion"][k], did["motion"][k]
            if a["clips"] != b["clips"]:
                raise refuse(f"the {k} split has {b['clips']} clips, expected {a['clips']}")
            for q in ("mean", "std"):
                if a["clips"]:
                    worst = max(worst, float(np.max(np.abs(np.subtract(a[q], b[q])))))
        if not worst <= MOTION_ATOL:
            raise refuse(f"the motion differs beyond float rounding (per-split coordinate moments differ by up to "
                         f"{worst:.3g} m, tolerance {MOTION_ATOL:g} m)")
    return Compatibility("rounding", f"note: dataset {have} differs from the dataset {what} was {made} ({want}) "
                         f"only by float "
                         f"rounding (same recipe, clip ids, splits and captions; motion moments within "
                         f"{worst:.2g} m, tolerance {MOTION_ATOL:g} m): accepted", worst)


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
    stats: bool | Sequence[NormPreset] = True,
    workers: int = 1,
    recipe: dict | None = None,
    arrays: dict[str, np.ndarray] | None = None,
    records: dict[str, Sequence[Any]] | None = None,
) -> Path:
    """Write a complete dataset atomically. ``motion`` may be a memory-mapped array.

    ``arrays`` ({name: array with one row per clip}) and ``records`` ({name: one JSON record per clip}) are a
    corpus's own per-clip annotations, written as ``name.npy`` and ``name.jsonl`` beside the motion (the
    hand–object corpus's object states, held parts and contact maps: synthesis/object_build.py).

    Without ``splits`` every clip goes to train. Fractions are nested subsets of train. ``stats``: the
    normalisation presets whose statistics ``stats.npz`` holds, given by the caller (the command layer passes
    what the family registry declares, ``families.norm_presets``); True: every preset defined
    (``representation.norm_presets``), False: no ``stats.npz``. ``workers`` processes compute the statistics
    (the numbers do not depend on it). ``recipe`` is what the data was made from (check_compatible compares
    it); by default the content itself.
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
    # Plain writes, not a memory map: a full disk then raises ENOSPC (DiskFullError naming the file, and
    # atomic_dir removes the half-written folder) instead of killing the process with SIGBUS.
    check_free_space(out, motion.size * 4)
    with atomic_dir(out, overwrite=overwrite) as tmp:
        with NpyWriter(tmp / "motion.npy", np.float32, motion.shape) as w:
            for s in range(0, n, 4096):
                w.append(motion[s:s + 4096])
        _write_lines(tmp / "texts.jsonl", texts)
        if events is not None:
            _write_lines(tmp / "events.jsonl", events)
        for name, a in (arrays or {}).items():
            if len(a) != n:
                raise DataError(f"{n} motion clips but {len(a)} rows of {name}")
            with disk_full_as_error(tmp / f"{name}.npy"):
                np.save(tmp / f"{name}.npy", np.ascontiguousarray(a))
        for name, rows in (records or {}).items():
            if len(rows) != n:
                raise DataError(f"{n} motion clips but {len(rows)} records of {name}")
            _write_lines(tmp / f"{name}.jsonl", rows)
        atomic_write_json(tmp / "splits.json", split_doc, indent=None)
        if report is not None:
            atomic_write_json(tmp / "report.json", report)
        presets = _stats_presets(stats)
        if presets and split_doc["train"]:
            _write_stats(tmp, split_doc["train"], presets, workers)
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
            "recipe": recipe or {"kind": "content", "fingerprint": compute_fingerprint(tmp)},
            "identity": dataset_identity(motion, (tmp / "texts.jsonl").read_bytes(), ids, split_doc),
            "fingerprint": compute_fingerprint(tmp),
        }
        atomic_write_json(tmp / "meta.json", meta)
    return out


def _write_lines(path: Path, rows: Sequence[Any]) -> None:
    # Streamed (the file is inside a temporary directory that is renamed only when complete).
    with disk_full_as_error(path), open(path, "w", encoding="utf-8") as f:
        for r in rows:
            f.write(json.dumps(r, separators=(",", ":"), ensure_ascii=False) + "\n")


STATS_CHUNK = 2048  # clips per statistics task; fixed, so the float64 sums are added in one order


def _stats_presets(stats: bool | Sequence[NormPreset]) -> tuple[NormPreset, ...]:
    if stats is True:
        from handx_jax import representation as rep

        return tuple(rep.norm_presets().values())
    return tuple(stats or ())


def _write_stats(root: Path, train_idx: Sequence[int], presets: Sequence[NormPreset], workers: int = 1) -> None:
    """stats.npz: mean/std of each preset's representation over the train split (§1.8), in clip chunks whose
    float64 moments are summed in chunk order, so ``workers`` changes the time but not one bit."""
    from handx_jax import representation as rep

    idx = np.asarray(sorted(train_idx))
    tasks = (idx[s:s + STATS_CHUNK] for s in range(0, len(idx), STATS_CHUNK))
    totals: dict[str, tuple] = {}
    # Workers get the presets by name (a featuriser may be a lambda, which does not pickle), and the modules of
    # their featurisers to import first: a preset is known by its name once its module has run (a forkserver
    # worker starts without a family's own).
    names = tuple(dict.fromkeys(p.name for p in presets))
    modules = tuple(sorted({p.featurize.__module__ for p in presets}))
    chunk = functools.partial(_chunk_moments, str(root / "motion.npy"), names, modules)
    for moments in map_ordered(chunk, tasks, workers):
        for name, m in moments.items():
            totals[name] = m if name not in totals else tuple(a + b for a, b in zip(totals[name], m))
    arrays = {}
    for name, (s, ss, n) in totals.items():
        st = rep.stats_from_moments(name, s, ss, n)
        arrays[f"{name}_mean"] = st.mean
        arrays[f"{name}_std"] = st.std
    with disk_full_as_error(root / "stats.npz"):
        np.savez(root / "stats.npz", **arrays)


def _chunk_moments(motion_path: str, names: tuple[str, ...], modules: tuple[str, ...], idx: np.ndarray
                   ) -> dict[str, tuple[np.ndarray, np.ndarray, int]]:
    import importlib

    from handx_jax import representation as rep

    for module in modules:
        importlib.import_module(module)
    m = np.asarray(np.load(motion_path, mmap_mode="r")[idx], dtype=np.float64)
    return {name: rep.preset_moments(name, rep.norm_preset(name).featurize(m)) for name in names}


def _index_list(idx: Any, field: str, n: int, path: Path) -> np.ndarray:
    if not isinstance(idx, list) or not all(type(i) is int and 0 <= i < n for i in idx):
        raise DataError(f"must be a list of clip indices in [0, {n})", path=path, field=field)
    return np.asarray(idx, np.int64)


def read_splits(path: Path, n: int) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """splits.json's split and data-fraction index lists, each checked: whole clip indices below ``n``."""
    sp = read_json(path, expect=dict)
    splits = {k: _index_list(sp.get(k, []), k, n, path) for k in SPLITS}
    fr = get_field(sp, "fractions", dict, path=path, default={})
    return splits, {k: _index_list(v, f"fractions[{k!r}]", n, path) for k, v in fr.items()}


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
        root = require_dir(root, "dataset directory")
        meta = read_format_meta(root / "meta.json", FORMAT, FORMAT_VERSION,
                                missing="missing meta.json: not a handx-jax dataset")
        mp = root / "meta.json"
        n = get_field(meta, "num_clips", int, path=mp, check=lambda v: v >= 0, must="a count >= 0")
        clip_len = get_field(meta, "clip_len", int, path=mp, check=lambda v: v >= 1, must="a frame count >= 1")
        motion = read_npy(root / "motion.npy", kind="f", mmap=True)
        if motion.shape != (n, clip_len, 2, sk.NUM_JOINTS, 3):
            raise DataError(f"shape {motion.shape} does not match meta.json (num_clips={n})",
                            path=root / "motion.npy")
        texts = read_jsonl(root / "texts.jsonl")
        if len(texts) != n:
            raise DataError(f"{len(texts)} text records for {n} clips", path=root / "texts.jsonl")
        validate_texts(texts, root / "texts.jsonl")
        splits, fractions = read_splits(root / "splits.json", n)
        return cls(root=root, meta=meta, motion=motion, texts=texts, splits=splits, fractions=fractions)

    def __len__(self) -> int:
        return self.motion.shape[0]

    @property
    def fingerprint(self) -> str:
        return get_field(self.meta, "fingerprint", str, path=self.root / "meta.json")

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
        return read_npz(p, kind="f")

    @cached_property
    def report(self) -> dict:
        p = self.root / "report.json"
        return read_json(p, expect=dict, default={})

    def captions(self, level: int = -1) -> list[tuple[str, str, str]]:
        """(left, right, interaction) per clip at one level (−1 = most detailed)."""
        return [(t["left"][level], t["right"][level], t["interaction"][level]) for t in self.texts]
