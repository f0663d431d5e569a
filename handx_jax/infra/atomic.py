"""Atomic writes: a file reaches the disk whole or not at all.

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
import time
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from handx_jax.infra.diskspace import DiskFullError, disk_full_as_error, disk_full_message, free_bytes
from handx_jax.infra.outputs import exclusive_output, refuse_existing


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
        with disk_full_as_error(path, len(data)), os.fdopen(fd, "wb") as f:
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


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, *, overwrite: bool = False, exclusive: bool = True) -> Iterator[Path]:
    """Yield a temporary directory that becomes ``path`` only if the block finishes.

    If ``path`` exists and ``overwrite`` is False, refuse before doing any work, so nothing already
    written is lost. With ``overwrite`` the old directory is replaced only after the new one is
    complete. ``exclusive``: hold the output's lock meanwhile (:func:`exclusive_output`: a second writer of
    the same folder is refused, temporaries of killed writers are removed).
    """
    path = Path(path)
    with contextlib.ExitStack() as stack:
        if exclusive:
            stack.enter_context(exclusive_output(path, overwrite=overwrite))
        else:
            refuse_existing(path, overwrite=overwrite)
        with _atomic_dir(path) as tmp:
            yield tmp


def remove_tree(path: Path, *, settle_s: float = 5.0) -> None:
    """``shutil.rmtree`` that outlasts a library's writer threads: a storage library that failed (orbax and
    tensorstore on a full disk) can still create a file in the folder while it is being removed, so the last
    ``rmdir`` fails and the folder would stay behind (seen once in a loaded suite run: ``.R.xxxx.tmp`` left on a
    full tmpfs). Retried until the folder is gone, for at most ``settle_s``."""
    deadline = time.monotonic() + settle_s
    while True:
        shutil.rmtree(path, ignore_errors=True)
        if not os.path.lexists(path) or time.monotonic() > deadline:
            return
        time.sleep(0.05)


@contextlib.contextmanager
def _atomic_dir(path: Path) -> Iterator[Path]:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it owner-only; a dataset should read like any folder
    try:
        yield tmp
    except DiskFullError as e:  # name the file the user asked for, not the removed temporary folder
        remove_tree(tmp)
        try:
            where = path / e.path.relative_to(tmp)
        except ValueError:
            raise e from None
        raise DiskFullError(where, e.needed, e.free) from None
    except BaseException as e:
        remove_tree(tmp)
        if isinstance(e, Exception) and disk_full_message(e) is not None:  # a library's own full-disk error
            raise DiskFullError(path, None, free_bytes(path)) from None  # (orbax: a ValueError naming the tmp)
        raise
    if path.exists():
        old = path.with_name(f".{path.name}.old-{os.getpid()}")
        os.replace(path, old)
        os.replace(tmp, path)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, path)
    _fsync_dir(path.parent)
