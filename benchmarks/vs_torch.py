"""JAX against the PyTorch reference (``../shared/bench/torch_ref``), side by side in one run, same config.

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/vs_torch.py --torch-python ~/venv-torch/bin/python
    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/vs_torch.py --torch-python P --repeats 5 --out F.json

Each of ``--repeats`` rounds runs, for training and then for sampling, one measurement of each side
back to back: PyTorch training (``bench_train.py``) and JAX training (``diffusion.bench_train``: the real
loop with dropout, AdamW, clipping), PyTorch DDIM + CFG sampling (``bench_sample.py``) and JAX DDIM + CFG
sampling (``diffusion.bench_sample``: the compiled sampler). The side that goes first alternates from
round to round, so a drift in the machine's speed does not favour either side. The matmul peak
(``_peak.py``) is measured before the first round and after the last.

Why rounds: on a shared 2-core machine one measurement of either side moves by 20-40% from run to run
(docs/results/perf_cpu.json), so a single pair gives a ratio anywhere in 0.95-1.40x. The ratios
reported (``ratios_jax_over_torch``) are of the two sides' medians over the rounds; ``ratio_per_round``
gives each round's own ratio, whose spread says how far to trust the median. Every throughput is also
given as a fraction of the measured peak (the larger of the two peak measurements), with the load
average before and after.

JAX compiles once: the compiled sampler is kept across rounds, and the training step comes from a
persistent compilation cache in a temporary folder (unless ``JAX_COMPILATION_CACHE_DIR`` is set), so
only the first round pays for compilation. Neither side's timed interval includes it in any round.

PyTorch is not a dependency of this project: give the interpreter of a separate environment that has
it (``--torch-python``; default ``$TORCH_PYTHON`` or ``python3``). The reference scripts are looked up
at ``../shared/bench/torch_ref`` from the repository root (``--torch-ref`` to override).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
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
from handx_jax.infra import hostdevices  # noqa: E402
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


# part: (PyTorch's field, JAX's field, the unit both are in, the name of their ratio)
PARTS = {"train": ("samples_per_s", "samples_per_s", "samples_per_s", "train_samples_per_s"),
         "sample": ("seconds", "seconds_per_batch", "seconds", "ddim_cfg_sampling_speed")}


def _speed(unit: str, value: float) -> float:
    """Work per second, up to a constant: a time's inverse, a throughput as it is."""
    return 1.0 / value if unit == "seconds" else value


def summary(row: dict) -> str:
    """One round's figures on one line (stderr progress)."""
    out = []
    for part, (t_key, j_key, unit, _) in PARTS.items():
        if f"jax_{part}" in row:
            t, j = row[f"torch_{part}"][t_key], row[f"jax_{part}"][j_key]
            out.append(f"{part} JAX {j:.2f} / torch {t:.2f} {unit} ({_speed(unit, j) / _speed(unit, t):.2f}x)")
    return "; ".join(out)


def aggregate(rounds: list[dict], fwd: int, peak: float, ddim_steps: int, batch: int) -> dict:
    """Medians over the rounds, the ratio of the medians (JAX over PyTorch; > 1: JAX faster), each
    round's own ratio, and the medians as fractions of ``peak`` (3 forward passes per training sample;
    2 complete passes per sampling step and clip, the CFG work as PyTorch does it)."""
    med, ratios, per_round, frac = {}, {}, {}, {}
    flops = {"train": 3 * fwd, "sample": 2 * fwd * ddim_steps * batch}  # per unit of work
    for part, (t_key, j_key, unit, name) in PARTS.items():
        if f"jax_{part}" not in rounds[0]:
            continue
        both = {"torch": [x[f"torch_{part}"][t_key] for x in rounds], "jax": [x[f"jax_{part}"][j_key] for x in rounds]}
        for side, values in both.items():
            med[f"{side}_{part}_{unit}"] = statistics.median(values)
            frac[f"{side}_{part}"] = flops[part] * _speed(unit, med[f"{side}_{part}_{unit}"]) / peak
        ratios[name] = _speed(unit, med[f"jax_{part}_{unit}"]) / _speed(unit, med[f"torch_{part}_{unit}"])
        per_round[name] = [_speed(unit, j) / _speed(unit, t) for t, j in zip(both["torch"], both["jax"])]
    return {"peak_flops_per_s": peak, "medians": med, "ratios_jax_over_torch": ratios, "ratio_per_round": per_round,
            "fraction_of_peak": frac}


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
    ap.add_argument("--repeats", type=int, default=3,
                    help="rounds of (PyTorch, JAX) pairs, sides alternating which goes first; medians reported")
    ap.add_argument("--skip", default="", help="comma list of parts to leave out: train, sample")
    ap.add_argument("--out", help="also write the JSON here")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error(f"--repeats must be at least 1, got {a.repeats}")
    ref = Path(a.torch_ref)
    if not (ref / "bench_train.py").exists():
        sys.exit(f"error: no PyTorch reference at {ref} (bench_train.py missing); pass --torch-ref")
    a.m = PRESETS[a.preset]
    hostdevices.configure()  # before any JAX work: sampling splits its batch over the host's cores
    skip = set(filter(None, a.skip.split(",")))
    fwd = forward_flops(a.m, a.text_len)
    with tempfile.TemporaryDirectory() as tmp:
        # Before anything compiles: JAX reads the cache setting when it first compiles.
        if not os.environ.get("JAX_COMPILATION_CACHE_DIR"):
            jax.config.update("jax_compilation_cache_dir", str(Path(tmp) / "jax_cache"))
        doc = side_by_side(a, ref, skip, fwd, Path(tmp))
    emit(doc, a.out, indent=1)
    return 0


def side_by_side(a, ref: Path, skip: set, fwd: int, tmp: Path) -> dict:
    doc = {"machine": {"host": platform.node(), "cpus": os.cpu_count(), "platform": platform.platform(),
                       "processor": platform.processor(), "jax_backend": jax.default_backend(),
                       "device": jax.devices()[0].device_kind, "jax": jax.__version__, "jax_devices": jax.device_count(),
                       "loadavg_before": os.getloadavg()},
           "config": {"preset": a.preset, "layers": a.m.layers, "dim": a.m.dim, "heads": a.m.heads, "ff": a.m.ff,
                      "dropout": a.m.dropout, "batch": a.batch, "text_len": a.text_len, "text_dim": a.m.text_dim,
                      "forward_flops_per_sample": fwd},
           "peak_start": matmul_peak()}
    jcfg = DiffusionRunConfig(preset=a.preset, model=a.m)
    params = init_denoiser(a.m, jax.random.PRNGKey(0), a.text_len)[1] if "sample" not in skip else None
    sampler_cache: dict = {}

    def measure(part: str, side: str, r: int) -> dict:
        if side == "torch":
            script, steps = ("bench_train.py", a.train_steps) if part == "train" else ("bench_sample.py", a.ddim_steps)
            return run_torch(a.torch_python, ref, script, a, steps)
        if part == "train":
            return bench_train(a.preset, jcfg, a.text_len, a.batch, a.train_steps, False, tmp / f"round{r}")
        return bench_sample(jcfg, params, a.text_len, a.batch, "ddim", a.ddim_steps, False, cache=sampler_cache)

    doc["rounds"] = []
    for r in range(a.repeats):
        row = {"round": r, "first": "torch" if r % 2 == 0 else "jax"}
        for part in ("train", "sample"):
            if part not in skip:
                for side in (("torch", "jax") if r % 2 == 0 else ("jax", "torch")):
                    row[f"{side}_{part}"] = measure(part, side, r)
        doc["rounds"].append(row)
        print(f"[round {r + 1}/{a.repeats}] " + summary(row), file=sys.stderr, flush=True)
    doc["peak_end"] = matmul_peak()
    doc["machine"]["loadavg_after"] = os.getloadavg()
    doc.update(aggregate(doc["rounds"], fwd, max(doc["peak_start"]["flops_per_s"], doc["peak_end"]["flops_per_s"]),
                         a.ddim_steps, a.batch))
    return doc


if __name__ == "__main__":
    sys.exit(main())
