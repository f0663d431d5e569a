"""Hugging Face T5 folders: the tensor-name table, a numpy safetensors reader, load and export.

A folder holds ``config.json``, ``model.safetensors`` (or shards + ``model.safetensors.index.json``)
and ``spiece.model``. ``hf_param_names`` is the one table between Hugging Face tensor names and our
parameter tree, used by both the loader and the exporter, so a folder we write is read back by the
same code as a stock one. Loading hashes the weights (``FrozenEncoder.fingerprint``) on first use;
load a folder once per command and pass the :class:`~handx_jax.text.t5.FrozenEncoder` on
(:func:`as_encoder` accepts either).
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.infra.atomic import atomic_dir, atomic_write_json
from handx_jax.infra.checksums import verify_checksum, write_checksum
from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import get_field, read_json
from handx_jax.text.t5 import FrozenEncoder, Params, T5Config, T5EncoderModel
from handx_jax.text.tokenizer import MODEL_FILENAME, Tokenizer

CONFIG_FILE, WEIGHTS_FILE, INDEX_FILE = "config.json", "model.safetensors", "model.safetensors.index.json"


# --------------------------------------------------------------------------------------------------
# Hugging Face names ↔ our tree


def hf_param_names(cfg: T5Config, *, encoder_only: bool = True) -> list[tuple[str, tuple[str, ...], bool]]:
    """(HF tensor name, our path, transpose?) for every parameter. PyTorch Linear stores (out, in)."""
    out = [("shared.weight", ("shared", "embedding"), False)]
    stacks = [("encoder", cfg.num_layers, False)]
    if not encoder_only:
        stacks.append(("decoder", cfg.num_decoder_layers, True))
    ffn = ("wi_0", "wi_1", "wo") if cfg.gated else ("wi", "wo")
    for stack, n, dec in stacks:
        out.append((f"{stack}.block.0.layer.0.SelfAttention.relative_attention_bias.weight",
                    (stack, "rel_bias", "embedding"), False))
        for i in range(n):
            hf, me = f"{stack}.block.{i}.layer", (stack, f"block_{i}")
            out.append((f"{hf}.0.layer_norm.weight", me + ("attn_norm", "scale"), False))
            out += [(f"{hf}.0.SelfAttention.{p}.weight", me + ("attn", p, "kernel"), True) for p in "qkvo"]
            ff = 1
            if dec:
                out.append((f"{hf}.1.layer_norm.weight", me + ("cross_norm", "scale"), False))
                out += [(f"{hf}.1.EncDecAttention.{p}.weight", me + ("cross", p, "kernel"), True) for p in "qkvo"]
                ff = 2
            out.append((f"{hf}.{ff}.layer_norm.weight", me + ("mlp_norm", "scale"), False))
            out += [(f"{hf}.{ff}.DenseReluDense.{p}.weight", me + ("mlp", p, "kernel"), True) for p in ffn]
        out.append((f"{stack}.final_layer_norm.weight", (stack, "final_norm", "scale"), False))
    if not encoder_only and not cfg.tie_word_embeddings:
        out.append(("lm_head.weight", ("lm_head", "kernel"), True))
    return out


def _get(tree: Params, path: Sequence[str]):
    for p in path:
        tree = tree[p]
    return tree


def set_path(tree: dict, path: Sequence[str], value) -> None:
    """``tree[path[0]]…[path[-1]] = value``, creating the dicts on the way (a parameter tree from names)."""
    for p in path[:-1]:
        tree = tree.setdefault(p, {})
    tree[path[-1]] = value


# --------------------------------------------------------------------------------------------------
# safetensors (read with numpy; handles BF16, which safetensors.numpy cannot)

_ST_DTYPES = {"F64": "<f8", "F32": "<f4", "F16": "<f2", "BF16": "bf16"}


class _SafetensorsFile:
    def __init__(self, path: Path):
        self.path = path
        # A truncated or garbage file must be a DataError naming it, not a MemoryError (a random 8-byte
        # header length), a KeyError, or numpy's "mmap length is greater than file size" (issue 14.8).
        verify_checksum(path)
        size = path.stat().st_size
        try:
            with open(path, "rb") as f:
                n = struct.unpack("<Q", f.read(8))[0]
                if n > size - 8:
                    raise ValueError(f"header length {n} exceeds the file's {size} bytes")
                self.header = json.loads(f.read(n))
            if not isinstance(self.header, dict):
                raise ValueError(f"header is a {type(self.header).__name__}, not an object")
        except (struct.error, ValueError, UnicodeDecodeError) as e:  # JSONDecodeError is a ValueError
            raise DataError(f"not a safetensors file, or truncated ({e})", path=path) from None
        self.header.pop("__metadata__", None)
        self.offset = 8 + n
        for name, info in self.header.items():
            try:
                start, end = (int(x) for x in info["data_offsets"])
                count = int(np.prod(info["shape"], dtype=np.int64))
                item = 2 if info["dtype"] in ("F16", "BF16") else np.dtype(_ST_DTYPES.get(info["dtype"], "<f4")).itemsize
            except (KeyError, TypeError, ValueError) as e:
                raise DataError(f"malformed header entry for tensor {name!r} ({type(e).__name__}: {e})",
                                path=path) from None
            if not 0 <= start <= end or self.offset + end > size:
                raise DataError(f"tensor {name!r} lies at bytes {start}..{end} of the data, beyond the file's "
                                f"{size - self.offset} data bytes (truncated file?)", path=path)
            if info["dtype"] in _ST_DTYPES and end - start != count * item:
                raise DataError(f"tensor {name!r}: {end - start} bytes for shape {info['shape']} "
                                f"{info['dtype']}", path=path)

    def names(self) -> list[str]:
        return list(self.header)

    def shape(self, name: str) -> tuple[int, ...]:
        return tuple(self.header[name]["shape"])

    def get(self, name: str) -> np.ndarray:
        info = self.header[name]
        if info["dtype"] not in _ST_DTYPES:
            raise DataError(f"tensor {name!r} has dtype {info['dtype']}; expected a float type", path=self.path)
        start, end = info["data_offsets"]
        raw = np.memmap(self.path, dtype=np.uint8, mode="r", offset=self.offset + start, shape=(end - start,))
        if info["dtype"] == "BF16":  # bfloat16 = the top 16 bits of a float32
            arr = (np.frombuffer(raw, "<u2").astype(np.uint32) << 16).view(np.float32)
        else:
            arr = np.frombuffer(raw, _ST_DTYPES[info["dtype"]]).astype(np.float32)
        return arr.reshape(info["shape"])


def _open_weights(folder: Path) -> dict[str, _SafetensorsFile]:
    """Tensor name → the file holding it, for ``model.safetensors`` or a sharded index."""
    index = folder / INDEX_FILE
    single = folder / WEIGHTS_FILE
    if single.is_file():
        f = _SafetensorsFile(single)
        return {n: f for n in f.names()}
    if index.is_file():
        weight_map = get_field(read_json(index, expect=dict), "weight_map", dict, path=index)
        files: dict[str, _SafetensorsFile] = {}
        out = {}
        for name, shard in weight_map.items():
            if shard not in files:
                if not (folder / shard).is_file():
                    raise DataError(f"shard {shard} named by the index is missing", path=folder)
                files[shard] = _SafetensorsFile(folder / shard)
            out[name] = files[shard]
        return out
    other = [p.name for p in folder.glob("*.bin")] + [p.name for p in folder.glob("*.h5")]
    hint = f" (found {other}: convert them to safetensors)" if other else ""
    raise DataError(f"missing {WEIGHTS_FILE} or {INDEX_FILE}{hint}", path=folder)


# --------------------------------------------------------------------------------------------------
# Loading and exporting an encoder folder


def as_encoder(encoder: str | os.PathLike | FrozenEncoder) -> FrozenEncoder:
    """``encoder`` itself if already loaded, else the folder loaded (so a command loads it once)."""
    return encoder if isinstance(encoder, FrozenEncoder) else load_hf_t5_encoder(encoder)


def load_hf_t5_encoder(folder: str | os.PathLike) -> FrozenEncoder:
    """Load a Hugging Face-format T5 folder, encoder only, with no network access.

    Needs ``config.json``, ``model.safetensors`` (or shards + ``model.safetensors.index.json``) and
    ``spiece.model``. A full encoder–decoder checkpoint works: decoder tensors are ignored.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError("encoder folder does not exist", path=folder)
    missing = [n for n in (CONFIG_FILE, MODEL_FILENAME) if not (folder / n).is_file()]
    if not (folder / WEIGHTS_FILE).is_file() and not (folder / INDEX_FILE).is_file():
        missing.append(f"{WEIGHTS_FILE} (or {INDEX_FILE} with shards)")
    if missing:
        other = sorted(p.name for p in folder.iterdir() if p.suffix in (".bin", ".h5", ".msgpack", ".ckpt"))
        hint = f"; found {other}: convert them to safetensors" if other else ""
        raise DataError(f"missing {', '.join(missing)}; an encoder folder needs {CONFIG_FILE}, {WEIGHTS_FILE} "
                        f"and {MODEL_FILENAME}{hint}", path=folder)
    cfg = T5Config.from_hf(read_json(folder / CONFIG_FILE), folder / CONFIG_FILE)
    tok = Tokenizer.load(folder / MODEL_FILENAME)
    tensors = _open_weights(folder)
    # Tied checkpoints may keep the embedding only under the encoder's alias.
    if "shared.weight" not in tensors and "encoder.embed_tokens.weight" in tensors:
        tensors["shared.weight"] = tensors["encoder.embed_tokens.weight"]
    names = hf_param_names(cfg, encoder_only=True)
    absent = [n for n, _, _ in names if n not in tensors]
    if absent:
        raise DataError(f"weights lack {len(absent)} tensor(s) the config implies, e.g. {absent[:3]} "
                        f"(feed_forward_proj={cfg.feed_forward_proj!r}, num_layers={cfg.num_layers})", path=folder)
    emb_rows = tensors["shared.weight"].shape("shared.weight")[0]
    if emb_rows != cfg.vocab_size:
        raise DataError(f"vocab mismatch: embedding has {emb_rows} rows but config.json says vocab_size="
                        f"{cfg.vocab_size}", path=folder)
    if tok.vocab_size > cfg.vocab_size:
        raise DataError(f"vocab mismatch: {MODEL_FILENAME} emits ids up to {tok.vocab_size - 1} but the weights have "
                        f"{cfg.vocab_size} embedding rows (tokenizer and weights come from different models?)",
                        path=folder)
    expected = jax.eval_shape(lambda: T5EncoderModel(cfg).init(
        jax.random.key(0), jnp.zeros((1, 1), jnp.int32), jnp.ones((1, 1), jnp.int32))["params"])
    params: dict = {}
    for hf, path, transpose in names:
        a = tensors[hf].get(hf)
        a = a.T if transpose else a
        want = tuple(_get(expected, path).shape)
        if a.shape != want:
            raise DataError(f"tensor {hf!r} has shape {a.shape} (after transpose), config implies {want}",
                            path=tensors[hf].path)
        set_path(params, path, jnp.asarray(np.ascontiguousarray(a)))
    return FrozenEncoder(cfg, params, tok, folder)


def save_hf_t5_encoder(folder: str | os.PathLike, cfg: T5Config, params: Params, tokenizer: Tokenizer, *,
                       overwrite: bool = False, extra_config: dict | None = None) -> Path:
    """Write an encoder folder in Hugging Face format, atomically; ``load_hf_t5_encoder`` reads it back."""
    from safetensors.numpy import save_file

    if tokenizer.vocab_size > cfg.vocab_size:
        raise ValueError(f"tokenizer vocab {tokenizer.vocab_size} exceeds model vocab {cfg.vocab_size}")
    tensors = {hf: np.ascontiguousarray(np.asarray(_get(params, path), np.float32).T if tr
                                        else np.asarray(_get(params, path), np.float32))
               for hf, path, tr in hf_param_names(cfg, encoder_only=True)}
    with atomic_dir(folder, overwrite=overwrite) as tmp:
        atomic_write_json(tmp / CONFIG_FILE, cfg.to_hf(extra=extra_config))
        save_file(tensors, str(tmp / WEIGHTS_FILE), metadata={"format": "pt"})
        write_checksum(tmp / WEIGHTS_FILE)  # model.safetensors.sha256: flipped bytes are refused on load
        (tmp / MODEL_FILENAME).write_bytes(tokenizer.model_proto)
    return Path(folder)
