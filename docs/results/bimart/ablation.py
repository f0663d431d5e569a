"""BimArt's Tab. 3 on the procedural corpus: contact condition, guidance, refinement, the oracle map, baselines.

    JAX_PLATFORMS=cpu .venv/bin/python docs/results/bimart/ablation.py --run RUN --data OBJ --limit 8 --samples 2 \\
        --out docs/results/bimart/ablation.json

Every variant generates ``samples`` motions for each of the split's first ``limit`` clips (the same seed, so the
variants that differ only after sampling share their samples) and is scored by evaluation/object_clips.py (the
metrics of ``handx eval objects``). Beside them: the ground truth (its own hands and contact maps), another clip's
hands on each trajectory (the next clip of the split, cyclically), and the run's pipeline with untrained
(initial) weights for both models.
"""

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import numpy as np

from handx_jax.evaluation import object_clips
from handx_jax.families.bimart import GenerateOptions, load
from handx_jax.families.bimart import common as C
from handx_jax.models import bimart as BM

VARIANTS = {
    "without contact map": dict(contact="none", guidance=0.0, refine=False),
    "with contact map": dict(contact="generated", guidance=0.0, refine=False),
    "+ contact guidance": dict(contact="generated", guidance=1.0, refine=False),
    "+ refinement (BimArt)": dict(contact="generated", guidance=1.0, refine=True),
    "oracle contact map + guidance + refinement": dict(contact="ground_truth", guidance=1.0, refine=True),
}


def _gen_doc(data, out, samples):
    return {"joints": out["joints"], "object_state": data.states, "contact": out["contact"],
            "bps_points": data.bps_points, "records": data.records}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--limit", type=int, default=8)
    ap.add_argument("--samples", type=int, default=2)
    ap.add_argument("--batch-size", type=int, default=16, help="rows per compiled batch (one batch: fastest)")
    ap.add_argument("--variants", help="comma-separated subset of the variants (default: all)")
    ap.add_argument("--strengths", help="comma-separated guidance strengths s: also 'contact map + guidance s' "
                                        "variants (no refinement), the guidance scan")
    ap.add_argument("--no-baselines", action="store_true", help="skip the untrained-weights row")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override the run's sample config, e.g. sample.refine_cfg.param=joints (repeatable)")
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    run = load(a.run, overrides=a.set)
    clips = run.object_clips(a.data, a.split, a.limit)
    data = C.prepare(a.data, clips, run.cfg.model, motion=False)
    gt = data.joints
    table = {}
    gt_maps = np.asarray(C.unit_to_contact(data.contact)).reshape(len(clips), 1, *data.contact.shape[1:2], 2, 2, -1)
    table["ground truth"] = object_clips.score({"joints": gt[:, None], "object_state": data.states,
                                                "contact": gt_maps, "bps_points": data.bps_points,
                                                "records": data.records}, gt)
    other = np.roll(np.arange(len(clips)), -1)
    table["another clip's hands"] = object_clips.score({"joints": gt[other][:, None], "object_state": data.states,
                                                        "contact": gt_maps, "bps_points": data.bps_points,
                                                        "records": data.records}, gt)
    names = a.variants.split(",") if a.variants else list(VARIANTS)
    for x in (a.strengths.split(",") if a.strengths else []):
        VARIANTS[f"with contact map + guidance s={x}"] = dict(contact="generated", guidance=float(x), refine=False)
        names.append(f"with contact map + guidance s={x}")
    seconds = {}
    for name in names:
        t0 = time.perf_counter()
        out = run.generate_clips(data, GenerateOptions(**VARIANTS[name], batch_size=a.batch_size), samples=a.samples)
        seconds[name] = round(time.perf_counter() - t0, 1)
        table[name] = object_clips.score(_gen_doc(data, out, a.samples), gt)
        print(name, json.dumps({k: round(v, 4) for k, v in table[name].items()}), flush=True)
    # Untrained: both models at their initial weights, the full pipeline (guidance and refinement).
    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    untrained = dataclasses.replace(run, params=BM.init(k1, run.cfg.model, "motion"),
                                    contact=dataclasses.replace(run.contact,
                                                                params=BM.init(k2, run.contact.cfg.model, "contact")))
    if not a.no_baselines:
        out = untrained.generate_clips(data, GenerateOptions(batch_size=a.batch_size), samples=a.samples)
        table["untrained weights, full pipeline"] = object_clips.score(_gen_doc(data, out, a.samples), gt)
    doc = {"run": str(a.run), "step": run.step, "overrides": a.set, "sample": dataclasses.asdict(run.cfg.sample), "data": str(a.data), "split": a.split, "clips": [int(c) for c in clips],
           "samples": a.samples, "generation_seconds": seconds, "table": table}
    print(json.dumps(doc, indent=1))
    if a.out:
        Path(a.out).write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
