"""Tokenizer: training, T5 id layout, padding/masks/truncation, sentinels, dataset-side storage."""

from pathlib import Path

import numpy as np
import pytest

from handx_jax.infra.errors import DataError
from handx_jax.text import tokenizer as tk
from handx_jax.text.toy import toy_texts, write_toy_dataset

FIXTURE = Path(__file__).parent / "fixtures" / "t5_tiny_relu"


def _captions(n=40, seed=0):
    return [c for t in toy_texts(n, seed) for f in ("left", "right", "interaction") for c in t[f]]


@pytest.fixture(scope="module")
def tok():
    return tk.Tokenizer.train(_captions(), vocab_size=300, num_extra_ids=8)


def test_t5_id_layout_and_single_token_separators(tok):
    sp = tok.sp
    assert (sp.pad_id(), sp.eos_id(), sp.unk_id(), sp.bos_id()) == (0, 1, 2, -1)
    assert tok.num_sentinels == 8 and tok.sentinels_internal
    sep = [tok.sentinel_id(i) for i in range(4)]
    assert len(set(sep)) == 4 and all(tok.sp.id_to_piece(s) == f"<extra_id_{i}>" for i, s in enumerate(sep))
    ids = tok.encode_one(tk.join_fields("left hand waves", "right hand rests", "hands touch"))
    # each separator is exactly one token, and no stray "▁" piece sits next to it
    for i in range(3):
        assert ids.count(sep[i]) == 1
    assert tok.sp.piece_to_id("▁") not in ids
    assert ids[0] == sep[0] and ids[-1] == tk.EOS_ID
    assert tok.encode_one("<extra_id_2>", add_eos=False) == [sep[2]]


def test_round_trip(tok):
    texts = ["the left hand's thumb flexes slowly", "hands touch at the fingertips",
             tk.join_fields("left thumb taps", "right index finger curls", "the hands drift apart")]
    enc = tok.encode(texts)
    assert tok.decode(enc.ids_BxL) == texts


def test_padding_mask_truncation(tok):
    texts = ["hands touch", "the two hands move toward each other slowly at the start, then drift apart"]
    full = [tok.encode_one(t) for t in texts]
    L = len(full[0]) + 2
    assert len(full[1]) > L
    enc = tok.encode(texts, max_len=L)
    assert enc.ids_BxL.shape == enc.mask_BxL.shape == (2, L) and enc.ids_BxL.dtype == np.int32
    assert enc.num_truncated == 1
    np.testing.assert_array_equal(enc.lengths_B, [len(full[0]), L])
    np.testing.assert_array_equal(enc.mask_BxL[0], [1] * len(full[0]) + [0, 0])
    assert (enc.ids_BxL[0, len(full[0]):] == tk.PAD_ID).all()
    # truncation keeps the first L-1 tokens and the eos, as Hugging Face does
    np.testing.assert_array_equal(enc.ids_BxL[1], full[1][:L - 1] + [tk.EOS_ID])
    # without max_len: padded to the longest, nothing truncated
    enc2 = tok.encode(texts)
    assert enc2.ids_BxL.shape[1] == len(full[1]) and enc2.num_truncated == 0


def test_training_is_deterministic_and_order_free():
    caps = _captions(30, seed=3)
    a = tk.Tokenizer.train(caps, vocab_size=200)
    b = tk.Tokenizer.train(list(reversed(caps)) + caps[:10], vocab_size=200)
    assert a.model_proto == b.model_proto and a.fingerprint == b.fingerprint


def test_stock_t5_sentinels_follow_hugging_face():
    """A spiece.model without sentinel pieces gets <extra_id_N> = pieces + 99 - N (T5Tokenizer's layout)."""
    tok = tk.Tokenizer.load(FIXTURE)
    n = tok.sp.get_piece_size()
    assert not tok.sentinels_internal and tok.vocab_size == n + 100
    assert tok.sentinel_id(0) == n + 99 and tok.sentinel_id(99) == n
    assert tok.encode_one("<extra_id_1>", add_eos=False) == [n + 98]
    assert tok.decode([[n + 99, tk.EOS_ID]]) == ["<extra_id_0>"]


def test_stored_beside_dataset(tmp_path):
    data = write_toy_dataset(tmp_path / "data", num_clips=16)
    tok = tk.train_for_dataset(data, vocab_size=200)
    assert (data / "tokenizer" / "spiece.model").is_file() and (data / "tokenizer" / "tokenizer.json").is_file()
    assert tk.load_for_dataset(data).model_proto == tok.model_proto
    with pytest.raises(FileExistsError):
        tk.train_for_dataset(data)
    assert not list((data / "tokenizer").glob(".*tmp"))  # atomic write left no temporary behind


def test_load_errors(tmp_path):
    with pytest.raises(DataError, match="missing spiece.model"):
        tk.Tokenizer.load(tmp_path)
    (tmp_path / "spiece.model").write_bytes(b"not a model")
    with pytest.raises(DataError, match="not a SentencePiece model"):
        tk.Tokenizer.load(tmp_path)
    with pytest.raises(ValueError, match="num_extra_ids"):
        tk.Tokenizer.train(["a b c"], num_extra_ids=2)
