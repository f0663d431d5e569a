"""Held-out token NLL beside the scores: every LM run of an AR sweep and any untrained runs → ``lm_rows.json``.

    .venv/bin/python docs/results/ar_cpu_study/collect.py SWEEP [--untrained RUN ...] --out docs/results/ar_cpu_study

For each run: its axes (layers, dim, codebook), steps, the held-out token NLL (nats per motion slot, the LM's
evaluation hook, ``families/ar.make_evaluate``) at step 0 (the initial weights) and at its last evaluation,
the text gap (the same NLL with another held-out clip's text, minus the own text's), the tokenizer's val
MPJPE (its last evaluation), and top-1/top-3 R-Precision with their ± from ``eval.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _jsonl(p: Path) -> list[dict]:
    return [json.loads(x) for x in p.read_text().splitlines() if x.strip()]


def row(run: Path) -> dict:
    cfg = json.loads((run / "config.json").read_text())
    evals = [r for r in _jsonl(run / "metrics.jsonl") if "eval/nll" in r]
    sc = json.loads((run / "eval.json").read_text()) if (run / "eval.json").exists() else {}
    tok = Path(cfg["tokenizer"]["tokenizer_path"])
    tok_ev = [r for r in _jsonl(tok / "metrics.jsonl") if "eval/mpjpe_mm" in r]
    return {"run": run.name, "layers": cfg["model"]["layers"], "dim": cfg["model"]["dim"], "codebook": cfg["codebook"],
            "nb_code": cfg["nb_code"], "params": cfg["params"], "steps": evals[-1]["step"],
            "batch_size": cfg["train"]["batch_size"], "lr": cfg["train"]["optim"]["lr"],
            "nll_step0": evals[0]["eval/nll"], "nll": evals[-1]["eval/nll"], "acc": evals[-1]["eval/acc"],
            # held-out NLL with another held-out clip's text, and its excess over the own text's (0: text unused)
            "nll_other_text": evals[-1].get("eval/nll_other_text"), "text_gap": evals[-1].get("eval/text_gap"),
            "tokenizer_mpjpe_mm": tok_ev[-1]["eval/mpjpe_mm"] if tok_ev else None,
            "tokenizer_perplexity": tok_ev[-1].get("eval/perplexity") if tok_ev else None,
            **{k: sc.get(k) for k in ("rprec_top1", "rprec_top1_ci", "rprec_top3", "rprec_top3_ci", "fid", "fid_ci",
                                      "diversity", "mm_dist")}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("sweep", type=Path)
    ap.add_argument("--untrained", nargs="*", type=Path, default=[])
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    runs = sorted((args.sweep / "runs").iterdir(), key=lambda r: r.name)
    rows = {"trained": [row(r) for r in runs if (r / "eval.json").exists()],  # scored runs only
            "untrained": [row(r) for r in args.untrained]}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "lm_rows.json").write_text(json.dumps(rows, indent=2) + "\n")
    for kind, rs in rows.items():
        for r in rs:
            gap = "" if r["text_gap"] is None else f" (text gap {r['text_gap']:+.3f})"
            print(f"{kind:9} L{r['layers']} d{r['dim']} K{r['codebook']:<5} steps {r['steps']:>5}  "
                  f"NLL {r['nll_step0']:.3f} -> {r['nll']:.3f}{gap}  top-3 {r['rprec_top3']:.3f} ± "
                  f"{r['rprec_top3_ci']:.3f}  top-1 {r['rprec_top1']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
