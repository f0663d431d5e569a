"""Atomic file writing and the project's error type for bad input.

Every file the project writes goes through here: write to a temporary sibling, fsync, then
``os.replace``. A killed process therefore leaves either the old file or the new one, never half of
one. Directories are built the same way (``atomic_dir``): filled under a temporary name and renamed
into place only when complete.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np


class DataError(ValueError):
    """Bad input data. The message names the file and, where known, the clip or field."""

    def __init__(self, message: str, *, path: str | os.PathLike | None = None, clip: Any = None,
                 field: str | None = None):
        where = []
        if path is not None:
            where.append(f"file {os.fspath(path)!s}")
        if clip is not None:
            where.append(f"clip {clip}")
        if field is not None:
            where.append(f"field {field!r}")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)
        self.path, self.clip, self.field = path, clip, field


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_FILE_MODE = 0o666 & ~_umask()  # what open() would give; mkstemp alone makes files owner-only


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, _FILE_MODE)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any, *, indent: int | None = 2) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=indent, sort_keys=False) + "\n")


def atomic_write_jsonl(path: str | os.PathLike, rows: Iterable[Any]) -> Path:
    return atomic_write_text(path, "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in rows))


def atomic_save_npy(path: str | os.PathLike, array: np.ndarray) -> Path:
    buf = io.BytesIO()
    np.save(buf, np.asarray(array), allow_pickle=False)
    return atomic_write_bytes(path, buf.getvalue())


def append_jsonl(path: str | os.PathLike, row: Any) -> None:
    """Append one JSON line and fsync. A torn last line (killed mid-write) is skipped by readers."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a", encoding="utf-8") as f:
        f.write(json.dumps(row, separators=(",", ":")) + "\n")
        f.flush()
        os.fsync(f.fileno())


def read_json(path: str | os.PathLike, *, missing: str | None = None) -> Any:
    """Read a JSON file; a missing or corrupt file is a ``DataError`` naming it (``missing`` replaces the
    default message for an absent file, e.g. with the command that makes one)."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(missing or f"missing {path.name}", path=path.parent) from None
    except json.JSONDecodeError as e:
        raise DataError(f"corrupt JSON ({e.msg})", path=path) from None


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


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary directory that becomes ``path`` only if the block finishes.

    If ``path`` exists and ``overwrite`` is False, refuse before doing any work, so nothing already
    written is lost. With ``overwrite`` the old directory is replaced only after the new one is
    complete.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} already exists; pass --force (overwrite=True) to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it owner-only; a dataset should read like any folder
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if path.exists():
        old = path.with_name(f".{path.name}.old-{os.getpid()}")
        os.replace(path, old)
        os.replace(tmp, path)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, path)
    _fsync_dir(path.parent)
