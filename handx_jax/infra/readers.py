"""The one reader of the ``.npz``, ``.npy``, JSON and JSON-lines files the project loads (issue 54).

Every failure becomes a :class:`~handx_jax.infra.errors.DataError` naming the file and, where known, the field, so
the command line prints one line and exits 2 (``handx_jax.cli``):

- a missing file, a directory where a file goes, a symlink loop, an unreadable file;
- a truncated or garbage file (bytes that are not NumPy's format or not JSON);
- JSON of the wrong shape (``[]`` where an object is expected), a missing key, a value of the wrong type;
- an array of the wrong dtype, and arrays of Python objects.

Arrays of Python objects are refused from their header, before any byte of them is read: they are
pickles, and NumPy's own error for them suggests unpickling, which no file of this project needs and a
crafted file would abuse. Nothing here ever unpickles.

    doc = read_json(p, expect=dict)                  # {} / [] / "..." of the wrong kind: one line naming p
    n = get_field(doc, "num_clips", int, path=p)     # missing or not an int: "file p, field 'num_clips': ..."
    z = read_npz(p, keys=("mean", "std"), kind="f")  # {"mean": array, "std": array}, float arrays only
    a = read_npy(p, kind="f", ndim=5, mmap=True)     # a memory-mapped float array of 5 dimensions
"""

from __future__ import annotations

import errno
import json
import os
import zipfile
import zlib
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from handx_jax.infra.errors import DataError

NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")  # a zip's first local header, or an empty zip's end record
_REQUIRED = object()
_KIND_NAMES = {"f": "floating-point", "i": "signed integer", "u": "unsigned integer", "b": "boolean",
               "c": "complex", "U": "text", "S": "bytes"}
_TYPE_NAMES = {dict: "an object ({...})", list: "a list ([...])", str: "a string", int: "an integer",
               float: "a number", bool: "true or false", type(None): "null"}


def path_problem(path: str | os.PathLike) -> str | None:
    """Why ``path`` cannot be opened at all (a symlink loop, a dangling symlink, absent), or None if it exists.
    ``Path.exists()`` says False for a symlink loop, which commands reported as "does not exist"."""
    p = Path(path)
    try:
        os.stat(p)
        return None
    except OSError as e:
        if e.errno == errno.ELOOP:
            return "is a symlink loop (a link that points back to itself); point it at a real file or folder"
        if p.is_symlink():
            return f"is a symlink to {os.readlink(p)}, which does not exist"
        if e.errno == errno.ENOTDIR:
            return "does not exist (a part of the path is a file, not a folder)"
        if e.errno in (errno.EACCES, errno.EPERM):
            return "cannot be read: permission denied"
        return "does not exist"


def require_dir(path: str | os.PathLike, what: str = "directory") -> Path:
    """``path`` as a folder that exists, or a ``DataError`` saying why not (absent, a symlink loop, a file)."""
    p = Path(path)
    why = path_problem(p)
    if why is not None:
        raise DataError(f"{what} {why}", path=p)
    if not p.is_dir():
        raise DataError(f"{what} is a file, not a folder", path=p)
    return p


def _open_failure(e: OSError, path: Path, missing: str | None) -> DataError:
    if isinstance(e, FileNotFoundError) and not path.is_symlink():
        # io.read_json's wording, kept: "file FOLDER: missing NAME" (or the caller's ``missing``)
        return DataError(missing or f"missing {path.name}", path=path.parent)
    if isinstance(e, IsADirectoryError):
        return DataError("is a folder, not a file", path=path)
    return DataError(path_problem(path) or f"cannot be read ({e.strerror or e})", path=path)


def _read_bytes(path: Path, missing: str | None) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise _open_failure(e, path, missing) from None


def _type_name(v: Any) -> str:
    for t, name in _TYPE_NAMES.items():
        if type(v) is t:
            return name
    return type(v).__name__


def _describe(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join(_TYPE_NAMES.get(k, k.__name__) for k in kinds)


def _is(value: Any, kind: type | tuple[type, ...]) -> bool:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool):  # JSON's true is no count of anything
        return bool in kinds
    if float in kinds and isinstance(value, int):
        return True
    return isinstance(value, kinds)


def read_json(path: str | os.PathLike, *, expect: type | tuple[type, ...] | None = None,
              missing: str | None = None, default: Any = _REQUIRED) -> Any:
    """A JSON file's value. ``expect``: the type(s) the top level must have (``dict``, ``list``);
    ``missing`` replaces the message for an absent file (e.g. with the command that makes one);
    ``default`` is returned for an absent file instead of refusing it. A truncated, garbage or non-UTF-8
    file, or a top level of another type, is a ``DataError`` naming the file."""
    p = Path(path)
    if default is not _REQUIRED and not os.path.lexists(p):
        return default
    raw = _read_bytes(p, missing)
    try:
        doc = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise DataError("not a JSON file (its bytes are not UTF-8 text)", path=p) from None
    except json.JSONDecodeError as e:
        what = "empty" if not raw.strip() else f"corrupt JSON ({e.msg} at line {e.lineno} column {e.colno}: truncated or damaged)"
        raise DataError(what, path=p) from None
    except RecursionError:
        raise DataError("JSON nested too deeply to read", path=p) from None
    if expect is not None and not _is(doc, expect):
        raise DataError(f"expected {_describe(expect)} at the top level, found {_type_name(doc)}", path=p)
    return doc


def read_format_meta(path: str | os.PathLike, fmt: str, version: int, *, missing: str | None = None,
                     upgrade: str = "") -> dict:
    """Read the meta JSON of one of the project's on-disk formats and check its ``format`` and
    ``format_version`` fields; ``upgrade`` is appended to the version error (what to rebuild)."""
    meta = read_json(path, missing=missing)
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise DataError(f"not a {fmt} (format={got!r})", path=path)
    if meta.get("format_version") != version:
        raise DataError(f"{fmt} format_version {meta.get('format_version')} is not supported (this code reads "
                        f"{version}){upgrade}", path=path)
    return meta


def get_field(doc: Any, key: str, kind: type | tuple[type, ...] | None = None, *, path: str | os.PathLike,
              default: Any = _REQUIRED, check=None, must: str = "") -> Any:
    """``doc[key]`` of a JSON document read from ``path``; a dotted ``key`` ("text.eval_level") walks nested
    objects. A missing key (without ``default``), a value not of ``kind`` or one for which ``check(value)``
    is false (``must`` says what it must be, e.g. "a whole number >= 1") is a ``DataError`` naming the file
    and the field. JSON's true/false never passes as a number."""
    cur = doc
    parts = key.split(".")
    for i, part in enumerate(parts):
        where = ".".join(parts[:i])
        if not isinstance(cur, dict):
            raise DataError(f"expected an object, found {_type_name(cur)}", path=path, field=where or None)
        if part not in cur:
            if default is not _REQUIRED:
                return default
            have = ", ".join(sorted(map(str, cur))[:12]) or "nothing"
            holder = f"object {where!r}" if where else "file"
            raise DataError(f"missing (the {holder} holds {have})", path=path, field=key)
        cur = cur[part]
    if kind is not None and not _is(cur, kind):
        raise DataError(f"expected {_describe(kind)}, found {_type_name(cur)} {json.dumps(cur)[:60]}", path=path,
                        field=key)
    if check is not None and not check(cur):
        raise DataError(f"is {json.dumps(cur)[:60]}; it must be {must or 'valid'}", path=path, field=key)
    return cur


def _header(f, path: Path, field: str | None) -> np.dtype:
    """The dtype in an open ``.npy`` stream's header (the stream is left at the data), checked for objects."""
    try:
        if f.read(len(NPY_MAGIC)) != NPY_MAGIC:
            raise ValueError("no .npy header")
        f.seek(0)
        version = np.lib.format.read_magic(f)
        reader = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        _shape, _fortran, dtype = reader(f)
    except (ValueError, EOFError, OSError, zipfile.BadZipFile, zlib.error, SyntaxError):
        raise DataError("not a NumPy array (no valid .npy header: truncated or garbage)", path=path,
                        field=field) from None
    if dtype.hasobject:
        raise DataError(f"holds Python objects (dtype {dtype}), not numbers: such arrays are pickles, which this "
                        "project never loads; write plain numeric arrays", path=path, field=field)
    return dtype


def _check_array(a: np.ndarray, path: Path, field: str | None, kind: str | None, ndim: int | None,
                 finite: bool) -> np.ndarray:
    if kind is not None and a.dtype.kind not in kind:
        want = " or ".join(_KIND_NAMES.get(k, k) for k in kind)
        raise DataError(f"dtype {a.dtype}; expected {want} numbers", path=path, field=field)
    if ndim is not None and a.ndim != ndim:
        raise DataError(f"has {a.ndim} dimension(s) (shape {a.shape}); expected {ndim}", path=path, field=field)
    if finite and a.dtype.kind in "fc" and a.size and not np.isfinite(a).all():
        bad = a.size - int(np.isfinite(a).sum())
        raise DataError(f"holds {bad} non-finite value(s) (NaN or inf) of {a.size}", path=path, field=field)
    return a


def read_npz(path: str | os.PathLike, keys: Sequence[str] | None = None, *, kind: str | None = None,
             finite: bool = False, missing: str | None = None) -> dict[str, np.ndarray]:
    """The arrays of a ``.npz`` file, read whole: those named in ``keys`` (each must be there), or all.
    ``kind``: the NumPy dtype kinds allowed (``"f"`` floats, ``"iu"`` integers, ...); ``finite``: refuse NaN
    or inf. A missing key, an object array, a wrong dtype, a truncated or garbage file is a ``DataError``
    naming the file and the field."""
    p = Path(path)
    head = read_head(p, missing)
    if head[:4] not in ZIP_MAGICS:
        raise DataError(f"not a .npz file (it starts with {head[:6]!r}; .npz archives are zip files, which start "
                        f"with {ZIP_MAGICS[0]!r})", path=p)
    out: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(p) as zf:
            members = {n[:-4] if n.endswith(".npy") else n: n for n in zf.namelist()}
            want = list(members) if keys is None else list(keys)
            for k in want:
                if k not in members:
                    have = ", ".join(sorted(members)[:12]) or "nothing"
                    raise DataError(f"missing (the archive holds {have})", path=p, field=k)
                with zf.open(members[k]) as f:
                    _header(f, p, k)
                with zf.open(members[k]) as f:
                    a = np.lib.format.read_array(f, allow_pickle=False)
                out[k] = _check_array(a, p, k, kind, None, finite)
    except DataError:
        raise
    except (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, NotImplementedError) as e:
        raise DataError(f"corrupt or truncated .npz archive ({type(e).__name__}: {str(e)[:120]})", path=p) from None
    return out


def read_npy(path: str | os.PathLike, *, kind: str | None = None, ndim: int | None = None, mmap: bool = False,
             finite: bool = False, missing: str | None = None) -> np.ndarray:
    """A ``.npy`` array (memory-mapped read-only with ``mmap``), checked like :func:`read_npz`'s;
    ``ndim``: the number of dimensions it must have. ``finite`` is checked only when not memory-mapped
    (a mapped array may not fit in memory; its reader checks it in chunks)."""
    p = Path(path)
    head = read_head(p, missing)
    if not head.startswith(NPY_MAGIC):
        raise DataError(f"not a .npy file (it starts with {head[:6]!r}; NumPy array files start with {NPY_MAGIC!r})",
                        path=p)
    try:
        with open(p, "rb") as f:
            _header(f, p, None)
        a = np.load(p, mmap_mode="r" if mmap else None, allow_pickle=False)
    except DataError:
        raise
    except (ValueError, EOFError, OSError) as e:
        raise DataError(f"corrupt or truncated array ({type(e).__name__}: {str(e)[:120]})", path=p) from None
    return _check_array(a, p, None, kind, ndim, finite and not mmap)


def read_head(p: Path, missing: str | None = None) -> bytes:
    """A file's first 8 bytes (what it is: ``NPY_MAGIC``, one of ``ZIP_MAGICS``), or a ``DataError`` why not."""
    try:
        with open(p, "rb") as f:
            return f.read(8)
    except OSError as e:
        raise _open_failure(e, p, missing) from None


def read_jsonl(path: str | os.PathLike, *, strict: bool = True) -> list[Any]:
    """Read a JSON-lines file. With ``strict=False`` a torn final line is ignored."""
    path = Path(path)
    rows = []
    lines = path.read_text(encoding="utf-8").splitlines()
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError as e:
            if not strict and i == len(lines) - 1:
                break
            raise DataError(f"line {i + 1} is not valid JSON ({e.msg})", path=path) from None
    return rows
