"""Clear errors: encoder folders missing files, unsupported configs, vocabulary mismatches, bad weights."""

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from handx_jax.infra.errors import DataError
from handx_jax.text import cli
from handx_jax.text import tokenizer as tk
from handx_jax.text.hf import load_hf_t5_encoder
from handx_jax.text.toy import write_toy_dataset

FIXTURE = Path(__file__).parent / "fixtures" / "t5_tiny_relu"


@pytest.fixture
def folder(tmp_path):
    dst = tmp_path / "enc"
    shutil.copytree(FIXTURE, dst)
    return dst


def _edit_config(folder, **changes):
    doc = json.loads((folder / "config.json").read_text())
    doc.update(changes)
    (folder / "config.json").write_text(json.dumps(doc))


def test_missing_folder_and_files(folder, tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        load_hf_t5_encoder(tmp_path / "nope")
    for name, msg in (("config.json", "missing config.json"), ("spiece.model", "missing spiece.model"),
                      ("model.safetensors", "missing model.safetensors")):
        broken = tmp_path / f"no_{name}"
        shutil.copytree(folder, broken)
        (broken / name).unlink()
        with pytest.raises(DataError, match=msg) as e:
            load_hf_t5_encoder(broken)
        assert str(broken) in str(e.value)  # the message names the folder


def test_pytorch_bin_only_is_explained(folder):
    (folder / "model.safetensors").rename(folder / "pytorch_model.bin")
    with pytest.raises(DataError, match=r"pytorch_model.bin.*safetensors|safetensors.*pytorch_model.bin"):
        load_hf_t5_encoder(folder)


def test_missing_shard(folder):
    (folder / "model.safetensors").rename(folder / "model-00001-of-00002.safetensors")
    (folder / "model.safetensors.index.json").write_text(json.dumps({"weight_map": {
        "shared.weight": "model-00001-of-00002.safetensors", "encoder.final_layer_norm.weight":
            "model-00002-of-00002.safetensors"}}))
    with pytest.raises(DataError, match="shard model-00002-of-00002.safetensors .* missing"):
        load_hf_t5_encoder(folder)


@pytest.mark.parametrize("changes,msg", [
    ({"model_type": "bart"}, "unsupported config: model_type 'bart'"),
    ({"feed_forward_proj": "gated-silu"}, "unsupported config: feed_forward_proj 'gated-silu'"),
    ({"num_heads": None}, "unsupported config: required key 'num_heads'"),
    ({"d_kv": -1}, "unsupported config: d_kv must be positive"),
])
def test_unsupported_config(folder, changes, msg):
    _edit_config(folder, **changes)
    with pytest.raises(DataError, match=msg):
        load_hf_t5_encoder(folder)


def test_config_that_does_not_fit_the_weights(folder):
    _edit_config(folder, feed_forward_proj="gated-gelu")  # relu weights have wi, not wi_0/wi_1
    with pytest.raises(DataError, match="weights lack .*wi_0"):
        load_hf_t5_encoder(folder)
    _edit_config(folder, feed_forward_proj="relu", d_ff=128)
    with pytest.raises(DataError, match="DenseReluDense.wi.weight.* shape"):
        load_hf_t5_encoder(folder)


def test_vocab_mismatch(folder):
    _edit_config(folder, vocab_size=500)  # config disagrees with the embedding
    with pytest.raises(DataError, match="vocab mismatch: embedding has 184 rows but config.json says vocab_size=500"):
        load_hf_t5_encoder(folder)
    # a tokenizer with more ids than the weights have rows
    rng = np.random.default_rng(0)
    words = ["".join(rng.choice(list("abcdefghijklmnopqrstuvwxyz"), 6)) for _ in range(400)]
    big = tk.Tokenizer.train([" ".join(rng.choice(words, 12)) for _ in range(400)], vocab_size=400)
    assert big.vocab_size > 184
    _edit_config(folder, vocab_size=184)
    (folder / "spiece.model").write_bytes(big.model_proto)
    with pytest.raises(DataError, match="vocab mismatch: spiece.model emits ids up to"):
        load_hf_t5_encoder(folder)


def test_corrupt_weights(folder):
    (folder / "model.safetensors").write_bytes(b"\x05\x00\x00\x00\x00\x00\x00\x00{bad}")
    with pytest.raises(DataError, match="not a safetensors file"):
        load_hf_t5_encoder(folder)


def test_cli_errors_and_help(tmp_path, capsys):
    p = argparse.ArgumentParser(prog="handx")
    cli.add_parser(p.add_subparsers())
    for argv in (["text", "--help"], ["text", "encode", "--help"], ["text", "sentencepiece", "--help"],
                 ["text", "pretrain", "--help"], ["text", "cache", "--help"]):
        with pytest.raises(SystemExit) as e:
            p.parse_args(argv)
        assert e.value.code == 0
    assert "usage: handx text" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        p.parse_args(["text", "pretrain", "--data", "d", "--out", "o", "--preset", "huge"])
    a = p.parse_args(["text", "encode", "--encoder", str(tmp_path / "none"), "hello"])
    with pytest.raises(DataError, match="encoder folder does not exist"):
        a.func(a)
    data = write_toy_dataset(tmp_path / "data", num_clips=8)
    with pytest.raises(DataError, match="missing spiece.model"):
        tk.load_for_dataset(data)


@pytest.mark.parametrize("damage", ["truncated", "garbage", "huge_header", "bad_entry"])
def test_damaged_weights_are_named(folder, damage):
    """Issue 14.8: a truncated or garbage model.safetensors gave a ValueError (mmap length), MemoryError
    (a random header length) or KeyError that did not name the file."""
    p = folder / "model.safetensors"
    data = p.read_bytes()
    if damage == "truncated":
        p.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        p.write_bytes(np.random.default_rng(0).bytes(4096))
    elif damage == "huge_header":
        p.write_bytes((2 ** 62).to_bytes(8, "little") + data[8:])
    else:
        header = b'{"shared.weight": {"dtype": "F32", "shape": [2]}}'
        p.write_bytes(len(header).to_bytes(8, "little") + header)
    with pytest.raises(DataError, match=r"file .*model\.safetensors"):
        load_hf_t5_encoder(folder)


def test_checksum_catches_flipped_bytes(folder, tmp_path):
    """64 flipped bytes inside a tensor loaded silently; the sidecar written on save now refuses them."""
    from handx_jax.infra.checksums import checksum_path, verify_checksum, write_checksum
    from handx_jax.text.hf import save_hf_t5_encoder

    enc = load_hf_t5_encoder(folder)
    out = save_hf_t5_encoder(tmp_path / "saved", enc.cfg, enc.params, enc.tokenizer)
    w = out / "model.safetensors"
    assert checksum_path(w).read_text().split() == [__import__("hashlib").sha256(w.read_bytes()).hexdigest(), w.name]
    assert verify_checksum(w) and load_hf_t5_encoder(out).fingerprint == enc.fingerprint
    data = bytearray(w.read_bytes())
    data[-200:-136] = bytes(b ^ 0xFF for b in data[-200:-136])  # 64 bytes of the last tensor
    w.write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"file .*model\.safetensors: checksum mismatch"):
        load_hf_t5_encoder(out)
    write_checksum(w)  # re-blessed on purpose: loads again (the numbers are now different)
    assert load_hf_t5_encoder(out).fingerprint != enc.fingerprint
    assert verify_checksum(folder / "model.safetensors") is False  # no sidecar (e.g. a Hugging Face download)
    with pytest.raises(DataError, match="missing checksum"):
        verify_checksum(folder / "model.safetensors", required=True)


@pytest.mark.parametrize("damage", ["truncated", "garbage", "flipped", "other_structure"])
def test_params_msgpack_errors_name_the_file(tmp_path, damage):
    """The evaluator's params.msgpack: flax said "Unpack failed" or a ValueError without the file;
    flipped bytes loaded silently. read/write_params_msgpack name the file and check the sidecar."""
    from handx_jax.infra.param_files import read_params_msgpack, write_params_msgpack

    params = {"dense": {"kernel": np.arange(64, dtype=np.float32).reshape(8, 8), "bias": np.ones(8, np.float32)}}
    p = write_params_msgpack(tmp_path / "params.msgpack", params)
    back = read_params_msgpack(p, params)
    np.testing.assert_array_equal(back["dense"]["kernel"], params["dense"]["kernel"])
    data = p.read_bytes()
    if damage == "truncated":
        p.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        p.write_bytes(np.random.default_rng(0).bytes(len(data)))
    elif damage == "flipped":
        p.write_bytes(data[:100] + bytes(b ^ 0xFF for b in data[100:164]) + data[164:])
    else:
        write_params_msgpack(p, {"other": np.zeros(3, np.float32)})
    if damage != "other_structure":
        with pytest.raises(DataError, match=r"file .*params\.msgpack: checksum mismatch"):
            read_params_msgpack(p, params)
        p.with_name("params.msgpack.sha256").unlink()  # without a sidecar, the decoder's error names the file
        if damage == "flipped":
            return  # flipped float bytes decode "fine": only the checksum can tell
    with pytest.raises(DataError, match=r"file .*params\.msgpack: corrupt, truncated or incompatible"):
        read_params_msgpack(p, params)


def test_params_msgpack_reads_into_an_abstract_template_and_checks_shapes(tmp_path):
    """load_evaluator reads params.msgpack into jax.eval_shape of the init (no compiled init): the values come
    back as written, and a file of another model size (same tree, other shapes) is refused naming the leaf,
    where flax alone fills the tree without comparing shapes."""
    import jax

    from handx_jax.infra.param_files import read_params_msgpack, write_params_msgpack

    params = {"dense": {"kernel": np.arange(64, dtype=np.float32).reshape(8, 8), "bias": np.ones(8, np.float32)}}
    p = write_params_msgpack(tmp_path / "params.msgpack", params)
    abstract = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), params)
    back = read_params_msgpack(p, abstract)
    np.testing.assert_array_equal(back["dense"]["kernel"], params["dense"]["kernel"])
    np.testing.assert_array_equal(back["dense"]["bias"], params["dense"]["bias"])
    wider = {"dense": {"kernel": jax.ShapeDtypeStruct((8, 16), np.float32), "bias": jax.ShapeDtypeStruct((16,), np.float32)}}
    with pytest.raises(DataError, match=r"params\.msgpack: parameter \['dense'\]\['bias'\] has shape \(8,\), but this "
                                        r"configuration needs \(16,\)"):
        read_params_msgpack(p, wider)
