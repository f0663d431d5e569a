"""AR-family throughput: tokenizer training samples/s, LM training tokens/s, decoding tokens/s with and
without the KV cache; MFU on a GPU.

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/ar.py [--tokenizer-presets tiny] [--lm-presets tiny,small]
    .venv/bin/python benchmarks/ar.py --tokenizer-presets paper --lm-presets 8L-512,12L-768 --batch-size 128  # GPU

- **Tokenizer training**: the real loop (``handx_jax.train.train``: jitted step, AdamW, host → device
  batches) on random normalised 48-frame windows; samples/s of the second log interval (compiled).
- **LM training**: the same loop on random codes and random text features of ``--text-len`` tokens;
  tokens/s counts the 31 motion slots (30 codes + END) per sample.
- **Decoding**: ``families.ar.decode.decode`` (one jitted ``while_loop``) greedy over 30 tokens with END masked
  out of the head so every row runs the full length; generated tokens/s with the KV cache and with a
  full recompute per step. The second call is timed.
- **Peak host memory**: each training benchmark runs in a fresh child process of this script and reports
  its peak resident set (``peak_rss_mb``, ``resource.getrusage(RUSAGE_SELF).ru_maxrss``): the process
  keeps its peak by design (``handx_jax.infra.hostmem``), so one process cannot tell two benchmarks apart.
  The figure includes JAX, XLA's compiled programs and the benchmark's random data.
- **MFU** (GPU only): analytic forward FLOPs (``models.fsq.forward_flops``, ``models.prefix_lm.forward_flops``)
  ×3 per training sample, over the peak dense bf16 FLOP/s of ``benchmarks/diffusion.py``'s table.

Prints one JSON document.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/_peak.py

from handx_jax.families.ar import decode as AD  # noqa: E402
from handx_jax.infra import hostdevices  # noqa: E402
from handx_jax.models import fsq as Q  # noqa: E402
from handx_jax.models import prefix_lm as P  # noqa: E402
from handx_jax.optim import OptimConfig  # noqa: E402
from handx_jax.train import TrainConfig, TrainSpec, train  # noqa: E402
from _peak import device_peak, emit, matmul_peak  # noqa: E402


def _loop_cfg(batch_size, steps, bf16, microbatch=0):
    return TrainConfig(steps=2 * steps, batch_size=batch_size, log_every=steps, ckpt_every=10 * steps, wandb="disabled",
                       bf16=bf16, prefetch=2, microbatch=microbatch, optim=OptimConfig(lr=1e-4))


def bench_tokenizer(preset: str, codebook: int, batch_size: int, steps: int, bf16: bool, work: Path) -> dict:
    cfg = dataclasses.replace(Q.PRESETS[preset], codebook=codebook)
    model = Q.FSQTokenizer(cfg)
    n = 4 * batch_size
    x = np.random.default_rng(0).normal(size=(n, 48, 288)).astype(np.float32)
    mean, scale = jnp.zeros(288), jnp.ones(288)

    def loss(params, batch, rng, train_):
        xhat, _ = model.apply(params, batch["x"])
        return Q.tokenizer_loss(xhat.astype(jnp.float32), batch["x"], mean, scale)

    rows = []
    train(work / f"tok_{preset}", TrainSpec(
        init=lambda r: Q.init_tokenizer(cfg, r, 48)[1], loss=loss, get_batch=lambda idx: {"x": x[idx]},
        num_examples=n, cfg=_loop_cfg(batch_size, steps, bf16), config={"family": "tokenizer"}), on_log=rows.append)
    fwd = Q.forward_flops(cfg, 48)
    return {"preset": preset, "codebook": codebook, "width": cfg.width, "params": Q.param_count(cfg),
            "flops_per_sample": fwd, "batch_size": batch_size, "bf16": bf16,
            "samples_per_s": rows[-1]["samples_per_s"], "first_interval_samples_per_s": rows[0]["samples_per_s"]}


def bench_lm(preset: str, nb_code: int, text_len: int, text_dim: int, batch_size: int, steps: int, bf16: bool,
             work: Path, microbatch: int = 0) -> dict:
    cfg = dataclasses.replace(P.PRESETS[preset], nb_code=nb_code, text_dim=text_dim)
    model = P.PrefixLM(cfg)
    n = 4 * batch_size
    r = np.random.default_rng(0)
    codes = r.integers(0, nb_code, size=(n, 30)).astype(np.int32)
    text = r.normal(size=(n, text_len, text_dim)).astype(np.float16)
    mask = np.ones((n, text_len), bool)
    rows = []
    train(work / f"lm_{preset}", TrainSpec(
        init=lambda k: P.init_lm(cfg, k, text_len)[1],
        loss=lambda p, b, k, t: P.lm_loss(model, p, b["text"].astype(jnp.float32), b["mask"], b["codes"]),
        get_batch=lambda idx: {"codes": codes[idx], "text": text[idx], "mask": mask[idx]}, num_examples=n,
        cfg=_loop_cfg(batch_size, steps, bf16, microbatch), config={"family": "ar"}), on_log=rows.append)
    sps = rows[-1]["samples_per_s"]
    return {"preset": preset, "nb_code": nb_code, **P.param_counts(cfg), "flops_per_sample": P.forward_flops(cfg, text_len),
            "batch_size": batch_size, "microbatch": microbatch, "bf16": bf16, "samples_per_s": sps,
            "tokens_per_s": 31 * sps}


def bench_decode(preset: str, nb_code: int, text_len: int, text_dim: int, batch: int, use_cache: bool) -> dict:
    cfg = dataclasses.replace(P.PRESETS[preset], nb_code=nb_code, text_dim=text_dim)
    model, params = P.init_lm(cfg, jax.random.PRNGKey(0), text_len)
    # END never wins, so every row decodes all 30 tokens (a fixed amount of work to time).
    params["params"]["head"]["kernel"] = params["params"]["head"]["kernel"].at[:, cfg.end_id].set(0.0)
    r = np.random.default_rng(1)
    text = jnp.asarray(r.normal(size=(batch, text_len, text_dim)), jnp.float32)
    mask = jnp.ones((batch, text_len), bool)
    obs = jnp.zeros((batch, 0), jnp.int32)

    def call(seed):
        toks, lens = AD.decode(model, params, text, mask, obs, jax.random.PRNGKey(seed), use_cache=use_cache)
        return jax.block_until_ready(toks), lens

    t0 = time.perf_counter()
    call(0)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    toks, lens = call(1)
    dt = time.perf_counter() - t0
    n_tok = int(np.asarray(lens).sum())
    return {"preset": preset, "kv_cache": use_cache, "batch": batch, "tokens": n_tok, "tokens_per_s": n_tok / dt,
            "seconds": dt, "first_call_s": first}


def peak_rss_mb() -> float:
    """This process's peak resident set so far, in MB (Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


CHILD_FLAG = "--child"


def run_child(kind: str, kwargs: dict) -> dict:
    """``bench_tokenizer``/``bench_lm`` in a fresh process of this script: its result plus ``peak_rss_mb``."""
    proc = subprocess.run([sys.executable, __file__, CHILD_FLAG, kind, json.dumps(kwargs)], capture_output=True,
                          text=True, env={**os.environ})
    if proc.returncode:
        raise RuntimeError(f"{kind} benchmark child failed (exit {proc.returncode}):\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def child_main(kind: str, kwargs: str) -> int:
    kw = json.loads(kwargs)
    with tempfile.TemporaryDirectory() as tmp:
        fn = bench_tokenizer if kind == "tokenizer" else bench_lm
        res = fn(**kw, work=Path(tmp))
    print(json.dumps({**res, "peak_rss_mb": peak_rss_mb()}))
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == [CHILD_FLAG]:
        return child_main(argv[1], argv[2])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tokenizer-presets", default="tiny")
    ap.add_argument("--lm-presets", default="tiny,small")
    ap.add_argument("--codebook", type=int, default=4096, help="nominal codebook (the LM vocabulary is its real size)")
    ap.add_argument("--text-len", type=int, default=96, help="joined-prefix tokens (synthetic text features)")
    ap.add_argument("--text-dim", type=int, default=768)
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--train-steps", type=int, default=10, help="timed steps (after as many warm-up)")
    ap.add_argument("--microbatch", type=int, default=0, help="LM training: train.microbatch (0: the whole batch)")
    ap.add_argument("--decode-batch", type=int, default=16)
    ap.add_argument("--bf16", choices=["auto", "on", "off"], default="auto")
    ap.add_argument("--out", help="also write the JSON here")
    args = ap.parse_args(argv)
    hostdevices.configure()  # before any JAX work: decoding splits its batch over the host's cores

    dev = jax.devices()[0]
    on_gpu = dev.platform == "gpu"
    bf16 = on_gpu if args.bf16 == "auto" else args.bf16 == "on"
    peak = device_peak(dev.device_kind) if on_gpu else None
    measured = matmul_peak()  # issue 15 §3: every training figure also as a fraction of this machine's peak
    print(f"[peak] {measured['dtype']} {measured['n']}² matmul: {measured['flops_per_s'] / 1e9:.1f} GFLOP/s",
          file=sys.stderr, flush=True)
    nb = Q.real_codebook_size(args.codebook)
    doc = {"device": dev.device_kind, "platform": dev.platform, "num_devices": jax.device_count(),
           "host": platform.node(), "jax": jax.__version__,
           "codebook": args.codebook, "nb_code": nb, "text_len": args.text_len, "peak_bf16_flops": peak,
           "measured_peak": measured, "tokenizer": [], "lm": [], "decode": []}

    def add_peak_fractions(res: dict) -> None:
        train_flops_per_s = 3 * res["flops_per_sample"] * res["samples_per_s"]  # forward + backward
        res["fraction_of_peak"] = train_flops_per_s / measured["flops_per_s"]
        if peak:
            res["mfu"] = train_flops_per_s / peak

    with tempfile.TemporaryDirectory() as tmp:
        for p in filter(None, args.tokenizer_presets.split(",")):
            res = run_child("tokenizer", dict(preset=p, codebook=args.codebook, batch_size=args.batch_size,
                                              steps=args.train_steps, bf16=bf16))
            add_peak_fractions(res)
            doc["tokenizer"].append(res)
            print(f"[tokenizer {p}] {res['samples_per_s']:.1f} samples/s ({res['fraction_of_peak']:.0%} of peak), "
                  f"peak host memory {res['peak_rss_mb']:.0f} MB", file=sys.stderr, flush=True)
        for p in filter(None, args.lm_presets.split(",")):
            res = run_child("lm", dict(preset=p, nb_code=nb, text_len=args.text_len, text_dim=args.text_dim,
                                       batch_size=args.batch_size, steps=args.train_steps, bf16=bf16,
                                       microbatch=args.microbatch))
            add_peak_fractions(res)
            doc["lm"].append(res)
            dec = [bench_decode(p, nb, args.text_len, args.text_dim, args.decode_batch, c) for c in (True, False)]
            dec[0]["speedup_vs_no_cache"] = dec[0]["tokens_per_s"] / dec[1]["tokens_per_s"]
            doc["decode"] += dec
            print(f"[lm {p}] train {res['tokens_per_s']:.0f} tokens/s ({res['fraction_of_peak']:.0%} of peak), "
                  f"peak host memory {res['peak_rss_mb']:.0f} MB; "
                  f"decode {dec[0]['tokens_per_s']:.0f} tokens/s (KV cache) vs {dec[1]['tokens_per_s']:.0f} (no cache)",
                  file=sys.stderr, flush=True)
    emit(doc, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
