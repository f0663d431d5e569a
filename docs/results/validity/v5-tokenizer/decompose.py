"""What limits a tokenizer's reconstruction under evaluator v5? (issue 40, item 5)

Ground truth through a tokenizer and back loses 0.61 of v5's top-3 (0.39×), while 10 mm of noise on the
fingers loses only 0.10 (0.90×, ``docs/results/validity/v5``). A reconstruction errs in two separable ways:
where each WRIST goes (its global path: the AR features integrate the root, so errors accumulate), and the
HAND'S SHAPE about its wrist (the finger joints relative to the wrist). This scores, under the packaged
evaluator, hybrids that take one part from the reconstruction and the other from the ground truth:

- ``reconstruction``: the tokenizer's output as the suite scores it;
- ``reconstructed wrist path, true shape``: ground truth translated per hand and frame onto the
  reconstruction's wrist positions;
- ``true wrist path, reconstructed shape``: the reconstruction's wrist-relative joints placed on the ground
  truth's wrists;
- ``... and palm orientation, reconstructed articulation``: the same, each hand also turned onto the ground
  truth's palm orientation (``validity.scores.hybrids``, the suite's own split);
- for scale, ground truth with low-frequency noise (σ 4 frames) on the finger joints of the same mean
  wrist-relative error as the reconstruction; and the CURVE of top-3 ratio against that noise's size
  (wrist-relative finger error 5 … 40 mm), the yardstick's tolerance for shape error.

    python docs/results/validity/v5-tokenizer/decompose.py DATA OUT TOK [TOK ...]
    # writes OUT/decompose.json and OUT/decompose.png
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from handx_jax import standard
from handx_jax.dataset.format import Dataset
from handx_jax.generation import split_prompts
from handx_jax.validity import perturb as P
from handx_jax.validity.scores import (Scorer, finger_error_mm, hybrids, tokenizer_reconstruction,
                                       wrist_path_error_mm)


def main(data: str, out: str, toks: list[str]) -> None:
    ds = Dataset.open(data)
    clips, prompts, motion = split_prompts(ds, "test", None, 0)
    gt = np.stack(motion).astype(np.float32)
    assets = standard.ASSETS  # the packaged (current) standard evaluator
    ev = standard.load(assets)
    scorer = Scorer(ev, ds, clips, prompts, block=32, cache=standard.reference_cache_dir(assets))
    base = scorer.score(gt)["rprec_top3"]
    rows = []

    def row(tok, name, y):
        r = scorer.score(y)
        rows.append({"tokenizer": tok, "case": name, "finger_error_mm": finger_error_mm(gt, y),
                     "wrist_path_error_mm": wrist_path_error_mm(gt, y), "mean_shift_mm": P.mean_shift_mm(gt, y),
                     "top3": r["rprec_top3"], "ratio": r["rprec_top3"] / base, "fid": r["fid"]})
        print(json.dumps(rows[-1]), flush=True)

    unit = finger_error_mm(gt, P.apply("lowfreq", gt, 0.001, 0))  # low-frequency noise scales linearly
    for mm in (5, 10, 15, 20, 30, 40):
        row(None, f"low-frequency finger noise, {mm} mm finger error", P.apply("lowfreq", gt, mm / unit / 1000, 0))
    for tok in toks:
        rec = tokenizer_reconstruction(tok, gt)
        row(tok, "reconstruction", rec)
        parts = hybrids(gt, rec)
        row(tok, "reconstructed wrist path, true shape", parts["wrist_path"])
        row(tok, "true wrist path, reconstructed shape", parts["shape"])
        row(tok, "true wrist path and palm orientation, reconstructed articulation", parts["articulation"])
        e = finger_error_mm(gt, rec)
        row(tok, f"low-frequency finger noise of the same size ({e / unit:.1f} mm)", P.apply("lowfreq", gt, e / unit / 1000, 0))
    o = Path(out)
    o.mkdir(parents=True, exist_ok=True)
    (o / "decompose.json").write_text(json.dumps({"data": data, "test_clips": len(clips), "ground_truth_top3": base,
                                                  "rows": rows}, indent=1) + "\n")
    plot(rows, o / "decompose.png")


def plot(rows, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7.5, 4.6))
    curve = [r for r in rows if r["tokenizer"] is None]
    ax.plot([r["finger_error_mm"] for r in curve], [r["ratio"] for r in curve], "o-", c="grey",
            label="ground truth + low-frequency finger noise")
    marks = {"reconstruction": ("s", "whole reconstruction"), "true wrist path, reconstructed shape": ("^", "its shape alone"),
             "true wrist path and palm orientation, reconstructed articulation": ("v", "its articulation alone")}
    toks = sorted({r["tokenizer"] for r in rows if r["tokenizer"] is not None})
    for k, tok in enumerate(toks):
        for r in rows:
            if r["tokenizer"] == tok and r["case"] in marks:
                m, what = marks[r["case"]]
                ax.scatter(r["finger_error_mm"], r["ratio"], marker=m, s=55, color=f"C{k}",
                           label=f"{Path(tok).name.split('-')[0] + '-' + Path(tok).name.split('-')[1] if '-' in Path(tok).name else Path(tok).name}: {what}")
    ax.axhline(0.8, ls="--", c="k", lw=0.8)
    ax.text(41, 0.81, "target 0.8×", fontsize=8)
    ax.set_xlabel("wrist-relative finger error (mm)")
    ax.set_ylabel("top-3 ratio to ground truth (evaluator v5)")
    ax.set_xlim(0, 46)
    ax.set_ylim(0, 1.05)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--plot":  # redraw OUT/decompose.png from OUT/decompose.json
        plot(json.loads((Path(sys.argv[2]) / "decompose.json").read_text())["rows"], Path(sys.argv[2]) / "decompose.png")
        sys.exit(0)
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2], sys.argv[3:])
