"""Contact guidance ablation (issue 33 item 2): the same diffusion run and prompts, guidance off and on at two
strengths; contacts requested from each prompt's own record (``--contact caption``).

    python docs/results/guidance/ablation.py --run RUN --data DATA --out OUT [--prompts 128] [--samples 4]
        [--strengths 4,16] [--steps 25] [--repeats 1]

Prompts: the test clips whose records name an inter-hand contact (all of them), then clips naming only
intra-hand contacts, in clip order, up to ``--prompts``. Every condition samples with the same seed, DDIM
``--steps``, CFG at the run's scale. Per condition it writes OUT/<name>.npz (official layout with source_clip
and group, for ``handx eval run``) and the requested-contact figures; OUT/ablation.json collects them with
the standard evaluator's scores (run separately: see README.md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.families.diffusion import guidance as G
from handx_jax import metrics as M
from handx_jax.dataset.format import Dataset
from handx_jax.families.diffusion import load
from handx_jax.families.diffusion.sampling import SampleOptions
from handx_jax.generation import Prompt, with_records, write_generated

N_INTRA = 8  # channels 0..7 are intra-hand thumb pinches; 8..42 are inter-hand (25 tip-tip, 10 tip-palm)


def pick_clips(ds: Dataset, n: int) -> np.ndarray:
    clips = np.sort(np.asarray(ds.split("test")))
    named = M.named_contacts([ds.events[int(c)] for c in clips])
    inter = np.bincount(named.clip_E[named.channel_E >= N_INTRA], minlength=len(clips)) > 0
    anyc = np.bincount(named.clip_E, minlength=len(clips)) > 0
    order = np.concatenate([np.flatnonzero(inter), np.flatnonzero(anyc & ~inter)])[:n]
    return clips[np.sort(order)]


def requested_scores(joints_NxTx2x21x3: np.ndarray, request_NxTxC: np.ndarray) -> dict:
    """Against the request: per (clip, frame, channel) cell, contact = distance below the channel's threshold.
    inter-hand cell F1 over the 35 inter-hand channels (a contact where none was requested counts against
    precision); feasibility = share of requested contact runs realised in at least one of their frames."""
    W = jnp.asarray(M.palm_barycentric())
    d = np.asarray(M.contact_channel_distances(jnp.asarray(joints_NxTx2x21x3, jnp.float32), W))
    hit = d < M.contact_thresholds()[None, None]
    req = request_NxTxC > 0
    out = {}
    for name, sl in (("inter", slice(N_INTRA, None)), ("intra", slice(0, N_INTRA))):
        h, r = hit[..., sl], req[..., sl]
        tp, fp, fn = (h & r).sum(), (h & ~r).sum(), (~h & r).sum()
        p, rc = tp / max(tp + fp, 1), tp / max(tp + fn, 1)
        out[f"cell_precision_{name}"] = float(p)
        out[f"cell_recall_{name}"] = float(rc)
        out[f"cell_f1_{name}"] = float(2 * p * rc / max(p + rc, 1e-12))
        out[f"requested_cells_{name}"] = int(r.sum())
    return out


def feasibility(joints_NxTx2x21x3, named: M.NamedContacts) -> dict:
    W = M.palm_barycentric()
    out = {}
    for name, keep in (("inter", named.channel_E >= N_INTRA), ("intra", named.channel_E < N_INTRA)):
        sub = M.NamedContacts(named.clip_E[keep], named.channel_E[keep], named.start_E[keep], named.end_E[keep])
        hit, n = M.contact_feasibility_counts(joints_NxTx2x21x3, sub, W)
        out[f"feasibility_{name}"] = float(hit.sum() / max(n.sum(), 1))
        out[f"named_{name}"] = int(n.sum())
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--run", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--prompts", type=int, default=128)
    ap.add_argument("--samples", type=int, default=4)
    ap.add_argument("--strengths", default="4,16")
    ap.add_argument("--schedule", default="late")
    ap.add_argument("--steps", type=int, default=25)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=1,
                    help="sampling calls per condition: the first compiles, the last is the steady-state time")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ds = Dataset.open(args.data)
    clips = pick_clips(ds, args.prompts)
    ps = with_records([Prompt(*(ds.texts[c][f][-1] for f in ("left", "right", "interaction"))) for c in clips],
                      ds, clips)
    run = load(args.run)
    Gs = args.samples
    flat_records = [p.record for p in ps for _ in range(Gs)]
    named = M.named_contacts(flat_records)
    request = G.request_from_named(named, len(flat_records), run.cfg.model.frames)
    conds = [("off", 0.0)] + [(f"s{float(s):g}", float(s)) for s in args.strengths.split(",")]
    results = {"run": str(args.run), "data": str(args.data), "clips": [ds.ids[c] for c in clips],
               "prompts": len(clips), "samples": Gs, "sampler": f"ddim-{args.steps}", "schedule": args.schedule,
               "cfg_scale": run.cfg.diffusion.guidance, "seed": args.seed, "conditions": {}}
    for name, s in conds:
        opts = SampleOptions(sampler="ddim", steps=args.steps, seed=args.seed, batch_size=len(ps) * Gs,
                             contact="" if name == "off" else G.CAPTION, contact_strength=s,
                             contact_schedule=args.schedule)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            j = run.generate(ps, opts, samples=Gs, sources=[np.asarray(ds.motion[c], np.float32) for c in clips])
            jax.block_until_ready(j)
            times.append(time.perf_counter() - t0)
        flat = j.reshape(-1, *j.shape[2:])
        write_generated(out / f"{name}.npz", flat, [[p] for p in ps for _ in range(Gs)],
                        source_clips=[ds.ids[c] for c in clips for _ in range(Gs)],
                        groups=[g for _ in clips for g in range(Gs)])
        depth = np.asarray(M.interhand_penetration(jnp.asarray(flat)))
        pen, pdepth = M.penetration_stats(depth)
        r = {"strength": s, "seconds_first_call": times[0], "seconds": times[-1] if len(times) > 1 else None,
             "pen_1cm": float(pen.mean()), "pen_depth_mm": float(pdepth.mean()),
             **feasibility(flat, named), **requested_scores(flat, request)}
        results["conditions"][name] = r
        print(name, json.dumps(r), flush=True)
        (out / "ablation_raw.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
