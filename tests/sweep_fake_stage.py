"""A light stand-in for a training stage (and a shared step), for launcher tests without JAX.

    python tests/sweep_fake_stage.py --out DIR [--seconds S] [--fail] [--family F] [--size N] [--tokenizer T]

Writes DIR/config.json and DIR/metrics.jsonl like a real run (a run folder analysis.schema reads),
appends one line per invocation to DIR/invocations.log (pid, env), writes DIR/pid while it works, and
sleeps ``--seconds`` in small steps so a kill lands mid-run.
"""

import argparse
import json
import os
import sys
import time
from pathlib import Path

p = argparse.ArgumentParser()
p.add_argument("--out", required=True)
p.add_argument("--seconds", type=float, default=0.0)
p.add_argument("--fail", action="store_true")
p.add_argument("--family", default="diffusion")
p.add_argument("--size", type=int, default=1)
p.add_argument("--tokenizer", default=None)
a = p.parse_args()
out = Path(a.out)
out.mkdir(parents=True, exist_ok=True)
with open(out / "invocations.log", "a") as f:
    f.write(json.dumps({"pid": os.getpid(), "cache": os.environ.get("JAX_COMPILATION_CACHE_DIR"),
                        "slurm_job": os.environ.get("SLURM_JOB_ID")}) + "\n")
(out / "pid").write_text(str(os.getpid()))
t_end = time.time() + a.seconds
while time.time() < t_end:
    time.sleep(0.05)
if a.fail:
    print("fake stage: failing on purpose", file=sys.stderr)
    sys.exit(3)
cfg = {"family": a.family, "model": {"layers": a.size, "dim": 32 * a.size}, "params": 1000 * a.size,
       "flops_per_sample": 1e6 * a.size}
if a.tokenizer:
    cfg["tokenizer"] = a.tokenizer
(out / "config.json").write_text(json.dumps(cfg))
(out / "metrics.jsonl").write_text(json.dumps({"step": 2, "loss": 1.0 / a.size, "samples_seen": 16}) + "\n")
