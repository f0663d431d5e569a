"""Model parameters as a flax msgpack file with its checksum sidecar, read back checked: structure, shapes
and finiteness."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from handx_jax.infra.atomic import atomic_write_bytes
from handx_jax.infra.checksums import verify_checksum, write_checksum
from handx_jax.infra.errors import DataError


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
