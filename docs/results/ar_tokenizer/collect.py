"""Rate–distortion of the FSQ tokenizer: the last evaluation row of each run folder → a JSON table and a plot.

    .venv/bin/python docs/results/ar_tokenizer/collect.py RUN_K256 RUN_K512 ... --out docs/results/ar_tokenizer
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

KEYS = ("mpjpe_mm", "fingers_mm", "wrist_orient_mm", "root_mm", "global_mpjpe_mm", "mean_pose_mpjpe_mm",
        "mpjpe_vs_mean_pose", "usage", "perplexity", "codes_used")


def row(run: Path) -> dict:
    cfg = json.loads((run / "config.json").read_text())
    ev = [json.loads(l) for l in (run / "metrics.jsonl").read_text().splitlines() if '"eval/mpjpe_mm"' in l][-1]
    return {"codebook": cfg["codebook"], "nb_code": cfg["nb_code"], "levels": cfg["levels"], "width": cfg["model"]["width"],
            "loss": cfg.get("loss", "reference"), "steps": ev["step"], "batch_size": cfg["train"]["batch_size"],
            "val_tokens": ev["step"] and _val_tokens(run), **{k: ev[f"eval/{k}"] for k in KEYS}}


def _val_tokens(run: Path) -> int:
    """Tokens the evaluation encodes: min(eval_clips, val clips) × 30."""
    cfg = json.loads((run / "config.json").read_text())
    splits = json.loads((Path(cfg["data"]["path"]) / "splits.json").read_text())
    return min(cfg["data"]["eval_clips"], len(splits["val"]) or len(splits["test"])) * 30


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    rows = sorted((row(r) for r in args.runs), key=lambda r: r["nb_code"])
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "rate_distortion.json").write_text(json.dumps({"rows": rows}, indent=2) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = [r["nb_code"] for r in rows]
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.4))
    for k, lab in (("mpjpe_mm", "total"), ("fingers_mm", "fingers only"), ("wrist_orient_mm", "wrist orientation only")):
        ax[0].plot(x, [r[k] for r in rows], "o-", label=lab)
    ax[0].axhline(rows[0]["mean_pose_mpjpe_mm"], color="grey", ls="--", label="mean pose")
    ax[0].set(ylabel="val MPJPE, wrist-relative (mm)", xscale="log", xlabel="real codebook size")
    ax[0].legend(fontsize=7)
    ax[1].plot(x, [r["usage"] for r in rows], "o-", label="usage")
    if "val_tokens" in rows[0]:  # the most a val set of that many tokens can show
        ax[1].plot(x, [min(1.0, r["val_tokens"] / r["nb_code"]) for r in rows], ":", color="grey",
                   label="val tokens / codebook")
        ax[1].legend(fontsize=7)
    ax[1].set(ylabel="codebook usage", xscale="log", xlabel="real codebook size", ylim=(0, 1))
    ax[2].plot(x, [r["perplexity"] for r in rows], "o-", label="perplexity")
    ax[2].plot(x, x, ":", color="grey", label="codebook size")
    ax[2].set(ylabel="code perplexity", xscale="log", yscale="log", xlabel="real codebook size")
    ax[2].legend(fontsize=7)
    for a in ax:
        a.set_xticks(x, [str(v) for v in x], fontsize=7)
        a.minorticks_off()
    fig.tight_layout()
    fig.savefig(args.out / "rate_distortion.png", dpi=120)
    for r in rows:
        print(json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
