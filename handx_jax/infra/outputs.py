"""Where a command may write: an ``--out`` apart from the dataset it reads (issue 54).

``handx data reverse --data D --out D --force`` replaced the 600-clip dataset D by its 536 reversed train
clips: the writer's atomic rename put the new folder where the input was. Every command that reads a
dataset and writes a folder asks :func:`check_out_apart` first, before any work and before anything exists.
"""

from __future__ import annotations

import os
from pathlib import Path

from handx_jax.io import DataError


def _real(p: str | os.PathLike) -> Path:
    return Path(os.path.realpath(os.path.abspath(p)))  # through symlinks: a link to D is D


def check_out_apart(out: str | os.PathLike, data: str | os.PathLike, *, replaces: bool = True,
                    out_flag: str = "--out", data_flag: str = "--data") -> None:
    """Refuse an ``out`` that is ``data`` or lies inside it; with ``replaces`` (the writer replaces ``out``
    as a whole, e.g. ``io.atomic_dir`` under ``--force``) also one that contains ``data``. A ``DataError``
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
