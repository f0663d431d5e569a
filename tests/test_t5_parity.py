"""Parity with the PyTorch reference (transformers' T5EncoderModel), without torch.

Fixtures from tools/make_t5_fixture.py: random tiny T5 encoders (original t5 ReLU and v1.1
gated-GELU) in Hugging Face format, with the token ids and last hidden states transformers produced.
"""

import json
import shutil
import struct
from pathlib import Path

import jax
import numpy as np
import pytest

from handx_jax.text.hf import load_hf_t5_encoder, save_hf_t5_encoder

FIXTURES = Path(__file__).parent / "fixtures"
VARIANTS = ["t5_tiny_relu", "t5_tiny_gated"]


@pytest.mark.parametrize("name", VARIANTS)
def test_hidden_states_match_transformers(name):
    enc = load_hf_t5_encoder(FIXTURES / name)
    z = np.load(FIXTURES / name / "expected.npz")
    ids, mask = z["ids"], z["mask"]
    # same token ids as T5Tokenizer, sentinel separators included
    e = enc.tokenizer.encode([str(s) for s in z["sentences"]], max_len=ids.shape[1])
    np.testing.assert_array_equal(e.ids_BxL, ids)
    np.testing.assert_array_equal(e.mask_BxL, mask)
    assert ids.shape[1] > 32  # long enough to reach the logarithmic position buckets
    h = np.asarray(enc(ids, mask))
    valid = mask.astype(bool)
    assert np.abs(h - z["hidden"])[valid].max() < 1e-5
    assert np.abs(h - z["hidden_f64"])[valid].max() < 1e-5


@pytest.mark.parametrize("name", VARIANTS)
def test_sharded_weights_load_the_same(tmp_path, name):
    """Sharded safetensors + model.safetensors.index.json give the same parameters."""
    src = FIXTURES / name
    dst = tmp_path / name
    dst.mkdir()
    for f in ("config.json", "spiece.model"):
        shutil.copy(src / f, dst / f)
    header, data = _read_raw(src / "model.safetensors")
    names = sorted(header)
    weight_map = {}
    for k, part in enumerate((names[: len(names) // 2], names[len(names) // 2:])):
        shard = f"model-{k + 1:05d}-of-00002.safetensors"
        _write_raw(dst / shard, {n: header[n] for n in part}, data)
        weight_map.update({n: shard for n in part})
    (dst / "model.safetensors.index.json").write_text(json.dumps({"metadata": {}, "weight_map": weight_map}))
    a, b = load_hf_t5_encoder(src), load_hf_t5_encoder(dst)
    jax.tree.map(np.testing.assert_array_equal, a.params, b.params)
    assert a.fingerprint == b.fingerprint


def test_bfloat16_weights_are_read(tmp_path):
    """Checkpoints stored in bf16 (as flan-t5 often is) load as the float32 values they round to."""
    src = FIXTURES / "t5_tiny_gated"
    dst = tmp_path / "bf16"
    dst.mkdir()
    for f in ("config.json", "spiece.model"):
        shutil.copy(src / f, dst / f)
    header, data = _read_raw(src / "model.safetensors")
    tensors = {}
    for n, info in header.items():
        s, e = info["data_offsets"]
        a = np.frombuffer(data[s:e], "<f4")
        tensors[n] = (info["shape"], (a.view(np.uint32) >> 16).astype("<u2").tobytes())
    _write_bf16(dst / "model.safetensors", tensors)
    a, b = load_hf_t5_encoder(src), load_hf_t5_encoder(dst)
    for x, y in zip(jax.tree.leaves(a.params), jax.tree.leaves(b.params)):
        x, y = np.asarray(x), np.asarray(y)
        assert np.all(np.abs(x - y) <= np.abs(x) * 2 ** -7 + 1e-30)  # bf16 truncation error


def test_export_round_trip(tmp_path):
    """What save_hf_t5_encoder writes, load_hf_t5_encoder reads back bit for bit (one loader for all)."""
    a = load_hf_t5_encoder(FIXTURES / "t5_tiny_relu")
    save_hf_t5_encoder(tmp_path / "enc", a.cfg, a.params, a.tokenizer)
    b = load_hf_t5_encoder(tmp_path / "enc")
    assert b.cfg == a.cfg and b.fingerprint == a.fingerprint
    assert b.tokenizer.model_proto == a.tokenizer.model_proto


# -- raw safetensors helpers (kept local so the test checks the loader, not a shared writer) --------

def _read_raw(path):
    raw = Path(path).read_bytes()
    n = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8:8 + n])
    header.pop("__metadata__", None)
    return header, raw[8 + n:]


def _write_raw(path, header, data):
    out, blobs, off = {}, [], 0
    for name, info in header.items():
        s, e = info["data_offsets"]
        out[name] = {"dtype": info["dtype"], "shape": info["shape"], "data_offsets": [off, off + e - s]}
        blobs.append(data[s:e])
        off += e - s
    _dump(path, out, blobs)


def _write_bf16(path, tensors):
    out, blobs, off = {}, [], 0
    for name, (shape, blob) in tensors.items():
        out[name] = {"dtype": "BF16", "shape": shape, "data_offsets": [off, off + len(blob)]}
        blobs.append(blob)
        off += len(blob)
    _dump(path, out, blobs)


def _dump(path, header, blobs):
    h = json.dumps(header).encode()
    h += b" " * (-len(h) % 8)
    Path(path).write_bytes(struct.pack("<Q", len(h)) + h + b"".join(blobs))
