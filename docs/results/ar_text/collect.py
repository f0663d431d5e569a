"""Collect the AR text-following rows (docs/results/ar_text/README.md): each row's eval.json (standard
evaluator v4, block 32) beside its run's last held-out NLL with its own text and with another held-out
clip's text (the `eval/*` rows the AR family's evaluation hook writes to metrics.jsonl).

    python docs/results/ar_text/collect.py NAME=RUN:EVAL_DIR ... --out docs/results/ar_text
"""

import argparse
import json
import shutil
from pathlib import Path

KEYS = ("rprec_top1", "rprec_top2", "rprec_top3", "fid", "diversity", "mm_dist")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rows", nargs="+", help="NAME=RUN_DIR:EVAL_DIR")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    out = Path(a.out)
    rows = []
    for spec in a.rows:
        name, rest = spec.split("=", 1)
        run, ev = (Path(p) for p in rest.split(":"))
        e = json.loads((ev / "eval.json").read_text())
        cfg = json.loads((run / "config.json").read_text())
        evals = [json.loads(l) for l in (run / "metrics.jsonl").read_text().splitlines() if '"eval/nll"' in l]
        gen = json.loads((ev / "generate.json").read_text()) if (ev / "generate.json").exists() else {}
        rows.append({"row": name, "run": str(run), "steps": cfg["train"]["steps"], "lr": cfg["train"]["optim"]["lr"],
                     "batch_size": cfg["train"]["batch_size"], "layers": cfg["model"]["layers"], "dim": cfg["model"]["dim"],
                     "levels": cfg["data"].get("levels", []), "text_drop": cfg["data"].get("text_drop", 0.0), **gen,
                     **{k: e[k] for k in KEYS}, **{k + "_ci": e[k + "_ci"] for k in KEYS},
                     "prompts": e["_meta"]["prompts"], "groups": e["_meta"]["groups"], "block": e["_meta"]["rprec_block"],
                     "evaluator": e["_meta"].get("evaluator_name"), "ci_method": e["_meta"]["ci_method"]["rprec_top3"],
                     "nll": evals[-1]["eval/nll"], "nll_other_text": evals[-1].get("eval/nll_other_text"),
                     "text_gap_curve": [(r["step"], round(r["eval/text_gap"], 4)) for r in evals if "eval/text_gap" in r]})
        row_dir = out / "runs" / name  # a run folder analyze table reads: config, metrics, eval
        row_dir.mkdir(parents=True, exist_ok=True)
        for f in ("config.json", "metrics.jsonl"):
            shutil.copy(run / f, row_dir / f)
        shutil.copy(ev / "eval.json", row_dir / "eval.json")
    (out / "rows.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["| row | Top-1 | Top-3 | FID | Diversity | MM-Dist | held-out NLL own text | other clip's text | gap |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        f = lambda k, d=3: f"{r[k]:.{d}f} ± {r[k + '_ci']:.{d}f}"  # noqa: E731
        lines.append(f"| {r['row']} | {f('rprec_top1')} | {f('rprec_top3')} | {f('fid', 2)} | {f('diversity', 2)} | "
                     f"{f('mm_dist', 2)} | {r['nll']:.3f} | {r['nll_other_text']:.3f} | "
                     f"{r['nll_other_text'] - r['nll']:+.4f} |")
    (out / "table2_nll.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
