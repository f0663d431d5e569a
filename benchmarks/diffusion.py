"""Diffusion-family throughput: training samples/s and sampling clips/s per preset; MFU on a GPU.

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/diffusion.py [--presets tiny,small] [--text-len 64]
    .venv/bin/python benchmarks/diffusion.py --presets paper-4L,paper-8L,paper-12L --batch-size 256   # GPU

- **Training**: the real loop (``handx_jax.train.train``: jitted step with AdamW, clipping, EMA, host →
  device batch transfer) on synthetic in-memory batches (random motion, random ``--text-dim`` text
  features of ``--text-len`` tokens). Two log intervals are run; the second (compiled, steady state)
  gives samples/s.
- **Sampling**: ``generation``'s compiled sampler (one ``lax.scan``) with classifier-free guidance
  (scale 2.5: conditional + unconditional pass per step) for DDPM-1000 and DDIM-50 at batch 32 clips;
  the second call is timed. ``--ddpm-estimate`` times DDPM over a respaced 50-step scan of the same
  per-step work and scales to 1000 steps (for slow CPUs).
- **MFU** (GPU only): analytic FLOPs (``models.dit.forward_flops`` at ``--text-len``; ×3 for a training
  step, ×2 per sampling step for CFG) per second over the device's peak dense bf16 FLOP/s (table below).
  Training runs in bf16 on a GPU (``--bf16`` to force either way).
- **Fraction of the measured peak** (every device): the same analytic FLOP/s over the machine's own
  jitted-matmul peak, measured at start-up (``benchmarks/_peak.py``: float32 2048² on CPU, bf16 on a
  GPU). Sampling FLOPs are counted as the full CFG work (two complete forward passes per step, as the
  PyTorch reference does); the sampler skips the text keys/values of every step after the first and
  the null pass's cross-attention, so this is "useful work per second", comparable across versions.

Prints one JSON document.
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.families.diffusion import DiffusionRunConfig, apply_overrides, make_loss, make_model, params_non_embedding
from handx_jax.infra import hostdevices
from handx_jax.families.diffusion.sampling import compile_sampler
from handx_jax.models.dit import PRESETS, forward_flops, init_denoiser, param_count
from handx_jax.train import TrainSpec, train
from handx_jax.infra.xla_options import inference_options

sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/_peak.py, also when loaded by path
from _peak import PEAK_BF16, device_peak, emit, matmul_peak  # noqa: E402


def bench_train(preset: str, cfg: DiffusionRunConfig, text_len: int, batch_size: int, steps: int, bf16: bool,
                work: Path) -> dict:
    m = cfg.model
    rng = np.random.default_rng(0)
    n = 4 * batch_size
    x0 = rng.normal(size=(n, m.frames, m.joints, m.channels)).astype(np.float32)
    text = rng.normal(size=(n, 3, text_len, m.text_dim)).astype(np.float16)
    mask = np.ones((n, 3, text_len), bool)
    cfg = apply_overrides(cfg, [f"train.steps={2 * steps}", f"train.log_every={steps}", f"train.batch_size={batch_size}",
                                f"train.ckpt_every={10 * steps}", "train.wandb=disabled", f"train.bf16={bf16}"])
    rows = []
    t0 = time.perf_counter()
    train(work / f"train_{preset}", TrainSpec(
        init=lambda r: init_denoiser(m, r, text_len)[1], loss=make_loss(make_model(m, bf16), cfg.diffusion),
        get_batch=lambda idx: {"x0": x0[idx], "text": text[idx], "mask": mask[idx]}, num_examples=n,
        cfg=cfg.train, config={"family": "diffusion"}), on_log=rows.append)
    return {"batch_size": batch_size, "bf16": bf16, "steps_timed": steps, "samples_per_s": rows[-1]["samples_per_s"],
            "first_interval_samples_per_s": rows[0]["samples_per_s"], "wall_s": time.perf_counter() - t0}


def bench_sample(cfg: DiffusionRunConfig, params, text_len: int, batch: int, sampler: str, steps: int,
                 estimate_ddpm: bool, cache: dict | None = None) -> dict:
    """Times one call of the compiled sampler after a first (compiling) call. With ``cache`` (a dict kept
    by the caller), the jitted sampler is kept there and a later call with the same arguments times
    one more call without compiling or warming up again (``first_call_s`` is then None)."""
    m = cfg.model
    timed_sampler, timed_steps = (sampler, steps)
    if sampler == "ddpm" and estimate_ddpm:
        timed_sampler, timed_steps = "ddim", 50
    key = (timed_sampler, timed_steps, text_len, batch, cfg)
    cache = {} if cache is None else cache
    compile_s = None
    if key not in cache:
        fn = compile_sampler(make_model(m), cfg.diffusion, sampler=timed_sampler, steps=timed_steps,
                             guidance=cfg.diffusion.guidance, batch=batch)
        r = np.random.default_rng(1)
        text = jnp.asarray(r.normal(size=(3, batch, text_len, m.text_dim)), jnp.float32)
        mask = jnp.ones((3, batch, text_len), bool)
        t0 = time.perf_counter()
        jax.block_until_ready(fn(params, text, mask, jax.random.PRNGKey(0), None, None))
        compile_s = time.perf_counter() - t0
        cache[key] = (fn, text, mask)
    fn, text, mask = cache[key]
    t0 = time.perf_counter()
    jax.block_until_ready(fn(params, text, mask, jax.random.PRNGKey(1), None, None))
    dt = time.perf_counter() - t0
    n_steps = cfg.diffusion.steps if sampler == "ddpm" else steps
    n_timed = cfg.diffusion.steps if timed_sampler == "ddpm" else timed_steps
    dt_full = dt * n_steps / n_timed
    return {"sampler": f"{sampler}-{n_steps}", "batch": batch, "guidance": cfg.diffusion.guidance,
            "clips_per_s": batch / dt_full, "seconds_per_batch": dt_full, "first_call_s": compile_s,
            "estimated_from_steps": None if n_timed == n_steps else n_timed,
            "compiler_options": inference_options(m.dim),  # what handx generate compiles with (xla_options)
            "devices": fn.mesh.size if hasattr(fn, "mesh") else 1}  # split over the host's CPU devices


def add_peak_fractions(res: dict, fwd: float, peak_flops: float) -> None:
    """Analytic FLOP/s (3 × forward per training sample; 2 × forward per sampling step and clip) and
    their fraction of the measured matmul peak, beside samples/s."""
    tr = res["train"]
    tr["flops_per_s"] = 3 * fwd * tr["samples_per_s"]
    tr["fraction_of_peak"] = tr["flops_per_s"] / peak_flops
    for s in res["sample"]:
        n = int(s["sampler"].split("-")[1])
        s["flops_per_s"] = 2 * fwd * n * s["clips_per_s"]
        s["fraction_of_peak"] = s["flops_per_s"] / peak_flops


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--presets", default="tiny,small")
    ap.add_argument("--text-len", type=int, default=64, help="tokens per prompt (synthetic text features)")
    ap.add_argument("--text-dim", type=int, default=768, help="text feature width (768 = T5-base)")
    ap.add_argument("--batch-size", type=int, default=32, help="training batch")
    ap.add_argument("--train-steps", type=int, default=10, help="timed training steps (after as many warm-up)")
    ap.add_argument("--sample-batch", type=int, default=32)
    ap.add_argument("--ddim-steps", type=int, default=50)
    ap.add_argument("--ddpm-estimate", action="store_true", help="time 50 steps and scale to DDPM-1000")
    ap.add_argument("--samplers", default="ddpm,ddim", help="which samplers to time (comma list)")
    ap.add_argument("--bf16", choices=["auto", "on", "off"], default="auto", help="training compute (auto: on for GPU)")
    ap.add_argument("--out", help="also write the JSON here")
    args = ap.parse_args(argv)
    hostdevices.configure()  # before any JAX work: sampling splits its batch over the host's cores

    dev = jax.devices()[0]
    on_gpu = dev.platform == "gpu"
    bf16 = on_gpu if args.bf16 == "auto" else args.bf16 == "on"
    peak = device_peak(dev.device_kind) if on_gpu else None
    measured = matmul_peak()
    print(f"[peak] {measured['dtype']} {measured['n']}² matmul: {measured['flops_per_s'] / 1e9:.1f} GFLOP/s",
          file=sys.stderr, flush=True)
    doc = {"device": dev.device_kind, "platform": dev.platform, "num_devices": jax.device_count(),
           "host": platform.node(), "jax": jax.__version__, "text_len": args.text_len, "text_dim": args.text_dim,
           "measured_peak": measured, "peak_bf16_flops": peak, "peak_table": PEAK_BF16, "results": []}
    with tempfile.TemporaryDirectory() as tmp:
        for preset in args.presets.split(","):
            m = PRESETS[preset]
            m = dataclasses.replace(m, text_dim=args.text_dim)
            cfg = DiffusionRunConfig(preset=preset, model=m)
            fwd = forward_flops(m, args.text_len)
            res = {"preset": preset, "layers": m.layers, "dim": m.dim, "heads": m.heads, "ff": m.ff,
                   "params": param_count(m), "params_non_embedding": params_non_embedding(m),
                   "flops_per_sample": fwd}
            res["train"] = bench_train(preset, cfg, args.text_len, args.batch_size, args.train_steps, bf16, Path(tmp))
            params = init_denoiser(m, jax.random.PRNGKey(0), args.text_len)[1]
            samplers = args.samplers.split(",")
            res["sample"] = [bench_sample(cfg, params, args.text_len, args.sample_batch, "ddpm", 1000,
                                          args.ddpm_estimate)] if "ddpm" in samplers else []
            if "ddim" in samplers:
                res["sample"].append(bench_sample(cfg, params, args.text_len, args.sample_batch, "ddim",
                                                  args.ddim_steps, False))
            add_peak_fractions(res, fwd, measured["flops_per_s"])
            if peak:
                res["train"]["mfu"] = 3 * fwd * res["train"]["samples_per_s"] / peak
                for s in res["sample"]:
                    n = int(s["sampler"].split("-")[1])
                    s["mfu"] = 2 * fwd * n * s["clips_per_s"] / peak  # 2 passes per step (CFG)
            doc["results"].append(res)
            print(f"[{preset}] train {res['train']['samples_per_s']:.1f} samples/s "
                  f"({res['train']['fraction_of_peak']:.0%} of peak); "
                  + "; ".join(f"{s['sampler']} {s['clips_per_s']:.2f} clips/s ({s['fraction_of_peak']:.0%} of peak)"
                              for s in res["sample"]),
                  file=sys.stderr, flush=True)
    emit(doc, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
