"""sha256 checksums: a sidecar ``NAME.sha256`` beside a file, ``SHA256SUMS`` for a folder; a mismatch is a
``DataError`` naming the file."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from handx_jax.infra.atomic import atomic_write_text
from handx_jax.infra.errors import DataError

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
