"""Build the T5 parity fixtures in tests/fixtures/t5_tiny_{relu,gated}/ with the PyTorch reference.

Runs OUTSIDE the project venv, in a throwaway environment that has torch (CPU), transformers and
sentencepiece; the tests that use its output need none of them:

    python3 -m venv /tmp/t5fix-venv
    /tmp/t5fix-venv/bin/pip install torch==2.13.0 transformers sentencepiece protobuf  # torch: the CPU wheel
    /tmp/t5fix-venv/bin/python tools/make_t5_fixture.py

For each variant (original t5 ``relu``, v1.1/flan ``gated-gelu``) it writes a Hugging Face folder
(config.json, model.safetensors, spiece.model) holding a random tiny T5 encoder, plus
``expected.npz``: the token ids and attention mask that transformers' ``T5Tokenizer`` gives a few
sentences, and the last hidden states that ``T5EncoderModel`` computes for them (``hidden`` in
float32, ``hidden_f64`` from the same model in float64). Layer-norm scales
and relative-position tables are randomised too, so a loader that dropped them would fail parity.
It also writes ``buckets.json`` (T5's relative-position buckets for offsets −200..200).
"""

from __future__ import annotations

import io
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import sentencepiece as spm
import torch
from transformers import T5Config, T5EncoderModel, T5Tokenizer
from transformers.models.t5.modeling_t5 import T5Attention

ROOT = Path(__file__).resolve().parents[1] / "tests" / "fixtures"

CORPUS = [
    "the left hand slowly curls its index finger toward the palm",
    "the right hand spreads all five fingers wide and holds still",
    "both hands move toward each other until the fingertips touch",
    "the left thumb taps the right palm twice in quick succession",
    "the right wrist rotates outward while the fingers stay relaxed",
    "the hands separate and drift apart at shoulder height",
    "the index and middle fingers of the left hand extend together",
    "the right hand grips an imaginary ball and releases it",
]

SENTENCES = [
    "the left hand curls its index finger",
    "both hands touch",
    "<extra_id_0> the left hand waves <extra_id_1> the right hand rests <extra_id_2> the hands stay apart",
    # long enough (> 16 tokens) to reach the logarithmic position buckets
    "the right hand spreads all five fingers wide and holds still while the left thumb taps the right palm "
    "twice in quick succession and the hands separate and drift apart at shoulder height",
]

VARIANTS = {
    "t5_tiny_relu": dict(feed_forward_proj="relu", relative_attention_num_buckets=32,
                         relative_attention_max_distance=128),
    "t5_tiny_gated": dict(feed_forward_proj="gated-gelu", relative_attention_num_buckets=16,
                          relative_attention_max_distance=32),
}


def train_spiece() -> bytes:
    """A tiny stock-T5-style SentencePiece model: pad 0, eos 1, unk 2, no sentinel pieces."""
    buf = io.BytesIO()
    spm.SentencePieceTrainer.train(
        sentence_iterator=iter(CORPUS * 4), model_writer=buf, model_type="unigram", vocab_size=96,
        hard_vocab_limit=False, pad_id=0, eos_id=1, unk_id=2, bos_id=-1, character_coverage=1.0,
        normalization_rule_name="identity", num_threads=1, minloglevel=2)  # identity: no 240 kB NFKC table
    return buf.getvalue()


def build(name: str, overrides: dict, spiece: bytes, seed: int) -> None:
    out = ROOT / name
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    (out / "spiece.model").write_bytes(spiece)
    pieces = spm.SentencePieceProcessor(model_proto=spiece).get_piece_size()
    vocab = -(-(pieces + 100) // 8) * 8  # HF's 100 extra ids past the pieces, padded as t5 pads to 32128
    cfg = T5Config(vocab_size=vocab, d_model=32, d_kv=8, d_ff=64, num_layers=2, num_decoder_layers=2, num_heads=4,
                   dropout_rate=0.0, layer_norm_epsilon=1e-6, **overrides)
    torch.manual_seed(seed)
    model = T5EncoderModel(cfg).eval()
    with torch.no_grad():
        for n, p in model.named_parameters():
            if "layer_norm" in n:
                p.copy_(1.0 + 0.2 * torch.randn_like(p))
            elif "relative_attention_bias" in n:
                p.copy_(0.5 * torch.randn_like(p))
            else:  # HF's init scale, redrawn so the fixture does not depend on its init code
                p.copy_(torch.randn_like(p) * p.shape[-1] ** -0.5)
    model.save_pretrained(out, safe_serialization=True)
    (out / "model.safetensors").chmod(0o644)

    tok = T5Tokenizer.from_pretrained(out)  # reads spiece.model; adds <extra_id_0..99> past the pieces
    batch = tok(SENTENCES, padding=True, return_tensors="pt")
    with torch.no_grad():
        hidden = model(**batch).last_hidden_state.numpy()
        # The same reference run in float64: float32 rounding of either implementation, not of both, is
        # then what a parity test sees.
        hidden64 = model.double()(**batch).last_hidden_state.numpy()
    np.savez(out / "expected.npz", ids=batch["input_ids"].numpy().astype(np.int32),
             mask=batch["attention_mask"].numpy().astype(np.int32), hidden=hidden.astype(np.float32),
             hidden_f64=hidden64.astype(np.float64), sentences=np.array(SENTENCES))
    size = sum(p.stat().st_size for p in out.iterdir())
    print(f"{name}: vocab {vocab}, {sum(p.numel() for p in model.parameters())} params, {size} bytes, "
          f"ids {batch['input_ids'].shape}")


def buckets() -> None:
    rel = torch.arange(-200, 201)[None, :]
    doc = {"relative_position": list(range(-200, 201)), "cases": []}
    for bidirectional, nb, md in ((True, 32, 128), (False, 32, 128), (True, 16, 32)):
        b = T5Attention._relative_position_bucket(rel, bidirectional=bidirectional, num_buckets=nb, max_distance=md)
        doc["cases"].append({"bidirectional": bidirectional, "num_buckets": nb, "max_distance": md,
                             "buckets": b[0].tolist()})
    (ROOT / "t5_tiny_relu" / "buckets.json").write_text(json.dumps(doc, separators=(",", ":")) + "\n")


def main() -> int:
    spiece = train_spiece()
    for i, (name, ov) in enumerate(VARIANTS.items()):
        build(name, ov, spiece, seed=1234 + i)
    buckets()
    return 0


if __name__ == "__main__":
    sys.exit(main())
