"""``NpyWriter``: a ``.npy`` file of known shape written by appending rows (a full disk is a
``DiskFullError``, never SIGBUS)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from handx_jax.infra.diskspace import check_free_space, disk_full_as_error


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
