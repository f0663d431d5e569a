"""What the standard evaluator reads, and how much of it a tokenizer keeps (issue 30 item 5's diagnosis).

The standard corpus's test clips are put through a tokenizer (encode -> FSQ codes -> decode) and scored by the
standard evaluator v4 as if generated, whole and part by part: the ground truth's 288-d AR features with one
part replaced by the reconstruction's (models.fsq.PARTS: fingers = the 240 local joint positions, wrist
orientation = the 12 wrist-6D features, root = root velocity and left-right offset), and the fingers'
per-clip static pose (time mean) and dynamics (the rest) swapped between reconstruction and ground truth.
How finely the evaluator reads the fingers is measured on the ground truth alone: its finger positions with
Gaussian noise of 1 and 3 mm per coordinate (independent per frame), and with one 3 mm offset per clip.
Joints are the features' global joints (models.fsq.global_joints) placed at the clip's first right-wrist
position. No LM is involved: a row's top-3 is the ceiling for any LM over that tokenizer's codes.

    python docs/results/ar_cpu_study/ceiling.py DATA OUT TOK [TOK ...]   # writes OUT/ceiling.json

TOK: tokenizer run folders (a sweep's steps/tokenizer-K*). The ground truth's rows (and the no-finger-motion
row, which needs no tokenizer) come first, named "gt".
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from handx_jax import representation as rep
from handx_jax import standard
from handx_jax.dataset.format import Dataset
from handx_jax.interop.handx_npz import read_handx_npz
from handx_jax.evaluation import evaluate_generated
from handx_jax.families import tokenizer as T
from handx_jax.generation import split_prompts, write_generated
from handx_jax.metrics import MetricConfig
from handx_jax.models import fsq as Q

KEYS = ("rprec_top1", "rprec_top3", "rprec_top3_ci", "fid")


def score(npz: Path, ds, ev) -> dict:
    """``handx eval run --generated NPZ --evaluator standard --block 32``, in this process (one evaluator load)."""
    res = evaluate_generated(ev, read_handx_npz(npz), ds, MetricConfig(rprec_block=32),
                             cache=standard.reference_cache_dir())
    return {k: round(res.flat()[k], 4) for k in KEYS}


def main(data: str, out: str, toks: list[str]) -> None:
    ds, out, ev = Dataset.open(data), Path(out), standard.load()
    out.mkdir(parents=True, exist_ok=True)
    clips, prompts, motion = split_prompts(ds, "test", None, 0)
    gt = np.stack(motion)
    gt_u = rep.to_ar(gt.astype(np.float64)).astype(np.float32)
    root0 = gt[:, 0, 1, 0]  # the right wrist at frame 0: global_joints integrates from the origin
    (fing,) = Q.PARTS["fingers"]

    def write(name: str, f_u: np.ndarray) -> dict:
        j = np.asarray(Q.global_joints(jnp.asarray(f_u))) + root0[:, None, None, None, :]
        path = out / f"{name}.npz"
        write_generated(path, j, [[p] for p in prompts], source_clips=[ds.ids[c] for c in clips],
                        groups=[0] * len(clips))
        row = {"global_mm": round(float(np.linalg.norm(j - gt, axis=-1).mean() * 1000), 2), **score(path, ds, ev)}
        print(name, row, flush=True)
        return row

    def with_part(src_u, parts, base=gt_u):
        m = base.copy()
        for p in parts:
            for sl in Q.PARTS[p]:
                m[..., sl] = src_u[..., sl]
        return m

    def fingers(f_u, v):
        m = f_u.copy()
        m[..., fing] = v
        return m

    lp = gt_u[..., fing]
    static = lambda x: x.mean(axis=1, keepdims=True)  # noqa: E731  per-clip time mean
    rng = np.random.default_rng(0)
    noise = lambda sd, shape: rng.normal(0.0, sd, shape).astype(np.float32)  # noqa: E731  metres
    rows = {"gt": {"all": write("gt-all", gt_u),
                   "no finger motion": write("gt-static-fingers", fingers(gt_u, np.broadcast_to(static(lp), lp.shape))),
                   "finger noise 1 mm": write("gt-noise1mm", fingers(gt_u, lp + noise(0.001, lp.shape))),
                   "finger noise 3 mm": write("gt-noise3mm", fingers(gt_u, lp + noise(0.003, lp.shape))),
                   "finger offset 3 mm per clip": write("gt-offset3mm", fingers(gt_u, lp + noise(0.003, static(lp).shape)))}}
    for tok_dir in toks:
        tok = T.load(tok_dir)
        xh = tok.model.apply(tok.params, jnp.asarray(tok.norm.normalize(gt_u), jnp.float32))[0]
        pr_u = np.asarray(tok.norm.denormalize(np.asarray(xh)), np.float32)
        pl = pr_u[..., fing]
        name = f"K{tok.cfg.model.codebook}"
        rows[name] = {
            "all": write(f"{name}-all", pr_u),
            "fingers": write(f"{name}-fingers", with_part(pr_u, ["fingers"])),
            "wrist orientation": write(f"{name}-orient", with_part(pr_u, ["wrist_orient"])),
            "root": write(f"{name}-root", with_part(pr_u, ["root"])),
            "finger dynamics (static pose GT)": write(f"{name}-fdyn", fingers(gt_u, pl - static(pl) + static(lp))),
            "finger static pose (dynamics GT)": write(f"{name}-fstatic", fingers(gt_u, lp - static(lp) + static(pl))),
        }
    (out / "ceiling.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2], sys.argv[3:])
