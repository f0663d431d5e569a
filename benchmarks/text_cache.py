"""Text-cache build speed (distinct captions encoded per second) for the pretraining presets' encoders.

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/text_cache.py [--presets tiny,small] [--clips 200]

Builds a toy caption dataset and a randomly initialised encoder of each preset's size (speed does not
depend on the weights' values), then builds the cache twice: ``cold`` includes XLA compilation of the
length buckets, ``warm`` reuses the compiled forward (the steady-state rate a large corpus sees).
Prints one JSON document.
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from handx_jax.text import tokenizer as tk
from handx_jax.text.cache import TextCache, build_cache
from handx_jax.text.pretrain import model_config
from handx_jax.text.hf import save_hf_t5_encoder
from handx_jax.text.t5 import T5EncoderModel, count_params
from handx_jax.text.toy import write_toy_dataset

sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/_peak.py, also when loaded by path
from _peak import emit  # noqa: E402


def bench(preset: str, data: Path, tok: tk.Tokenizer, work: Path, batch_size: int, dtype: str) -> dict:
    cfg = model_config(preset, tok.vocab_size)
    ids = jnp.ones((1, 4), jnp.int32)
    params = jax.jit(T5EncoderModel(cfg).init)(jax.random.key(0), ids, ids)["params"]
    enc_dir = save_hf_t5_encoder(work / f"enc_{preset}", cfg, jax.device_get(params), tok)
    out = {"preset": preset, "d_model": cfg.d_model, "layers": cfg.num_layers,
           "encoder_params": count_params(params), "batch_size": batch_size, "dtype": dtype}
    for phase, overwrite in (("cold", False), ("warm", True)):
        t0 = time.perf_counter()
        root = build_cache(data, enc_dir, dtype=dtype, batch_size=batch_size, overwrite=overwrite, log=lambda s: None)
        wall = time.perf_counter() - t0
        meta = TextCache.open(root).meta
        out[phase] = {"captions_per_s": meta["captions_per_s"], "encode_s": meta["build_seconds"],
                      "total_s_with_load": wall}
    out.update(rows=meta["num_rows"], captions=meta["num_captions"], Lmax=meta["Lmax"],
               mean_tokens=meta["mean_tokens"], flops_per_caption=meta["encoder_flops_per_caption"]["mean"])
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--presets", default="tiny,small")
    p.add_argument("--clips", type=int, default=200)
    p.add_argument("--batch-size", type=int, default=128)
    p.add_argument("--dtype", default="float16", choices=("float16", "float32"))
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        data = write_toy_dataset(work / "data", num_clips=a.clips)
        tok = tk.train_for_dataset(data, vocab_size=1000)
        results = [bench(pr, data, tok, work, a.batch_size, a.dtype) for pr in a.presets.split(",")]
    emit({"benchmark": "text_cache", "device": str(jax.devices()[0]), "backend": jax.default_backend(),
          "cpu": platform.processor() or platform.machine(), "clips": a.clips, "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
