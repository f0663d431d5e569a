"""Bad AR training data (issue 31 items 5, 6): a token cache is checked against the tokenizer's codebook
when it is opened, before any training step (codes outside it trained to a NaN loss at step 5 and left a
run folder behind), and a truncated cache names its file (numpy said only "Failed to read all data for
array"). Hand-made caches, no model: milliseconds. The same refusals through ``handx train ar``, with no
run folder left, are in tests/test_ar_family.py (its trained tokenizer)."""

import json

import numpy as np
import pytest

from handx_jax.families.tokenizer import TOKEN_FORMAT, TOKEN_FORMAT_VERSION, TokenCache
from handx_jax.infra.errors import DataError

NB = 240  # the real size of the nominal 256 codebook (levels 8, 6, 5)


def _cache(tmp_path, codes, **meta):
    root = tmp_path / "cache"
    root.mkdir()
    np.save(root / "codes.npy", codes)
    doc = {"format": TOKEN_FORMAT, "format_version": TOKEN_FORMAT_VERSION, "nb_code": NB, "num_clips": codes.shape[0],
           "tokens_per_clip": codes.shape[1], "dataset_fingerprint": "ds", "tokenizer_fingerprint": "tok123", **meta}
    (root / "meta.json").write_text(json.dumps(doc))
    return root


def _codes():
    return np.random.default_rng(0).integers(0, NB, size=(8, 30)).astype(np.int32)


def test_a_cache_inside_the_codebook_opens_unchanged(tmp_path):
    codes = _codes()
    codes[0, 0], codes[1, 1] = 0, NB - 1  # both ends of the codebook
    np.testing.assert_array_equal(TokenCache.open(_cache(tmp_path, codes)).codes, codes)


@pytest.mark.parametrize("value, where", [(NB, "the first 240 at clip 3, token 7"),
                                          (NB + 60, "the first 300 at clip 3, token 7"),
                                          (-1, "the first -1 at clip 3, token 7")])
def test_codes_outside_the_codebook_are_refused_naming_file_clip_and_token(tmp_path, value, where):
    codes = _codes()
    codes[3, 7] = value
    codes[5, 0] = value
    root = _cache(tmp_path, codes)
    with pytest.raises(DataError) as e:
        TokenCache.open(root)
    assert str(e.value) == (f"file {root / 'codes.npy'}: 2 codes outside the codebook [0, 240) of tokenizer tok123, "
                            f"{where}; rebuild it with `handx data tokens`")


def test_a_truncated_cache_names_its_file(tmp_path):
    root = _cache(tmp_path, _codes())
    data = (root / "codes.npy").read_bytes()
    (root / "codes.npy").write_bytes(data[:len(data) // 2])
    with pytest.raises(DataError, match=r"^file .*/cache/codes\.npy: corrupt or truncated array \(.*\); "
                                        r"rebuild it with `handx data tokens`$"):
        TokenCache.open(root)


@pytest.mark.parametrize("codes, words", [(np.zeros((8, 29), np.int32), "codes shape (8, 29) does not match"),
                                          (np.zeros((8, 30), np.float32), "codes must be integers, got dtype float32")])
def test_a_cache_of_the_wrong_shape_or_dtype_is_refused(tmp_path, codes, words):
    root = _cache(tmp_path, codes, tokens_per_clip=30)
    with pytest.raises(DataError, match=words.replace("(", r"\(").replace(")", r"\)")):
        TokenCache.open(root)


def test_a_missing_joined_text_cache_asks_for_joined(tmp_path):
    """``handx train ar`` with only the plain (per-field) text cache built: the hint names --joined, the cache
    the AR family reads (it suggested the command that had already been run)."""
    from diffusion_fixtures import ENCODER, make_dataset

    from handx_jax.text.cache import open_cache

    ds = make_dataset(tmp_path)  # with its per-field cache
    open_cache(ds, ENCODER)  # the plain cache is there
    with pytest.raises(DataError) as e:
        open_cache(ds, ENCODER, joined=True)
    msg = str(e.value)
    assert "(max_len 128, float16, joined)" in msg and "\n" not in msg
    assert msg.endswith(f"run `handx text cache --data {ds} --encoder {ENCODER} --joined`"), msg
