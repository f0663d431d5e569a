"""JAX against the PyTorch reference (``../shared/bench/torch_ref``), one after the other, same config.

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/vs_torch.py --torch-python ~/venv-torch/bin/python
    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/vs_torch.py --torch-python P --out docs/results/perf_cpu.json

Runs, in this order: the matmul peak (``_peak.py``), PyTorch training (``bench_train.py``), JAX training
(``diffusion.bench_train``: the real loop with dropout, AdamW, clipping), PyTorch DDIM + CFG sampling
(``bench_sample.py``), JAX DDIM + CFG sampling (``diffusion.bench_sample``: the compiled sampler), the
peak again. Prints one JSON document: both sides' figures, ``ratios`` (JAX / PyTorch throughput) and
each throughput as a fraction of the measured peak (the larger of the two peak measurements), with
the load average before and after, since on a shared machine every figure depends on it.

PyTorch is not a dependency of this project: give the interpreter of a separate environment that has
it (``--torch-python``; default ``$TORCH_PYTHON`` or ``python3``). The reference scripts are looked up
at ``../shared/bench/torch_ref`` from the repository root (``--torch-ref`` to override).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import jax  # noqa: E402

from _peak import emit, matmul_peak  # noqa: E402
from diffusion import bench_sample, bench_train  # noqa: E402
from handx_jax.families.diffusion import DiffusionRunConfig  # noqa: E402
from handx_jax.models.dit import PRESETS, forward_flops, init_denoiser  # noqa: E402


def default_torch_ref() -> Path:
    """``../shared/bench/torch_ref`` from the repository root; from a worktree nested deeper (e.g.
    ``/work/wt/<name>``), the nearest ancestor's ``shared/bench/torch_ref``."""
    for p in ROOT.parents:
        if (p / "shared" / "bench" / "torch_ref").is_dir():
            return p / "shared" / "bench" / "torch_ref"
    return ROOT.parent / "shared" / "bench" / "torch_ref"


def run_torch(python: str, ref: Path, script: str, a, steps: int) -> dict:
    cmd = [python, script, "--layers", str(a.m.layers), "--dim", str(a.m.dim), "--heads", str(a.m.heads),
           "--ff", str(a.m.ff), "--batch", str(a.batch), "--steps", str(steps), "--threads", str(a.threads),
           "--text-len", str(a.text_len)]
    p = subprocess.run(cmd, cwd=ref, capture_output=True, text=True)
    if p.returncode:
        sys.exit(f"error: {' '.join(cmd)} (in {ref}) failed:\n{p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1]) | {"command": " ".join(cmd)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--torch-python", default=os.environ.get("TORCH_PYTHON", "python3"))
    ap.add_argument("--torch-ref", default=str(default_torch_ref()))
    ap.add_argument("--preset", default="paper-4L")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--text-len", type=int, default=32)
    ap.add_argument("--train-steps", type=int, default=10, help="timed training steps on each side")
    ap.add_argument("--ddim-steps", type=int, default=50)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 2, help="torch.set_num_threads")
    ap.add_argument("--skip", default="", help="comma list of parts to leave out: train, sample")
    ap.add_argument("--out", help="also write the JSON here")
    a = ap.parse_args(argv)
    ref = Path(a.torch_ref)
    if not (ref / "bench_train.py").exists():
        sys.exit(f"error: no PyTorch reference at {ref} (bench_train.py missing); pass --torch-ref")
    a.m = PRESETS[a.preset]
    skip = set(filter(None, a.skip.split(",")))
    fwd = forward_flops(a.m, a.text_len)
    doc = {"machine": {"host": platform.node(), "cpus": os.cpu_count(), "platform": platform.platform(),
                       "processor": platform.processor(), "jax_backend": jax.default_backend(),
                       "device": jax.devices()[0].device_kind, "jax": jax.__version__,
                       "loadavg_before": os.getloadavg()},
           "config": {"preset": a.preset, "layers": a.m.layers, "dim": a.m.dim, "heads": a.m.heads, "ff": a.m.ff,
                      "dropout": a.m.dropout, "batch": a.batch, "text_len": a.text_len, "text_dim": a.m.text_dim,
                      "forward_flops_per_sample": fwd},
           "peak_start": matmul_peak()}
    jcfg = DiffusionRunConfig(preset=a.preset, model=a.m)
    with tempfile.TemporaryDirectory() as tmp:
        if "train" not in skip:
            doc["torch_train"] = run_torch(a.torch_python, ref, "bench_train.py", a, a.train_steps)
            doc["jax_train"] = bench_train(a.preset, jcfg, a.text_len, a.batch, a.train_steps, False, Path(tmp))
        if "sample" not in skip:
            doc["torch_sample"] = run_torch(a.torch_python, ref, "bench_sample.py", a, a.ddim_steps)
            params = init_denoiser(a.m, jax.random.PRNGKey(0), a.text_len)[1]
            doc["jax_sample"] = bench_sample(jcfg, params, a.text_len, a.batch, "ddim", a.ddim_steps, False)
    doc["peak_end"] = matmul_peak()
    doc["machine"]["loadavg_after"] = os.getloadavg()
    peak = max(doc["peak_start"]["flops_per_s"], doc["peak_end"]["flops_per_s"])
    doc["peak_flops_per_s"] = peak
    ratios, frac = {}, {}
    if "train" not in skip:
        t, j = doc["torch_train"]["samples_per_s"], doc["jax_train"]["samples_per_s"]
        ratios["train_samples_per_s"] = j / t
        frac["torch_train"], frac["jax_train"] = 3 * fwd * t / peak, 3 * fwd * j / peak
    if "sample" not in skip:
        t, j = doc["torch_sample"]["seconds"], doc["jax_sample"]["seconds_per_batch"]
        ratios["ddim_cfg_sampling_speed"] = t / j
        per_s = 2 * fwd * a.ddim_steps * a.batch  # full CFG work per batch (2 complete passes per step)
        frac["torch_sample"], frac["jax_sample"] = per_s / t / peak, per_s / j / peak
    doc["ratios_jax_over_torch"] = ratios
    doc["fraction_of_peak"] = frac
    emit(doc, a.out, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
