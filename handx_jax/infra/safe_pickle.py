"""The one home of restricted unpickling: pickles are read without trusting them.

Pickle runs code by design: a ``GLOBAL`` opcode imports any ``module.name`` and ``REDUCE`` calls it, so
``pickle.load`` on a file from elsewhere can run a command. Every reader of pickled data in handx-jax
(the official HandX ``.npz`` archives, ``interop/handx_npz.py``; PyTorch checkpoints,
``interop/torch_pickle.py``) goes through :class:`RestrictedUnpickler`, whose ``find_class`` resolves
only the globals listed here, never imports a module on the pickle's say-so, and refuses anything
else before it is resolved with a :class:`~handx_jax.infra.errors.DataError` naming the file (and key).

What is admitted: NumPy's array, dtype and scalar reconstructors (what ``np.save`` of object arrays
and pickled NumPy values need), the plain containers and ``_codecs.encode`` (how protocol-2 pickles
write bytes). A subclass adds its own names (``_extra_globals``) or turns unknown names into inert
placeholders (``_unknown_global``).
"""

from __future__ import annotations

import builtins
import codecs
import collections
import io
import os
import pickle
from typing import Any

import numpy as np

from handx_jax.infra.errors import DataError


def _numpy_core(submodule: str, name: str) -> Any:
    """The object NumPy pickles as ``numpy.core.<sub>.<name>`` (NumPy 1.x) or ``numpy._core...`` (2.x)."""
    import importlib

    for mod in (f"numpy._core.{submodule}", f"numpy.core.{submodule}"):
        try:
            return getattr(importlib.import_module(mod), name)
        except (ImportError, AttributeError):
            continue
    raise ImportError(f"numpy has no {submodule}.{name}")


# (module, name) as written in the pickle → the object. Nothing else is ever resolved.
NUMPY_GLOBALS: dict[tuple[str, str], Any] = {
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    **{(f"numpy.{core}.multiarray", n): _numpy_core("multiarray", n)
       for core in ("core", "_core") for n in ("_reconstruct", "scalar")},
    # Protocol-5 pickles of contiguous arrays rebuild through _frombuffer.
    **{(f"numpy.{core}.numeric", "_frombuffer"): _numpy_core("numeric", "_frombuffer") for core in ("core", "_core")},
}
PLAIN_GLOBALS: dict[tuple[str, str], Any] = {
    # Protocol-2 (Python 2 era) pickles write bytes as _codecs.encode(str, "latin1").
    ("_codecs", "encode"): codecs.encode,
    **{(mod, n): getattr(builtins, n) for mod in ("builtins", "__builtin__")
       for n in ("complex", "set", "frozenset", "dict", "list", "tuple", "int", "float", "str", "bool",
                 "bytes", "bytearray", "slice")},
    ("__builtin__", "long"): int,
    ("__builtin__", "unicode"): str,
    ("collections", "OrderedDict"): collections.OrderedDict,
    ("collections", "defaultdict"): collections.defaultdict,
}


class RestrictedUnpickler(pickle.Unpickler):
    """``pickle.Unpickler`` that resolves only :data:`NUMPY_GLOBALS`, :data:`PLAIN_GLOBALS` and the
    subclass's ``_extra_globals``; any other global goes to ``_unknown_global`` (refused here).
    Persistent ids are refused unless a subclass handles them."""

    what = "pickled data"  # the kind of file, for the messages

    def __init__(self, file: io.BytesIO, *, path: str | os.PathLike, key: str | None = None):
        super().__init__(file, encoding="latin1")
        self._path, self._key = path, key

    def _extra_globals(self) -> dict[tuple[str, str], Any]:
        return {}

    def _unknown_global(self, module: str, name: str) -> Any:
        raise self.error(f"refusing to unpickle global {module}.{name}: only NumPy array/dtype/scalar "
                         f"reconstruction and plain containers are allowed in {self.what} (possibly malicious file)")

    def error(self, message: str) -> DataError:
        return DataError(message, path=self._path, clip=self._key)

    def find_class(self, module: str, name: str) -> Any:
        key = (module, name)
        for table in (PLAIN_GLOBALS, NUMPY_GLOBALS, self._extra_globals()):
            if key in table:
                return table[key]
        return self._unknown_global(module, name)

    def persistent_load(self, pid: Any) -> Any:
        raise self.error("refusing a persistent-id reference in a pickled payload")
