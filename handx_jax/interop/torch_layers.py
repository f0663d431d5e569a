"""PyTorch ``nn.Linear`` / ``nn.LayerNorm`` / ``nn.MultiheadAttention`` / ``nn.Transformer*Layer``
state-dict entries ↔ this project's parameter subtrees (``handx_jax.models.layers``).

Every map is a pure re-layout (transpose, reshape, split, concatenate), so a round trip gives the
same bits. PyTorch Linear stores ``weight`` (out, in); flax ``kernel`` is (in, out). PyTorch's
attention packs q/k/v in ``in_proj_weight`` (3D, D) and ``in_proj_bias`` (3D); ours keeps them as
``query``/``key``/``value`` kernels (D, H, D/H) and biases (H, D/H), the out kernel (H, D/H, D).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from handx_jax.infra.errors import DataError

StateDict = Mapping[str, np.ndarray]


def tensor(sd: StateDict, name: str, shape: tuple[int, ...] | None = None, *, path=None) -> np.ndarray:
    """``sd[name]`` as a float32 array, refused (naming the file and tensor) if absent, not a tensor
    (an inert placeholder of the reader), of another shape (the message says where the expected sizes
    come from: ``checks.sizes_from``) or holding a NaN/inf (``checks.finite``)."""
    from handx_jax.interop import checks
    from handx_jax.interop.torch_pickle import inert_name

    if name not in sd:
        raise DataError(f"the state dict has no tensor {name!r}", path=path)
    a = sd[name]
    if not isinstance(a, np.ndarray):
        what = inert_name(a) or type(a).__name__
        raise DataError(f"state dict entry {name!r} is a pickled {what}, not a tensor", path=path)
    if shape is not None and tuple(a.shape) != tuple(shape):
        raise DataError(f"tensor {name!r} has shape {tuple(a.shape)}; the sizes imply {tuple(shape)}"
                        f"{checks.sizes_note()}", path=path)
    if a.dtype != np.float32:
        raise DataError(f"tensor {name!r} is {a.dtype}; float32 weights expected", path=path)
    return checks.finite(name, a, path=path)


def linear_from(sd, name, d_in, d_out, *, path=None) -> dict:
    return {"kernel": tensor(sd, f"{name}.weight", (d_out, d_in), path=path).T.copy(),
            "bias": tensor(sd, f"{name}.bias", (d_out,), path=path).copy()}


def linear_to(tree, name) -> dict:
    return {f"{name}.weight": np.asarray(tree["kernel"]).T.copy(), f"{name}.bias": np.asarray(tree["bias"]).copy()}


def norm_from(sd, name, d, *, path=None) -> dict:
    return {"scale": tensor(sd, f"{name}.weight", (d,), path=path).copy(),
            "bias": tensor(sd, f"{name}.bias", (d,), path=path).copy()}


def norm_to(tree, name) -> dict:
    return {f"{name}.weight": np.asarray(tree["scale"]).copy(), f"{name}.bias": np.asarray(tree["bias"]).copy()}


def mha_from(sd, name, d, heads, *, path=None) -> dict:
    w = tensor(sd, f"{name}.in_proj_weight", (3 * d, d), path=path)
    b = tensor(sd, f"{name}.in_proj_bias", (3 * d,), path=path)
    hd = d // heads
    out = {p: {"kernel": w[i * d:(i + 1) * d].T.reshape(d, heads, hd).copy(),
               "bias": b[i * d:(i + 1) * d].reshape(heads, hd).copy()}
           for i, p in enumerate(("query", "key", "value"))}
    out["out"] = {"kernel": tensor(sd, f"{name}.out_proj.weight", (d, d), path=path).T.reshape(heads, hd, d).copy(),
                  "bias": tensor(sd, f"{name}.out_proj.bias", (d,), path=path).copy()}
    return out


def mha_to(tree, name) -> dict:
    q = np.asarray(tree["query"]["kernel"])
    d = q.shape[0]
    w = np.concatenate([np.asarray(tree[p]["kernel"]).reshape(d, d).T for p in ("query", "key", "value")])
    b = np.concatenate([np.asarray(tree[p]["bias"]).reshape(d) for p in ("query", "key", "value")])
    return {f"{name}.in_proj_weight": w, f"{name}.in_proj_bias": b,
            f"{name}.out_proj.weight": np.asarray(tree["out"]["kernel"]).reshape(d, d).T.copy(),
            f"{name}.out_proj.bias": np.asarray(tree["out"]["bias"]).copy()}


def decoder_layer_from(sd, name, d, heads, ff, *, path=None) -> dict:
    """``nn.TransformerDecoderLayer`` → ``layers.DecoderLayer``."""
    return {"self_attn": mha_from(sd, f"{name}.self_attn", d, heads, path=path),
            "cross_attn": mha_from(sd, f"{name}.multihead_attn", d, heads, path=path),
            "ff": {"lin1": linear_from(sd, f"{name}.linear1", d, ff, path=path),
                   "lin2": linear_from(sd, f"{name}.linear2", ff, d, path=path)},
            **{n: norm_from(sd, f"{name}.{n}", d, path=path) for n in ("norm1", "norm2", "norm3")}}


def decoder_layer_to(tree, name) -> dict:
    return {**mha_to(tree["self_attn"], f"{name}.self_attn"), **mha_to(tree["cross_attn"], f"{name}.multihead_attn"),
            **linear_to(tree["ff"]["lin1"], f"{name}.linear1"), **linear_to(tree["ff"]["lin2"], f"{name}.linear2"),
            **{k: v for n in ("norm1", "norm2", "norm3") for k, v in norm_to(tree[n], f"{name}.{n}").items()}}


def encoder_layer_from(sd, name, d, heads, ff, *, path=None) -> dict:
    """``nn.TransformerEncoderLayer`` → ``layers.EncoderLayer``."""
    return {"self_attn": mha_from(sd, f"{name}.self_attn", d, heads, path=path),
            "ff": {"lin1": linear_from(sd, f"{name}.linear1", d, ff, path=path),
                   "lin2": linear_from(sd, f"{name}.linear2", ff, d, path=path)},
            **{n: norm_from(sd, f"{name}.{n}", d, path=path) for n in ("norm1", "norm2")}}


def layer_count(sd: StateDict, prefix: str) -> int:
    """Number of layers ``prefix.<i>.…`` (indices must run 0..n−1)."""
    idx = {int(k[len(prefix) + 1:].split(".", 1)[0]) for k in sd if k.startswith(prefix + ".")
           and k[len(prefix) + 1:].split(".", 1)[0].isdigit()}
    if idx != set(range(len(idx))):
        raise DataError(f"layers under {prefix!r} are numbered {sorted(idx)}, not 0..n-1")
    return len(idx)
