"""Merge the ablation's own figures (OUT/ablation_raw.json), the standard evaluator's scores (``handx eval run
--json``: OUT/<cond>.eval.json over both samples per prompt, OUT/<cond>_g0.eval.json over the first) and the
steady-state timing (TIMING/ablation_raw.json) into ablation.json, and print the README's tables.

    python docs/results/guidance/collect.py --abl OUT --timing TIMING --dest docs/results/guidance
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

EVAL = ("rprec_top3", "fid", "contact_f1_inter", "contact_feasibility", "pen_1cm", "pen_depth", "mm_dist",
        "diversity")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--abl", required=True)
    ap.add_argument("--timing", required=True)
    ap.add_argument("--dest", required=True)
    args = ap.parse_args()
    abl = json.loads((Path(args.abl) / "ablation_raw.json").read_text())
    timing = json.loads((Path(args.timing) / "ablation_raw.json").read_text())
    for name, r in abl["conditions"].items():
        for key, file in (("standard_v4_both_samples", f"{name}.eval.json"), ("standard_v4_first_sample",
                                                                               f"{name}_g0.eval.json")):
            ev = json.loads((Path(args.abl) / file).read_text())
            r[key] = {k: [ev[k], ev[f"{k}_ci"]] for k in EVAL if k in ev}
        t = timing["conditions"][name]
        r["timing"] = {"prompts": timing["prompts"], "samples": timing["samples"], "seconds_steady": t["seconds"],
                       "seconds_first_call": t["seconds_first_call"]}
    dest = Path(args.dest) / "ablation.json"
    if dest.exists() and "typed_prompt" in json.loads(dest.read_text()):  # the README's typed-prompt figures
        abl["typed_prompt"] = json.loads(dest.read_text())["typed_prompt"]
    dest.write_text(json.dumps(abl, indent=1) + "\n")

    def table(head, rows):
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for row in rows:
            print("| " + " | ".join(row) + " |")
        print()

    conds = abl["conditions"]
    table(["guidance", "inter-hand cell F1 (P / R)", "feasibility inter", "feasibility intra", "Pen 1cm (%)",
           "pen depth (mm)"],
          [[n, f"{r['cell_f1_inter']:.3f} ({r['cell_precision_inter']:.3f} / {r['cell_recall_inter']:.3f})",
            f"{r['feasibility_inter']:.3f}", f"{r['feasibility_intra']:.3f}", f"{r['pen_1cm']:.2f}",
            f"{r['pen_depth_mm']:.2f}"] for n, r in conds.items()])

    def cell(e, k, d=3):
        return f"{e[k][0]:.{d}f} ± {e[k][1]:.{d}f}"

    table(["guidance", "top-3", "FID", "C-feas", "F1-inter (vs GT)", "Pen 1cm (%)", "pen depth (mm)"],
          [[n, *(cell(r["standard_v4_first_sample"], k, d) for k, d in (("rprec_top3", 3), ("fid", 2),
                                                                       ("contact_feasibility", 3),
                                                                       ("contact_f1_inter", 3), ("pen_1cm", 2),
                                                                       ("pen_depth", 2)))] for n, r in conds.items()])
    table(["guidance", "top-3", "FID", "C-feas", "F1-inter (vs GT)"],
          [[n, *(f"{r['standard_v4_both_samples'][k][0]:.3f}" for k in ("rprec_top3", "fid", "contact_feasibility",
                                                                       "contact_f1_inter"))] for n, r in conds.items()])
    table(["guidance", f"seconds ({timing['prompts']} samples, steady)", "first call (with compile)"],
          [[n, f"{r['timing']['seconds_steady']:.1f}", f"{r['timing']['seconds_first_call']:.1f}"]
           for n, r in conds.items()])


if __name__ == "__main__":
    main()
