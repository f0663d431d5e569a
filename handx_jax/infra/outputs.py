"""Exclusive outputs: an output that exists is refused (``--force`` replaces it), a second writer of the same
output is refused naming the first, and what killed writers left beside it is removed. And an output apart
from what it is made of (:func:`check_out_apart`, issue 54): ``handx data reverse --data D --out D --force``
replaced the 600-clip dataset D by its 536 reversed train clips, the writer's atomic rename putting the new
folder where its input was."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import sys
from pathlib import Path
from typing import Iterator

from handx_jax.infra.errors import DataError


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
    from handx_jax.infra.runlock import pid_alive

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
    from handx_jax.infra.runlock import RunLock

    path = Path(path)
    refuse_existing(path, overwrite=overwrite, flag=flag)  # before the lock: nothing is created to refuse
    with RunLock.for_output(path):
        refuse_existing(path, overwrite=overwrite, flag=flag)  # written by another writer meanwhile
        remove_stale_temporaries(path)
        yield path


def _real(p: str | os.PathLike) -> Path:
    return Path(os.path.realpath(os.path.abspath(p)))  # through symlinks: a link to D is D


def check_out_apart(out: str | os.PathLike, data: str | os.PathLike, *, replaces: bool = True,
                    out_flag: str = "--out", data_flag: str = "--data") -> None:
    """Refuse an ``out`` that is ``data`` or lies inside it; with ``replaces`` (the writer replaces ``out``
    as a whole, e.g. ``infra.atomic.atomic_dir`` under ``--force``) also one that contains ``data``. A ``DataError``
    in one line naming both."""
    o, d = _real(out), _real(data)
    if o == d:
        why, then = "is", ""
    elif d in o.parents:
        why, then = "is inside", ""
    elif replaces and o in d.parents:
        why, then = "contains", f" (writing {out_flag} replaces that folder, and the dataset in it)"
    else:
        return
    raise DataError(f"{out_flag} {out} {why} the dataset it reads, {data_flag} {data}{then}; choose another "
                    f"{out_flag} outside it")
