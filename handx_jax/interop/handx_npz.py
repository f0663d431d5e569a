"""Read and write the official HandX ``.npz`` archives without trusting pickle.

Format (handx-reference.md §1.1): an ``np.savez`` archive of a dict, so each member ``"<key>.npy"`` is a
0-d object array whose pickled payload is a dict. Keys are ``"0"``, ``"1"``, …. Motion archives
(``*_can_pos_all_wotextfeat.npz``) hold ``motion`` ``(60, 2, 21, 3)`` (hand 0 = left, metres) and the
three equally long string lists ``left_annotation``, ``right_annotation``, ``interaction_annotation``.
Generated-motion archives (what ``handx eval run`` reads) may add two optional fields per entry:
``source_clip`` (str, the reference dataset's clip id the entry was generated for) and ``group`` (int,
the generation index for that prompt, 0..G−1). They round-trip through :class:`HandXClip`; the
official loaders ignore unknown keys.
MANO archives (``*_mano.npz``, §1.9) hold ``{left,right}_pose (60, 48)``, ``{left,right}_shape
(60, 10)`` and ``{left,right}_trans (60, 3)``.

Reading never calls plain ``pickle``/``np.load(allow_pickle=True)``: the zip is opened directly, each
``.npy`` header is parsed with ``numpy.lib.format`` and the object payload is unpickled by
:class:`_RestrictedUnpickler` (``handx_jax.infra.safe_pickle``), whose ``find_class`` admits only what NumPy needs
to rebuild arrays, dtypes and scalars, and plain containers. Any other global (``os.system``, ``builtins.eval``, …) is refused before it is
resolved, with a :class:`~handx_jax.infra.errors.DataError` naming the file and key. Every validation error is a
``DataError`` naming the file, the clip key and the field.

Writing produces exactly what ``np.savez(path, **{key: np.array(entry, dtype=object)})`` produces
(same member names, ``ZIP_STORED``, ``format.write_array``), built in memory and written atomically
through :func:`handx_jax.infra.atomic.atomic_write_bytes`, so ``np.load(path, allow_pickle=True)[k].item()``
returns the dicts.
"""

from __future__ import annotations

import io
import os
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np
from numpy.lib import format as npy_format

from handx_jax import skeleton as sk
from handx_jax.infra.atomic import atomic_write_bytes
from handx_jax.infra.errors import DataError
from handx_jax.infra.safe_pickle import RestrictedUnpickler

MOTION_FIELD = "motion"
ANNOTATION_FIELDS = ("left_annotation", "right_annotation", "interaction_annotation")
# Optional per-entry fields written by handx-jax generators for evaluation (``handx eval run``): the
# reference clip id the entry was generated for, and the generation index for that prompt (0..G-1).
# The official loaders read only the fields above and ignore these.
SOURCE_CLIP_FIELD, GROUP_FIELD = "source_clip", "group"
MANO_FIELDS = {
    "left_pose": 48, "right_pose": 48,
    "left_shape": 10, "right_shape": 10,
    "left_trans": 3, "right_trans": 3,
}


# ----------------------------------------------------------------------------------------------
# restricted unpickling

class _RestrictedUnpickler(RestrictedUnpickler):
    """NumPy reconstruction and plain containers only (``handx_jax.infra.safe_pickle``, the one home of
    restricted unpickling); any other global is refused naming the file and key."""

    what = "HandX archives"


def _member_key(name: str, path: Path) -> str:
    if not name.endswith(".npy") or len(name) <= 4:
        raise DataError(f"unexpected archive member {name!r} (expected '<key>.npy' members only)", path=path)
    return name[:-4]


def _load_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path, key: str) -> Any:
    """Parse one ``.npy`` member; object payloads go through the restricted unpickler."""
    try:
        data = zf.read(info)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, NotImplementedError) as e:
        raise DataError(f"cannot read archive member (truncated or corrupt): {e}", path=path, clip=key) from None
    f = io.BytesIO(data)
    try:
        version = npy_format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = npy_format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, fortran, dtype = npy_format.read_array_header_2_0(f)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
    except (ValueError, EOFError, SyntaxError, TypeError) as e:
        raise DataError(f"invalid .npy header: {e}", path=path, clip=key) from None
    if not dtype.hasobject:
        count = int(np.prod(shape))
        raw = f.read(count * dtype.itemsize)
        if len(raw) != count * dtype.itemsize:
            raise DataError("array data is truncated", path=path, clip=key)
        arr = np.frombuffer(raw, dtype=dtype, count=count)
        return arr.reshape(shape[::-1]).T if fortran else arr.reshape(shape)
    try:
        obj = _RestrictedUnpickler(f, path=path, key=key).load()
    except DataError:
        raise
    except Exception as e:  # any failure of a corrupt/truncated payload: EOFError, UnpicklingError, ...
        raise DataError(f"corrupt pickled payload ({type(e).__name__}: {e})", path=path, clip=key) from None
    return obj


def _iter_entries(path: str | os.PathLike) -> Iterator[tuple[str, Any]]:
    """(key, unpickled value) for every member, keys in numeric order when all are integers."""
    path = Path(path)
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile as e:
        raise DataError(f"not a readable .npz/zip archive (truncated or corrupt): {e}", path=path) from None
    except (EOFError, OSError) as e:
        if isinstance(e, FileNotFoundError):
            raise
        raise DataError(f"cannot open archive: {e}", path=path) from None
    with zf:
        infos = [i for i in zf.infolist() if not i.is_dir()]
        keyed = [(_member_key(i.filename, path), i) for i in infos]
        seen: set[str] = set()
        for k, _ in keyed:
            if k in seen:
                raise DataError("duplicate archive member", path=path, clip=k)
            seen.add(k)
        if all(k.isdigit() for k, _ in keyed):
            keyed.sort(key=lambda ki: int(ki[0]))
        for k, info in keyed:
            yield k, _load_member(zf, info, path, k)


def _entry_dict(value: Any, path: Path, key: str) -> dict:
    if isinstance(value, np.ndarray) and value.dtype == object and value.shape == ():
        value = value.item()
    if not isinstance(value, dict):
        what = f"{value.dtype} array of shape {value.shape}" if isinstance(value, np.ndarray) else type(value).__name__
        raise DataError(f"entry is not a dict (0-d object array holding a dict); got {what}", path=path, clip=key)
    return value


def read_npz_dicts(path: str | os.PathLike) -> dict[str, dict]:
    """All entries of a HandX-style archive as ``{key: dict}``, via the restricted loader, unvalidated."""
    p = Path(path)
    return {k: _entry_dict(v, p, k) for k, v in _iter_entries(p)}


# ----------------------------------------------------------------------------------------------
# motion archives

@dataclass(frozen=True, eq=False)
class HandXClip:
    """One entry of a HandX motion archive (§1.1)."""

    key: str
    motion: np.ndarray  # float32 (T, 2, 21, 3), T = 60 in the released data
    left: list[str]
    right: list[str]
    interaction: list[str]
    source_clip: str | None = None  # optional: reference clip id (evaluation; ignored by official loaders)
    group: int | None = None  # optional: generation index for this prompt (evaluation)

    def __post_init__(self) -> None:
        object.__setattr__(self, "key", str(self.key))
        if self.source_clip is not None:
            object.__setattr__(self, "source_clip", str(self.source_clip))
        if self.group is not None:
            object.__setattr__(self, "group", int(self.group))
        object.__setattr__(self, "motion", np.asarray(self.motion, dtype=np.float32))
        for name in ("left", "right", "interaction"):
            object.__setattr__(self, name, list(getattr(self, name)))

    def to_entry(self) -> dict:
        """The dict stored under this key in the official archive (optional fields only when set)."""
        entry = {
            MOTION_FIELD: self.motion,
            "left_annotation": list(self.left),
            "right_annotation": list(self.right),
            "interaction_annotation": list(self.interaction),
        }
        if self.source_clip is not None:
            entry[SOURCE_CLIP_FIELD] = self.source_clip
        if self.group is not None:
            entry[GROUP_FIELD] = self.group
        return entry


def _array_field(d: dict, name: str, shape: tuple[int | None, ...], path: Path, key: str,
                 allow_nonfinite: bool) -> np.ndarray:
    if name not in d:
        raise DataError("missing field", path=path, clip=key, field=name)
    v = d[name]
    if not isinstance(v, np.ndarray):
        try:
            v = np.asarray(v)
        except Exception:
            raise DataError(f"not an array ({type(v).__name__})", path=path, clip=key, field=name) from None
    if v.dtype.kind not in "fiu":
        raise DataError(f"expected a real numeric array, got dtype {v.dtype}", path=path, clip=key, field=name)
    if v.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, v.shape)):
        want = "(" + ", ".join("T" if s is None else str(s) for s in shape) + ")"
        raise DataError(f"wrong shape {tuple(v.shape)}, expected {want}", path=path, clip=key, field=name)
    v = v.astype(np.float32)
    if not allow_nonfinite:
        bad = ~np.isfinite(v)
        if bad.any():
            frames = np.unique(np.argwhere(bad)[:, 0])
            raise DataError(
                f"{int(bad.sum())} non-finite (NaN/inf) values in frames {frames[:10].tolist()}"
                f"{' …' if frames.size > 10 else ''}",
                path=path, clip=key, field=name,
            )
    return v


def _annotations(d: dict, path: Path, key: str) -> list[list[str]]:
    out = []
    for name in ANNOTATION_FIELDS:
        if name not in d:
            raise DataError("missing field", path=path, clip=key, field=name)
        v = d[name]
        if isinstance(v, np.ndarray) and v.ndim == 1:
            v = v.tolist()
        if not isinstance(v, (list, tuple)):
            raise DataError(f"expected a list of strings, got {type(v).__name__}", path=path, clip=key, field=name)
        if len(v) == 0:
            raise DataError("empty annotation list", path=path, clip=key, field=name)
        for i, s in enumerate(v):
            if not isinstance(s, str):
                raise DataError(f"entry {i} is {type(s).__name__}, not a string", path=path, clip=key, field=name)
        out.append([str(s) for s in v])
    lens = [len(v) for v in out]
    if len(set(lens)) != 1:
        raise DataError(
            "annotation lists have unequal lengths "
            + ", ".join(f"{n}={n_}" for n, n_ in zip(ANNOTATION_FIELDS, lens)),
            path=path, clip=key, field="interaction_annotation" if lens[2] != lens[0] else "right_annotation",
        )
    return out


def _optional_fields(d: dict, path: Path, key: str) -> dict:
    out: dict = {}
    if d.get(SOURCE_CLIP_FIELD) is not None:
        v = d[SOURCE_CLIP_FIELD]
        if isinstance(v, np.ndarray) and v.shape == () and v.dtype.kind == "U":
            v = str(v)
        if not isinstance(v, str) or not v:
            raise DataError(f"expected a non-empty string, got {type(v).__name__} {v!r}", path=path, clip=key,
                            field=SOURCE_CLIP_FIELD)
        out["source_clip"] = v
    if d.get(GROUP_FIELD) is not None:
        v = d[GROUP_FIELD]
        if isinstance(v, np.ndarray) and v.shape == ():
            v = v.item()
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise DataError(f"expected a non-negative integer, got {type(v).__name__} {v!r}", path=path, clip=key,
                            field=GROUP_FIELD)
        out["group"] = int(v)
    return out


def _validate_clip(d: dict, path: Path, key: str, clip_len: int | None, allow_nonfinite: bool) -> HandXClip:
    motion = _array_field(d, MOTION_FIELD, (clip_len, sk.NUM_HANDS, sk.NUM_JOINTS, 3), path, key, allow_nonfinite)
    left, right, inter = _annotations(d, path, key)
    return HandXClip(key=key, motion=motion, left=left, right=right, interaction=inter,
                     **_optional_fields(d, path, key))


def read_handx_npz(path: str | os.PathLike, *, clip_len: int | None = sk.CLIP_LEN,
                   allow_nonfinite: bool = False) -> list[HandXClip]:
    """Read an official motion archive (§1.1) safely; clips in key order.

    ``clip_len=None`` accepts any number of frames. NaN/inf motion raises ``DataError`` unless
    ``allow_nonfinite`` (the importer may then cut around defective frames itself).
    """
    p = Path(path)
    return [_validate_clip(_entry_dict(v, p, k), p, k, clip_len, allow_nonfinite) for k, v in _iter_entries(p)]


def _check_key(key: str, path: Path, seen: set[str]) -> None:
    if not key or "/" in key or "\\" in key or key in (".", ".."):
        raise DataError("invalid key for an archive member", path=path, clip=repr(key))
    if key in seen:
        raise DataError("duplicate key", path=path, clip=key)
    seen.add(key)


def _savez_bytes(entries: Iterable[tuple[str, dict]]) -> bytes:
    """What ``np.savez(f, **{k: np.array(d, dtype=object)})`` writes (numpy ``_savez``, uncompressed)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, mode="w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for k, d in entries:
            arr = np.empty((), dtype=object)
            arr[()] = d
            with zf.open(f"{k}.npy", "w", force_zip64=True) as f:
                npy_format.write_array(f, arr, allow_pickle=True)
    return buf.getvalue()


def write_handx_npz(path: str | os.PathLike, clips: Iterable[HandXClip], *, clip_len: int | None = sk.CLIP_LEN,
                    allow_nonfinite: bool = False) -> Path:
    """Write clips as an official motion archive (§1.1), atomically. Clips are validated as on read."""
    p = Path(path)
    seen: set[str] = set()
    entries = []
    for c in clips:
        _check_key(c.key, p, seen)
        entry = _validate_clip(c.to_entry(), p, c.key, clip_len, allow_nonfinite).to_entry()
        entries.append((c.key, entry))
    return atomic_write_bytes(p, _savez_bytes(entries))


# ----------------------------------------------------------------------------------------------
# MANO archives (§1.9)

@dataclass(frozen=True, eq=False)
class HandXManoClip:
    """One entry of a ``*_mano.npz`` archive: per-frame MANO parameters for both hands (§1.1, §1.9).

    Poses are axis-angle, 3 global orient + 45 hand pose, relative to the MANO mean pose.
    """

    key: str
    left_pose: np.ndarray   # (T, 48)
    right_pose: np.ndarray  # (T, 48)
    left_shape: np.ndarray  # (T, 10)
    right_shape: np.ndarray  # (T, 10)
    left_trans: np.ndarray  # (T, 3)
    right_trans: np.ndarray  # (T, 3)


def read_handx_mano_npz(path: str | os.PathLike, *, clip_len: int | None = sk.CLIP_LEN,
                        allow_nonfinite: bool = False) -> list[HandXManoClip]:
    """Read a ``*_mano.npz`` archive with the same restricted loader and validation rules."""
    p = Path(path)
    out = []
    for k, v in _iter_entries(p):
        d = _entry_dict(v, p, k)
        fields = {n: _array_field(d, n, (clip_len, w), p, k, allow_nonfinite) for n, w in MANO_FIELDS.items()}
        lens = {a.shape[0] for a in fields.values()}
        if len(lens) != 1:
            raise DataError(f"MANO fields have different frame counts {sorted(lens)}", path=p, clip=k)
        out.append(HandXManoClip(key=k, **fields))
    return out
