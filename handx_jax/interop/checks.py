"""The one place the importers and the exporter check a checkpoint's values (issue 43 item 1).

Shapes are checked where a tensor is read (``torch_layers.tensor``), against sizes whose source the
message names (``sizes_from``); values here: every weight finite, normalisation statistics finite with a
positive std, integer settings of ``config.yaml`` and the flags whole and positive. Each refusal is one
``DataError`` line naming the file and the tensor, key or flag.
"""

from __future__ import annotations

import contextlib
import contextvars
from typing import Any, Iterator, Mapping

import numpy as np

from handx_jax.infra.errors import DataError

# What the sizes a tensor is checked against come from ("the tensors' shapes", "config.yaml", "--heads"),
# set by the importer around its reads so that a wrong-shape refusal says why that shape was expected.
_SIZES_FROM: contextvars.ContextVar[str | None] = contextvars.ContextVar("sizes_from", default=None)


@contextlib.contextmanager
def sizes_from(text: str) -> Iterator[None]:
    token = _SIZES_FROM.set(text)
    try:
        yield
    finally:
        _SIZES_FROM.reset(token)


def sizes_note() -> str:
    note = _SIZES_FROM.get()
    return f" ({note})" if note else ""


def finite(name: str, a: np.ndarray, *, path=None, what: str = "tensor") -> np.ndarray:
    """``a`` if every value is finite; else a refusal naming the tensor and how many values are not."""
    if a.dtype.kind in "fc" and a.size and not np.isfinite(a).all():
        bad = a.size - int(np.isfinite(a).sum())
        first = np.unravel_index(int(np.flatnonzero(~np.isfinite(a.reshape(-1)))[0]), a.shape)
        raise DataError(f"{what} {name!r} holds {bad} non-finite value(s) (NaN or inf; first at "
                        f"{tuple(int(i) for i in first)}): the weights are broken (a diverged run?) and would "
                        "make every output NaN", path=path)
    return a


def finite_tree(tree: Any, *, path=None, what: str = "parameter") -> None:
    """Refuse a parameter tree (nested mappings of arrays) holding a NaN or inf, naming the leaf."""
    def walk(t, where):
        if isinstance(t, Mapping):
            for k, v in t.items():
                walk(v, f"{where}/{k}" if where else str(k))
        elif hasattr(t, "shape") and hasattr(t, "dtype"):
            finite(where, np.asarray(t), path=path, what=what)

    walk(tree, "")


def whole(value: Any, key: str, *, path=None, minimum: int = 1) -> int:
    """An integer setting (``model.latent_dim`` of config.yaml, ``--heads``) as an int >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        ok = isinstance(value, float) and value.is_integer()
        if not ok:
            raise DataError(f"{key} is {value!r}, not a whole number", path=path)
        value = int(value)
    if value < minimum:
        raise DataError(f"{key} is {value}; it must be a whole number >= {minimum}", path=path)
    return int(value)


def norm_stats(mean: np.ndarray, std: np.ndarray, *, mean_path=None, std_path=None) -> None:
    """Statistics the motion is divided by: finite, std > 0 (the official code adds no epsilon)."""
    if not np.isfinite(mean).all():
        bad = np.flatnonzero(~np.isfinite(np.asarray(mean).reshape(-1)))
        raise DataError(f"mean is not finite at {bad[:6].tolist()}", path=mean_path)
    s = np.asarray(std).reshape(-1)
    bad = np.flatnonzero(~np.isfinite(s) | (s <= 0))
    if bad.size:
        raise DataError(f"std is zero, negative or not finite at {bad[:6].tolist()} (the motion is divided by it "
                        "without an epsilon)", path=std_path)


def load_array_file(path, *, npz: bool = False):
    """A ``.npy`` array (or, with ``npz``, a ``.npz`` archive as a dict) read without pickles; a file of
    another kind (a text file, a pickle, an array of Python objects) is refused by what it is
    (``handx_jax.infra.readers``), not with numpy's hint to load it with ``allow_pickle``, which would run
    whatever the file names."""
    from pathlib import Path

    from handx_jax.infra.readers import NPY_MAGIC, ZIP_MAGICS, read_head, read_npy, read_npz

    p = Path(path)
    head = read_head(p)
    if npz and head[:4] in ZIP_MAGICS:
        return read_npz(p)
    if npz and not head.startswith(NPY_MAGIC):
        raise DataError(f"not a .npy or .npz file (it starts with {head[:6]!r}; NumPy array files start with "
                        f"{NPY_MAGIC!r} or an .npz zip)", path=p)
    return read_npy(p)
