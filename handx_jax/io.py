"""Atomic file writing and the project's error type for bad input.

Every file the project writes goes through here: write to a temporary sibling, fsync, then
``os.replace``. A killed process therefore leaves either the old file or the new one, never half of
one. Directories are built the same way (``atomic_dir``): filled under a temporary name and renamed
into place only when complete.

One concern: a file reaches the disk whole or not at all and comes back checked. Atomic writes, exclusive
outputs, checksums, parameter files and the errors that name a bad or full file all serve it, and every
writer in the package goes through them.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import os
import logging
import re
import shutil
import sys
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


@contextlib.contextmanager
def library_output_held() -> Iterator[None]:
    """Hold what a storage library prints while it writes (orbax's absl ``ERROR`` records with their
    tracebacks, tensorstore's "Event loop is closed" tracebacks from its write threads): released to stderr
    if the block succeeds, dropped if it fails, when the error itself becomes one line (``handx_jax.cli``).
    A full disk under ``orbax`` printed ~110 lines of them before that line (issue 43)."""
    held = io.StringIO()
    loggers = [logging.getLogger(n) for n in ("absl", "asyncio")]
    levels = [lg.level for lg in loggers]
    old = sys.stderr
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    sys.stderr = held
    ok = False
    try:
        yield
        ok = True
    finally:
        # After a failure the library's tasks keep reporting as they are collected (asyncio's "Task exception
        # was never retrieved", at exit): its loggers stay quiet and stderr passes only the project's lines.
        sys.stderr = old if ok else _Quiet(old)
        if ok:
            for lg, lv in zip(loggers, levels):
                lg.setLevel(lv)
            if held.getvalue():
                old.write(held.getvalue())


class _Quiet:
    """stderr after a failed library write: the library's threads may still print tracebacks of callbacks on
    their closed event loop while the error unwinds; only the project's own lines (``handx…``) pass."""

    def __init__(self, stream):
        self._stream, self._line = stream, ""

    def write(self, text: str) -> int:
        self._line += text
        *lines, self._line = self._line.split("\n")
        for ln in lines:
            if ln.startswith("handx"):
                self._stream.write(ln + "\n")
        return len(text)

    def flush(self) -> None:
        self._stream.flush()

    def __getattr__(self, name):
        return getattr(self._stream, name)


class NpyWriter:
    """Write a C-order ``.npy`` file of known shape by appending rows, with plain ``write`` calls.

    Replaces ``np.lib.format.open_memmap(mode="w+")`` for outputs: writing into a memory map on a full
    file system (e.g. tmpfs) kills the process with SIGBUS, with no message and no clean-up; a
    ``write`` fails with ENOSPC, which becomes a :class:`DiskFullError` naming the file.
    """

    def __init__(self, path: str | os.PathLike, dtype, shape: tuple[int, ...]):
        self.path, self.dtype, self.shape = Path(path), np.dtype(dtype), tuple(int(n) for n in shape)
        self.row_shape, self.rows = self.shape[1:], 0
        self.nbytes = int(np.prod(self.shape)) * self.dtype.itemsize
        check_free_space(self.path, self.nbytes)
        with disk_full_as_error(self.path, self.nbytes):
            self._f = open(self.path, "wb")
            header = {"descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False, "shape": self.shape}
            np.lib.format.write_array_header_2_0(self._f, header) if self.nbytes > 2**31 else \
                np.lib.format.write_array_header_1_0(self._f, header)

    def append(self, rows: np.ndarray) -> None:
        a = np.ascontiguousarray(rows, dtype=self.dtype)
        if a.shape[1:] != self.row_shape or self.rows + a.shape[0] > self.shape[0]:
            raise ValueError(f"{self.path}: rows {a.shape} do not fit {self.shape} after {self.rows} rows")
        with disk_full_as_error(self.path, self.nbytes):
            self._f.write(a.data if a.size else b"")
        self.rows += a.shape[0]

    def close(self) -> None:
        if self._f.closed:
            return
        try:
            if self.rows != self.shape[0]:
                raise ValueError(f"{self.path}: wrote {self.rows} of {self.shape[0]} rows")
            with disk_full_as_error(self.path, self.nbytes):
                self._f.flush()
                os.fsync(self._f.fileno())
        finally:
            self._f.close()

    def __enter__(self) -> "NpyWriter":
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is None:
            self.close()
        else:
            self._f.close()


# ---- checksums ---------------------------------------------------------------------------------
# A sidecar ``NAME.sha256`` ("<hex>  NAME" as sha256sum writes it, so `sha256sum -c` checks it too) next
# to a weights file: flipped or truncated bytes are caught before they load silently.
CHECKSUM_SUFFIX = ".sha256"


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def checksum_path(path: str | os.PathLike) -> Path:
    p = Path(path)
    return p.with_name(p.name + CHECKSUM_SUFFIX)


def write_checksum(path: str | os.PathLike) -> Path:
    """Write ``path``'s sha256 sidecar (atomically); call after the file itself is complete."""
    p = Path(path)
    return atomic_write_text(checksum_path(p), f"{sha256_file(p)}  {p.name}\n")


def verify_checksum(path: str | os.PathLike, *, required: bool = False) -> bool:
    """Check ``path`` against its sidecar. Returns True if verified, False if there is no sidecar (files
    written before checksums existed; a ``DataError`` instead when ``required``). A mismatch is a
    ``DataError`` naming the file: it was corrupted or changed after it was written."""
    p = Path(path)
    side = checksum_path(p)
    if not side.exists():
        if required:
            raise DataError(f"missing checksum {side.name}", path=p)
        return False
    try:
        want = side.read_text(encoding="utf-8").split()[0].lower()
    except (IndexError, UnicodeDecodeError, OSError):
        raise DataError(f"unreadable checksum file {side.name}", path=p) from None
    try:
        have = sha256_file(p)
    except FileNotFoundError:
        raise DataError("missing file (its checksum exists)", path=p) from None
    if have != want:
        raise DataError(f"checksum mismatch (sha256 {have[:16]}…, expected {want[:16]}… from {side.name}): the "
                        "file is corrupt or was changed after it was written; restore or regenerate it", path=p)
    return True


TREE_CHECKSUMS = "SHA256SUMS"


def write_tree_checksum(folder: str | os.PathLike) -> Path:
    """Checksum every file under ``folder`` into ``folder/SHA256SUMS`` (``sha256sum -c`` format, sorted
    relative paths). For checkpoint folders written by a library (e.g. an Orbax step directory): call
    it once the folder is complete; :func:`verify_tree_checksum` before restoring."""
    root = Path(folder)
    files = sorted(p for p in root.rglob("*") if p.is_file() and p.name != TREE_CHECKSUMS)
    lines = "".join(f"{sha256_file(p)}  {p.relative_to(root).as_posix()}\n" for p in files)
    return atomic_write_text(root / TREE_CHECKSUMS, lines)


def verify_tree_checksum(folder: str | os.PathLike, *, required: bool = False) -> bool:
    """Check the files listed in ``folder/SHA256SUMS``: True if all match, False if there is no list
    (unless ``required``); a changed or missing file is a ``DataError`` naming it."""
    root = Path(folder)
    listing = root / TREE_CHECKSUMS
    if not listing.exists():
        if required:
            raise DataError(f"missing {TREE_CHECKSUMS}", path=root)
        return False
    for line in listing.read_text(encoding="utf-8").splitlines():
        if not line.strip():
            continue
        want, _, rel = line.partition("  ")
        p = root / rel
        if not p.is_file():
            raise DataError(f"listed in {TREE_CHECKSUMS} but missing", path=p)
        if sha256_file(p) != want.lower():
            raise DataError(f"checksum mismatch against {TREE_CHECKSUMS}: the file is corrupt or was changed "
                            "after it was written", path=p)
    return True


def write_params_msgpack(path: str | os.PathLike, params: Any) -> Path:
    """Flax-serialise a parameter pytree to ``path`` atomically, with its sha256 sidecar."""
    import jax
    from flax import serialization

    out = atomic_write_bytes(path, serialization.to_bytes(jax.device_get(params)))
    write_checksum(out)
    return out


def read_params_msgpack(path: str | os.PathLike, template: Any) -> Any:
    """Read parameters written by :func:`write_params_msgpack` (or plain ``serialization.to_bytes``) into
    the structure of ``template``. The checksum sidecar, when present, is verified; a missing, truncated
    or garbage file, or one of another structure, is a ``DataError`` naming it (flax says only
    "Unpack failed" or raises a ValueError/KeyError that does not)."""
    from flax import serialization

    p = Path(path)
    verify_checksum(p)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise DataError(f"missing {p.name}", path=p.parent) from None
    try:
        params = serialization.from_bytes(template, data)
    except Exception as e:  # msgpack's ExtraData/UnpackValueError/FormatError, flax's ValueError/KeyError, ...
        raise DataError(f"corrupt, truncated or incompatible parameter file ({type(e).__name__}: "
                        f"{str(e).splitlines()[0][:200] if str(e) else 'no detail'})", path=p) from None
    # flax fills the template's structure but never compares shapes. The template may be abstract
    # (jax.eval_shape of an init: shapes without compiling or running it), so the shapes are checked here.
    import jax

    got = jax.tree_util.tree_flatten_with_path(params)[0]
    want = jax.tree_util.tree_leaves(template)
    for (where, a), b in zip(got, want):
        if hasattr(b, "shape") and tuple(np.shape(a)) != tuple(b.shape):
            raise DataError(f"parameter {jax.tree_util.keystr(where)} has shape {tuple(np.shape(a))}, but this "
                            f"configuration needs {tuple(b.shape)}: a parameter file of another model size", path=p)
    check_finite_params(params, path=p)
    return params


def check_finite_params(params: Any, *, path: str | os.PathLike | None = None) -> None:
    """Refuse parameters holding a NaN or inf, naming the first such parameter: weights like that (a diverged
    run, a damaged or crafted import) make every output NaN, which surfaced far from the cause (a NaN
    generated file, numpy's LinAlgError in FID, a NaN reference cache written into the evaluator)."""
    import jax

    for where, a in jax.tree_util.tree_flatten_with_path(params)[0]:
        a = np.asarray(a)
        if a.dtype.kind in "fc" and a.size and not np.isfinite(a).all():
            bad = a.size - int(np.isfinite(a).sum())
            raise DataError(f"parameter {jax.tree_util.keystr(where)} holds {bad} non-finite value(s) (NaN or inf) "
                            f"of {a.size}: the weights are broken (a diverged run?) and every output would be NaN",
                            path=path)


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


def refuse_existing(path: str | os.PathLike, *, overwrite: bool = False, flag: str | None = None) -> None:
    """The one refusal of an output that exists (every command that writes; ``--force`` replaces it)."""
    path = Path(path)
    if path.exists() and not overwrite:
        name = f"{flag} {path}" if flag else str(path)
        raise FileExistsError(f"{name} already exists; pass --force (overwrite=True) to replace it")


def _tmp_pattern(name: str) -> re.Pattern:
    # What tempfile.mkstemp/mkdtemp make for ``prefix=f".{name}."``, ``suffix=".tmp"`` (8 random characters),
    # and atomic_dir's ``.NAME.old-PID``: nothing an output of another name could have.
    return re.compile(rf"\.{re.escape(name)}\.(?:[a-z0-9_]{{8}}\.tmp|old-(\d+))")


def remove_stale_temporaries(path: str | os.PathLike) -> list[str]:
    """Remove what killed writers of ``path`` left beside it (``.NAME.<8 random chars>.tmp``, ``.NAME.old-PID``), and
    say so in one line on stderr. Call only while holding ``path``'s output lock (:func:`exclusive_output`):
    then no live writer owns them."""
    from handx_jax.runlock import pid_alive

    path = Path(path)
    pat, removed = _tmp_pattern(path.name), []
    try:
        entries = list(path.parent.iterdir())
    except OSError:
        return []
    for p in entries:
        m = pat.fullmatch(p.name)
        if m is None or (m.group(1) and pid_alive(int(m.group(1)))):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                p.unlink()
        if not p.exists():
            removed.append(p.name)
    if removed:
        print(f"handx: removed {', '.join(removed)} in {path.parent}: left by a writer of {path.name} that was "
              "killed", file=sys.stderr)
    return removed


@contextlib.contextmanager
def exclusive_output(path: str | os.PathLike, *, overwrite: bool = False, flag: str | None = None
                     ) -> Iterator[Path]:
    """Hold ``path``'s output lock (``runlock.RunLock.for_output``: a second writer of the same output is
    refused, naming the first), refuse an existing ``path`` without ``overwrite`` and remove the temporaries
    of killed writers. The writes themselves go through the atomic writers inside the block."""
    from handx_jax.runlock import RunLock

    path = Path(path)
    refuse_existing(path, overwrite=overwrite, flag=flag)  # before the lock: nothing is created to refuse
    with RunLock.for_output(path):
        refuse_existing(path, overwrite=overwrite, flag=flag)  # written by another writer meanwhile
        remove_stale_temporaries(path)
        yield path


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


@contextlib.contextmanager
def _atomic_dir(path: Path) -> Iterator[Path]:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it owner-only; a dataset should read like any folder
    try:
        yield tmp
    except DiskFullError as e:  # name the file the user asked for, not the removed temporary folder
        shutil.rmtree(tmp, ignore_errors=True)
        try:
            where = path / e.path.relative_to(tmp)
        except ValueError:
            raise e from None
        raise DiskFullError(where, e.needed, e.free) from None
    except BaseException as e:
        shutil.rmtree(tmp, ignore_errors=True)
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
