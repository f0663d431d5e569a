"""Span-corruption pretraining: the objective, the loss going down, exact resume, the exported encoder."""

import json

import jax
import numpy as np
import pytest

from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_jsonl
from handx_jax.cli import main
from handx_jax.text import tokenizer as tk
from handx_jax.text.pretrain import PretrainConfig, pretrain, span_corrupt, target_length
from handx_jax.text.hf import load_hf_t5_encoder
from handx_jax.text.toy import write_toy_dataset

SENTINELS = list(range(1000, 1032))


def _uncorrupt(inp, tgt):
    """Put the target spans back in place of their sentinels."""
    spans, cur = {}, None
    for t in tgt[:-1]:
        if t in SENTINELS:
            cur = t
            spans[cur] = []
        else:
            spans[cur].append(t)
    out = []
    for t in inp[:-1]:
        out += spans[t] if t in SENTINELS else [t]
    return out


def test_span_corruption_is_t5s():
    rng = np.random.default_rng(0)
    noise, spans = [], []
    for n in (1, 2, 5, 20, 60, 100):
        for _ in range(50):
            toks = rng.integers(10, 900, size=n).astype(np.int32)
            inp, tgt = span_corrupt(toks, SENTINELS, rng)
            assert inp[-1] == tgt[-1] == tk.EOS_ID
            assert _uncorrupt(inp.tolist(), tgt.tolist()) == toks.tolist()  # lossless split
            k = sum(t in SENTINELS for t in inp)
            assert tgt[0] == SENTINELS[0] and [t for t in inp if t in SENTINELS] == SENTINELS[:k]
            if n >= 20:
                noise.append((len(tgt) - 1 - k) / n)
                spans.append((len(tgt) - 1 - k) / k)
            assert len(tgt) <= target_length(n, 0.15, 3.0, len(SENTINELS))
    assert abs(np.mean(noise) - 0.15) < 0.01  # 15% noise
    assert abs(np.mean(spans) - 3.0) < 0.3  # mean span length 3


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = write_toy_dataset(tmp_path_factory.mktemp("pre") / "data", num_clips=48)
    tk.train_for_dataset(d, vocab_size=200)
    return d


CFG = PretrainConfig(preset="tiny", steps=24, batch_size=16, lr=3e-3, max_len=64, log_every=4, ckpt_every=8,
                     eval_every=1000)
CLI_ARGS = ["--preset", "tiny", "--steps", "24", "--batch-size", "16", "--lr", "3e-3", "--max-len", "64",
            "--log-every", "4", "--ckpt-every", "8", "--eval-every", "1000"]


def test_pretrain_lowers_loss_and_resumes_exactly(data, tmp_path):
    # the real entry point, through the CLI (same settings as CFG)
    assert main(["train", "t5", "--data", str(data), "--out", str(tmp_path / "b"), *CLI_ARGS]) == 0
    full = json.loads((tmp_path / "b" / "pretrain.json").read_text())
    assert full["eval_loss_end"] < full["eval_loss_start"] - 1.0
    assert full["train_loss_last"] < full["train_loss_first"]

    # the same run interrupted at step 12 and resumed
    assert pretrain(data, tmp_path / "c", CFG, log=lambda s: None, stop_at_step=12) is None
    assert not (tmp_path / "c" / "encoder").exists()
    resumed = pretrain(data, tmp_path / "c", CFG, log=lambda s: None)
    assert resumed["resumed_from"] == 12 and full["resumed_from"] is None
    rows_b = read_jsonl(tmp_path / "b" / "metrics.jsonl")
    rows_c = read_jsonl(tmp_path / "c" / "metrics.jsonl")
    # training rows every 4 steps; evaluation rows at step 0 and the end (the shared loop's hook)
    assert [r["step"] for r in rows_b] == [r["step"] for r in rows_c] == [0, 4, 8, 12, 16, 20, 24, 24]
    assert [r["step"] for r in rows_b if "eval_loss" in r] == [0, 24]
    for rb, rc in zip(rows_b, rows_c):
        for k in ("loss", "eval_loss", "grad_norm"):
            assert rb.get(k) == rc.get(k)
    eb, ec = load_hf_t5_encoder(tmp_path / "b" / "encoder"), load_hf_t5_encoder(tmp_path / "c" / "encoder")
    jax.tree.map(np.testing.assert_array_equal, eb.params, ec.params)
    assert eb.tokenizer.model_proto == tk.load_for_dataset(data).model_proto

    # the run folder's plain files
    cfg = json.loads((tmp_path / "b" / "config.json").read_text())
    assert cfg["pretrain"]["steps"] == 24 and cfg["n_params"]["encoder_total"] > 0
    assert sorted(p.name for p in (tmp_path / "b" / "checkpoints").iterdir() if not p.name.startswith(".")) \
        == ["16", "24"]

    # T5 pretraining is a trainable, not a model family: config.json says "trainable". A run written before
    # issue 42 said "family": "t5-pretrain"; it resumes to the same numbers, and its config.json is rewritten.
    assert cfg["trainable"] == "t5" and "family" not in cfg
    assert pretrain(data, tmp_path / "d", CFG, log=lambda s: None, stop_at_step=12) is None
    doc = json.loads((tmp_path / "d" / "config.json").read_text())
    doc.pop("trainable")
    (tmp_path / "d" / "config.json").write_text(json.dumps({"family": "t5-pretrain", **doc}))
    assert pretrain(data, tmp_path / "d", CFG, log=lambda s: None)["resumed_from"] == 12
    assert [r.get("loss") for r in read_jsonl(tmp_path / "d" / "metrics.jsonl")] == [r.get("loss") for r in rows_c]
    doc = json.loads((tmp_path / "d" / "config.json").read_text())
    assert doc["trainable"] == "t5" and "family" not in doc

    # a different config cannot resume into the same folder
    with pytest.raises(DataError, match=r"different configuration \(pretrain differ\)"):
        pretrain(data, tmp_path / "c", PretrainConfig(**{**CFG.__dict__, "lr": 1e-3}), log=lambda s: None)
