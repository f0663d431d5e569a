"""A full disk as one line: ``DiskFullError`` names the path, the bytes a write needed and what was free;
the free-space check before a long write, and ENOSPC/EDQUOT anywhere in an exception's chain."""

from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path
from typing import Iterator


class DiskFullError(OSError):
    """No space left while writing ``path`` (ENOSPC/EDQUOT). The message names the path, the bytes the
    write needed (where known) and what was free, so the user can free space or write elsewhere."""

    def __init__(self, path: str | os.PathLike, needed: int | None = None, free: int | None = None):
        need = f"; it needs {_human(needed)}" if needed is not None else ""
        have = f", {_human(free)} free" if free is not None else ""
        super().__init__(errno.ENOSPC, f"no space left on device writing {os.fspath(path)}{need}{have} "
                                       f"(free some space or write elsewhere)")
        self.path, self.needed, self.free = Path(path), needed, free

    def __str__(self) -> str:
        return self.strerror


def _human(n: int) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if abs(n) < 1024 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"


def is_disk_full(e: BaseException) -> bool:
    return isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT)


def disk_full_message(e: BaseException) -> str | None:
    """One line for a full-disk failure anywhere in ``e``'s chain (an OSError 28/122, or a library error
    that says "No space left on device"), else None."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, DiskFullError):
            return str(e)
        if is_disk_full(e):
            where = f" writing {e.filename}" if getattr(e, "filename", None) else ""
            return f"no space left on device{where} (free some space or write elsewhere)"
        if "No space left on device" in str(e) or "Disk quota exceeded" in str(e):
            return f"no space left on device ({type(e).__name__}: {str(e).strip().splitlines()[0][:300]})"
        e = e.__cause__ or e.__context__
    return None


def free_bytes(path: str | os.PathLike) -> int | None:
    """Bytes available to this user on the file system holding ``path`` (its nearest existing parent)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        st = os.statvfs(p)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def check_free_space(path: str | os.PathLike, needed: int, *, margin: float = 1.02) -> None:
    """Refuse before writing ``needed`` bytes under ``path`` if the file system cannot hold them, so a
    long build fails in a second, not after minutes (and never by SIGBUS on a memory-mapped write)."""
    free = free_bytes(path)
    if free is not None and needed * margin > free:
        raise DiskFullError(path, needed, free)


@contextlib.contextmanager
def disk_full_as_error(path: str | os.PathLike, needed: int | None = None) -> Iterator[None]:
    """Turn an ENOSPC/EDQUOT ``OSError`` raised inside the block into a :class:`DiskFullError` naming ``path``."""
    try:
        yield
    except DiskFullError:
        raise
    except OSError as e:
        if not is_disk_full(e):
            raise
        raise DiskFullError(path, needed, free_bytes(path)) from None
