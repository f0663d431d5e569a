"""The table of run.sh: per meaning-changing kind, each evaluator's top-3 ratio beside its caption reader's
(issue 55's target: ratio <= reader + 0.15), with ground-truth top-3 and chance.

    python table.py FOLDER        (FOLDER holds base/, hard/ and v7/, each a validity.json)
"""

import json
import sys
from pathlib import Path

WHICH = ("swap_hands", "swap_fingers", "still_fingers")
P_LABELS = {"swap_hands": "hands swapped", "swap_fingers": "fingers swapped", "still_fingers": "one hand still"}
RUNS = (("base", "small, no hard negatives"), ("hard", "small, hard negatives swap_hands + swap_fingers"),
        ("base-seed1", "small, no hard negatives, seed 1"), ("hard-seed1", "small, hard negatives, seed 1"),
        ("v7", "packaged v7 (corpus v4; out of its corpus)"))


def main(folder: Path) -> str:
    global RUNS
    RUNS = tuple((k, name) for k, name in RUNS if (folder / k / "validity.json").exists())
    reps = {k: json.loads((folder / k / "validity.json").read_text()) for k, _ in RUNS}
    first = reps["base"]
    block, n = first["block"], first["test_clips"]
    lines = [f"{n} test clips of the 2,000-clip corpus-v5 prefix, block {block}: chance top-3 "
             f"{min(3, block) / block:.3f}. Per evaluator: ground-truth top-3, then per kind the top-3 ratio to it, "
             f"the caption reader's ratio (through that evaluator's text side) and the margin ratio - reader "
             f"(target <= +0.15).", "",
             "| evaluator | GT top-3 | " + " | ".join(c["label"] for c in first["cases"]) + " |",
             "|---|---:|" + "---:|" * len(first["cases"])]
    for key, name in RUNS:
        r = reps[key]
        cells = []
        for c in r["cases"]:
            m = c["top3_ratio"] - c["caption_reader_ratio"]
            cells.append(f"{c['top3_ratio']:.2f} (reader {c['caption_reader_ratio']:.2f}; {m:+.2f}"
                         f"{'' if m <= 0.15 else ' **miss**'})")
        lines.append(f"| {name} | {r['ground_truth']['rprec_top3']:.3f} | " + " | ".join(cells) + " |")
    lines += ["", "Which test (the suite's two-way choice, chance 0.5; on the clips whose edit reads differently at "
              "level 0): the clip nearer its own caption than the edit's caption / the edited clip nearer the edit's "
              "caption than the clip's.", "",
              "| evaluator | " + " | ".join(P_LABELS[k] for k in WHICH) + " |", "|---|" + "---:|" * len(WHICH)]
    for key, name in RUNS:
        w = reps[key].get("which", {})
        lines.append(f"| {name} | " + " | ".join(
            f"{w[k]['forward_picks_own']:.2f} / {w[k]['reversed_picks_reversed']:.2f} ({w[k]['clips']} clips)"
            if w.get(k, {}).get("clips") else "-" for k in WHICH) + " |")
    o = {key: reps[key].get("order", {}) for key, _ in RUNS}
    lines += ["", "Order test (the same choice for time reversal): " + "; ".join(
        f"{name} {o[key]['forward_picks_own']:.2f} / {o[key]['reversed_picks_reversed']:.2f}"
        for key, name in RUNS if o[key].get("clips")) + "."]
    lines += ["", "Level-0 captions unchanged by each kind (the annotation, the same for every evaluator): "
              + ", ".join(f"{c['label']} {c['captions_unchanged'][0]:.3f}" for c in first["cases"]) + "."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.stdout.write(main(Path(sys.argv[1])))
