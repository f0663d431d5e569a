"""PyTorch zip checkpoints (``torch.save`` ≥ 1.6, Lightning ``.ckpt``) read and written without PyTorch.

A checkpoint is a zip archive, stored uncompressed, under one top-level folder (``archive/`` or the
file's stem): ``data.pkl`` (the pickled object), ``data/<key>`` (one raw little-endian storage per
key), ``byteorder``, ``version``, ``.format_version``, ``.storage_alignment`` and
``.data/serialization_id``. In the pickle a tensor is ``torch._utils._rebuild_tensor_v2(storage,
offset, size, stride, requires_grad, hooks)`` whose storage is a persistent id ``("storage",
torch.FloatStorage, key, location, numel)``.

:func:`load` unpickles ``data.pkl`` with :class:`TorchUnpickler` (``handx_jax.infra.safe_pickle``): tensors
become NumPy arrays (a copy in their own layout; views of one storage stay consistent because each
storage is read once), plain containers become Python objects, NumPy values are rebuilt by NumPy's own
reconstructors. Any other global (an omegaconf config, ``typing.Any``, a function of the official
package) becomes an :class:`Inert` placeholder that records its name, arguments and state and does
nothing: no module is imported and nothing is called. Globals of the standard library's modules that
run commands, load code or touch files (``os.system``, ``builtins.eval``, ``subprocess.Popen`` …)
are refused outright: one line naming the file, before anything is resolved. Readers that need a
value (a state dict's tensors) refuse a placeholder where a tensor should be.

Also refused with one line naming the file: a file that is not a zip (or is truncated: the zip's
central directory is at its end), the pre-1.6 legacy format, big-endian files, unknown storage types,
storages shorter than their tensors need.

:func:`save` writes the same format (protocol-2 pickle emitted opcode by opcode, since ``pickle``
would import ``torch`` to name its functions; records 64-byte aligned as PyTorch aligns them), so
``torch.load`` reads it, also with ``weights_only=True``, and :func:`load` reads it back bit for bit.
"""

from __future__ import annotations

import hashlib
import io
import os
import struct
import zipfile
import zlib
from pathlib import Path
from typing import Any

import ml_dtypes
import numpy as np

from handx_jax.infra.atomic import atomic_write_bytes
from handx_jax.infra.errors import DataError
from handx_jax.infra.safe_pickle import RestrictedUnpickler

# PyTorch's typed storage names (as they appear in the pickle) and their little-endian dtypes.
STORAGE_DTYPES: dict[str, np.dtype] = {
    "DoubleStorage": np.dtype("<f8"), "FloatStorage": np.dtype("<f4"), "HalfStorage": np.dtype("<f2"),
    "BFloat16Storage": np.dtype(ml_dtypes.bfloat16),
    "LongStorage": np.dtype("<i8"), "IntStorage": np.dtype("<i4"), "ShortStorage": np.dtype("<i2"),
    "CharStorage": np.dtype("i1"), "ByteStorage": np.dtype("u1"), "BoolStorage": np.dtype("?"),
    "ComplexFloatStorage": np.dtype("<c8"), "ComplexDoubleStorage": np.dtype("<c16"),
}
_STORAGE_OF = {dt: name for name, dt in STORAGE_DTYPES.items()}

# Standard-library modules whose globals run commands, load code or touch files: a checkpoint has no
# business naming them, so they are refused rather than made inert (a crafted pickle says so at once).
REFUSED_MODULES = frozenset({
    "os", "posix", "nt", "subprocess", "sys", "builtins", "__builtin__", "importlib", "runpy", "shutil",
    "socket", "pty", "code", "codeop", "ctypes", "pickle", "_pickle", "marshal", "types", "operator",
    "functools", "io", "_io", "codecs", "_codecs", "webbrowser", "multiprocessing", "signal", "asyncio",
    "platform", "tempfile", "glob", "pathlib", "commands", "popen2", "shlex", "threading", "_thread",
    "inspect", "gc", "copyreg", "copy_reg", "timeit", "pdb", "bdb", "trace", "cProfile", "profile",
    "doctest", "unittest", "sqlite3", "urllib", "http", "ftplib", "smtplib", "telnetlib", "xmlrpc",
    "zipimport", "pkgutil", "site", "sysconfig", "distutils", "setuptools", "pip", "pydoc", "zipfile", "tarfile",
    "ensurepip", "venv", "imp", "posixpath", "ntpath", "genericpath",
})


# --------------------------------------------------------------------------------------------------
# Reading


class Inert:
    """A pickled object or reference of a class/function this reader does not import. It keeps what
    the pickle said (``module``, ``name``, constructor ``args``, ``state``, items) and does nothing."""

    module = ""
    name = ""

    def __new__(cls, *args, **kwargs):
        obj = object.__new__(cls)
        obj.args, obj.kwargs, obj.state, obj.items, obj.listitems = args, kwargs, None, {}, []
        return obj

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        self.state = state

    def __setitem__(self, key, value):
        self.items[key] = value

    def append(self, value):
        self.listitems.append(value)

    def extend(self, values):
        self.listitems.extend(values)

    def __repr__(self) -> str:
        return f"<inert {self.module}.{self.name}>"


def inert_name(obj: Any) -> str | None:
    """``module.name`` if ``obj`` is a placeholder (an instance or the placeholder class), else None."""
    cls = obj if isinstance(obj, type) else type(obj)
    return f"{cls.module}.{cls.name}" if isinstance(cls, type) and issubclass(cls, Inert) else None


# Bounded reads (issue 43 item 4): a tensor is a view (size, stride) of its storage, and stride 0 lets a few
# bytes claim any size. A tensor that needs more elements than its storage holds (an expansion) is
# materialised only up to EXPAND_LIMIT bytes, and all tensors of a file together only up to
# BUDGET_FACTOR x the file's size + EXPAND_LIMIT (shared storages are read once, but each view of one is
# copied). Beyond either the tensor is refused, by name, before anything is allocated.
EXPAND_LIMIT = 16 << 20
BUDGET_FACTOR = 4


class _Oversized:
    """Stands for a tensor refused as too large while the pickle is read; :func:`load` names its key."""

    def __init__(self, why: str):
        self.why = why


def _find_oversized(obj: Any, where: str = "", depth: int = 0) -> tuple[str, _Oversized] | None:
    if isinstance(obj, _Oversized):
        return where, obj
    if depth > 50:
        return None
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, (list, tuple)) else ()
    for k, v in items:
        hit = _find_oversized(v, f"{where}[{k!r}]", depth + 1)
        if hit:
            return hit
    return None


class _Storage:
    def __init__(self, name: str):
        self.name, self.dtype = name, STORAGE_DTYPES[name]


class TorchUnpickler(RestrictedUnpickler):
    """The restricted unpickler of a checkpoint's ``data.pkl`` (see the module docstring)."""

    what = "PyTorch checkpoints"

    def __init__(self, file, *, path, zf: zipfile.ZipFile, prefix: str):
        super().__init__(file, path=path)
        self._zf, self._prefix = zf, prefix
        self._storages: dict[str, np.ndarray] = {}
        self._inert: dict[tuple[str, str], type] = {}
        self._budget = BUDGET_FACTOR * Path(path).stat().st_size + EXPAND_LIMIT
        self.oversized: list[_Oversized] = []

    def error(self, message: str) -> DataError:
        return DataError(message, path=self._path)

    def _extra_globals(self):
        return {
            ("torch._utils", "_rebuild_tensor_v2"): self._rebuild_tensor,
            ("torch._utils", "_rebuild_tensor"): self._rebuild_tensor,
            ("torch._utils", "_rebuild_parameter"): lambda data, *_: data,
            ("torch._utils", "_rebuild_parameter_with_state"): lambda data, *_: data,
            ("torch._tensor", "_rebuild_from_type_v2"): lambda func, _new_type, args, _state: func(*args),
            ("torch", "Size"): tuple,
            **{("torch", n): _Storage(n) for n in STORAGE_DTYPES},
        }

    def _unknown_global(self, module: str, name: str):
        if module == "torch" and name.endswith("Storage"):
            raise self.error(f"unknown storage type torch.{name}: this reader knows "
                             f"{', '.join(sorted(STORAGE_DTYPES))}")
        if module.split(".", 1)[0] in REFUSED_MODULES:
            raise self.error(f"refusing to unpickle global {module}.{name}: a checkpoint holds tensors and plain "
                             "data, and this name can run code or touch files (crafted or malicious file?); "
                             "nothing was run")
        key = (module, name)
        if key not in self._inert:
            self._inert[key] = type(f"Inert[{module}.{name}]", (Inert,), {"module": module, "name": name})
        return self._inert[key]

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"):
            raise self.error(f"unexpected persistent id {pid!r:.80} (not a tensor storage)")
        _, storage, key, _location, numel = pid
        if inert_name(storage) or not isinstance(storage, _Storage):
            raise self.error(f"unknown storage type {inert_name(storage) or storage!r}: this reader knows "
                             f"{', '.join(sorted(STORAGE_DTYPES))}")
        key = str(key)
        if key not in self._storages:
            member = f"{self._prefix}data/{key}"
            try:
                raw = self._zf.read(member)
            except KeyError:
                raise self.error(f"storage {member} named by data.pkl is missing (truncated file?)") from None
            except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as e:
                raise self.error(f"cannot read storage {member} (truncated or corrupt: {e})") from None
            need = int(numel) * storage.dtype.itemsize
            if len(raw) < need:
                raise self.error(f"storage {member} holds {len(raw)} bytes, {need} expected (truncated file?)")
            self._storages[key] = np.frombuffer(raw, storage.dtype, count=int(numel))
        return self._storages[key]

    def _rebuild_tensor(self, storage, offset, size, stride, *_):
        if not isinstance(storage, np.ndarray):
            raise self.error(f"tensor rebuilt from {storage!r:.60}, not a storage")
        size, stride, offset = tuple(int(s) for s in size), tuple(int(s) for s in stride), int(offset)
        if any(s == 0 for s in size):
            return np.zeros(size, storage.dtype)
        last = offset + sum((n - 1) * st for n, st in zip(size, stride))
        if offset < 0 or min(stride, default=0) < 0 or last >= storage.size:
            raise self.error(f"tensor of size {size} stride {stride} at offset {offset} overruns its storage of "
                             f"{storage.size} elements (corrupt file?)")
        item = storage.dtype.itemsize
        count = 1
        for n in size:
            count *= n
        nbytes = count * item
        why = None
        if count > storage.size - offset and nbytes > EXPAND_LIMIT:
            why = (f"size {size} stride {stride} materialises {nbytes / 2**20:,.0f} MiB from a storage of "
                   f"{storage.nbytes:,} bytes (an expansion over {EXPAND_LIMIT >> 20} MiB)")
        elif nbytes > self._budget:
            why = (f"size {size} would bring the checkpoint's tensors past {self._budget / 2**20:,.0f} MiB, "
                   f"{BUDGET_FACTOR}x the file's size + {EXPAND_LIMIT >> 20} MiB")
        if why is not None:
            self.oversized.append(_Oversized(why))
            return self.oversized[-1]
        self._budget -= nbytes
        view = np.lib.stride_tricks.as_strided(storage[offset:], size, tuple(s * item for s in stride))
        return np.array(view)  # a contiguous, writable copy


def _open(path: Path) -> tuple[zipfile.ZipFile, str]:
    """The archive and its top-level folder (with the trailing slash)."""
    with open(path, "rb") as f:
        head = f.read(8)
    if head[:1] == b"\x80" or head[:8] == b"\x8a\x0a\x6c\xfc\x9c\x46\xf9\x20":
        raise DataError("a legacy (pre-1.6, non-zip) PyTorch file: re-save it with a recent torch.save to read it "
                        "here", path=path)
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, EOFError, OSError) as e:
        raise DataError(f"not a PyTorch zip checkpoint, or truncated ({e})", path=path) from None
    pkls = [n for n in zf.namelist() if n.endswith("/data.pkl") and n.count("/") == 1]
    if len(pkls) != 1:
        zf.close()
        raise DataError(f"not a PyTorch zip checkpoint: expected one <folder>/data.pkl, found {pkls[:3]}", path=path)
    return zf, pkls[0][: -len("data.pkl")]


def load(path: str | os.PathLike) -> Any:
    """The object a ``torch.save`` / Lightning checkpoint holds, tensors as NumPy arrays (see module doc)."""
    path = Path(path)
    if not path.is_file():
        raise DataError("checkpoint file does not exist", path=path)
    zf, prefix = _open(path)
    with zf:
        # PyTorch stores its records uncompressed; a compressed member that inflates far beyond the file (a
        # zip bomb) is refused before it is read, as an expanded tensor is (bounded reads, issue 43).
        limit = BUDGET_FACTOR * path.stat().st_size + EXPAND_LIMIT
        big = max(zf.infolist(), key=lambda i: i.file_size, default=None)
        if big is not None and sum(i.file_size for i in zf.infolist()) > limit:
            raise DataError(f"its records inflate to {sum(i.file_size for i in zf.infolist()) / 2**20:,.0f} MiB ("
                            f"{big.filename}: {big.file_size / 2**20:,.0f} MiB) from a file of "
                            f"{path.stat().st_size:,} bytes, past {BUDGET_FACTOR}x its size + {EXPAND_LIMIT >> 20} "
                            "MiB; refused (a crafted or corrupt file?)", path=path)
        try:
            order = zf.read(prefix + "byteorder").decode().strip() if prefix + "byteorder" in zf.namelist() \
                else "little"
            data = zf.read(prefix + "data.pkl")
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as e:
            raise DataError(f"cannot read the checkpoint (truncated or corrupt: {e})", path=path) from None
        if order != "little":
            raise DataError(f"byteorder is {order!r}: big-endian checkpoints are not supported", path=path)
        up = TorchUnpickler(io.BytesIO(data), path=path, zf=zf, prefix=prefix)
        try:
            obj = up.load()
        except DataError:
            raise
        except Exception as e:  # a corrupt pickle: EOFError, UnpicklingError, a bad opcode argument ...
            raise DataError(f"corrupt data.pkl ({type(e).__name__}: {e})", path=path) from None
        if up.oversized:
            hit = _find_oversized(obj)
            name = f"tensor {hit[0]}" if hit else "a tensor (inside an object this reader keeps inert)"
            why = hit[1].why if hit else up.oversized[0].why
            raise DataError(f"{name}: {why}; refused (a crafted or corrupt file?)", path=path)
        return obj


# --------------------------------------------------------------------------------------------------
# Writing


class _Pickle:
    """A protocol-2 pickle of plain data and tensors, emitted opcode by opcode."""

    def __init__(self):
        self.out = io.BytesIO()
        self.storages: list[np.ndarray] = []

    def emit(self, b: bytes) -> None:
        self.out.write(b)

    def glob(self, module: str, name: str) -> None:
        self.emit(b"c" + module.encode() + b"\n" + name.encode() + b"\n")

    def save(self, obj: Any) -> None:
        if obj is None:
            self.emit(b"N")
        elif isinstance(obj, (bool, np.bool_)):
            self.emit(b"\x88" if obj else b"\x89")
        elif isinstance(obj, (int, np.integer)):
            v = int(obj)
            if 0 <= v < 256:
                self.emit(b"K" + bytes([v]))
            elif 0 <= v < 65536:
                self.emit(b"M" + struct.pack("<H", v))
            elif -2 ** 31 <= v < 2 ** 31:
                self.emit(b"J" + struct.pack("<i", v))
            else:
                raw = v.to_bytes((v.bit_length() + 8) // 8, "little", signed=True)
                self.emit(b"\x8a" + bytes([len(raw)]) + raw)
        elif isinstance(obj, (float, np.floating)):
            self.emit(b"G" + struct.pack(">d", float(obj)))
        elif isinstance(obj, str):
            raw = obj.encode("utf-8", "surrogatepass")
            self.emit(b"X" + struct.pack("<I", len(raw)) + raw)
        elif isinstance(obj, dict):
            self.emit(b"}")
            if obj:
                self.emit(b"(")
                for k, v in obj.items():
                    self.save(k)
                    self.save(v)
                self.emit(b"u")
        elif isinstance(obj, list):
            self.emit(b"]")
            if obj:
                self.emit(b"(")
                for v in obj:
                    self.save(v)
                self.emit(b"e")
        elif isinstance(obj, tuple):
            self.emit(b"(")
            for v in obj:
                self.save(v)
            self.emit(b"t")
        elif isinstance(obj, np.ndarray) or hasattr(obj, "__array__"):
            self.tensor(np.asarray(obj))
        else:
            raise TypeError(f"cannot write a {type(obj).__name__} into a PyTorch checkpoint")

    def tensor(self, a: np.ndarray) -> None:
        dt = a.dtype.newbyteorder("<") if a.dtype.byteorder == ">" else a.dtype
        if dt not in _STORAGE_OF:
            raise TypeError(f"no PyTorch storage type for dtype {a.dtype}")
        a = np.array(a, dt, order="C")  # not ascontiguousarray: it makes a 0-d tensor 1-d
        key = len(self.storages)
        self.storages.append(a)
        strides = tuple(int(np.prod(a.shape[i + 1:], dtype=np.int64)) for i in range(a.ndim))
        self.glob("torch._utils", "_rebuild_tensor_v2")
        self.emit(b"(")  # args
        self.emit(b"(")  # the persistent id
        self.save("storage")
        self.glob("torch", _STORAGE_OF[dt])
        self.save(str(key))
        self.save("cpu")
        self.save(int(a.size))
        self.emit(b"tQ")
        self.save(0)
        self.save(tuple(int(s) for s in a.shape))
        self.save(strides)
        self.save(False)
        self.glob("collections", "OrderedDict")
        self.emit(b")R")  # OrderedDict(): the (empty) backward hooks
        self.emit(b"tR")


ALIGN = 64  # PyTorch aligns every record's data to 64 bytes (``.storage_alignment``)


def _aligned_record(zf: zipfile.ZipFile, name: str, data: bytes) -> None:
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = zipfile.ZIP_STORED
    header = 30 + len(name.encode())
    pad = (-(zf.fp.tell() + header + 4)) % ALIGN
    info.extra = b"FB" + struct.pack("<H", pad) + b"Z" * pad  # the padding record PyTorch writes
    zf.writestr(info, data)


def dumps(obj: Any, archive: str = "archive") -> bytes:
    """The bytes of a ``torch.save(obj)`` checkpoint: ``obj`` of dicts, lists, tuples, str, int, float,
    bool, None and NumPy arrays (tensors). Deterministic: the same object gives the same bytes."""
    p = _Pickle()
    p.emit(b"\x80\x02")
    p.save(obj)
    p.emit(b".")
    pkl = p.out.getvalue()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        records = [("data.pkl", pkl), (".format_version", b"1"), (".storage_alignment", str(ALIGN).encode()),
                   ("byteorder", b"little")]
        records += [(f"data/{i}", a.tobytes()) for i, a in enumerate(p.storages)]
        digest = hashlib.sha256(pkl)
        for a in p.storages:
            digest.update(a.tobytes())
        records += [("version", b"3\n"), (".data/serialization_id", str(int(digest.hexdigest(), 16))[:40].encode())]
        for name, data in records:
            _aligned_record(zf, f"{archive}/{name}", data)
    return buf.getvalue()


def save(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` as a PyTorch checkpoint, atomically (see :func:`dumps`)."""
    return atomic_write_bytes(path, dumps(obj))
