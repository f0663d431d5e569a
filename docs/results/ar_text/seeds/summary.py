"""Top-3 over training seeds, the level-0 LM against the untrained LM (issue 30 item 4): seed 42 from
``../rows.json``, seeds 1 and 2 from this folder's eval JSONs; mean, s.d. and the 95% Student-t interval over
seeds, and Welch's t-test between the two rows. Writes ``summary.json`` beside this file.

    .venv/bin/python docs/results/ar_text/seeds/summary.py
"""
import json
from pathlib import Path

import numpy as np
from scipy import stats

HERE = Path(__file__).parent
rows = {r["row"]: r for r in json.loads((HERE.parent / "rows.json").read_text())}


def top3(kind: str, row: str) -> dict:
    vals = {42: rows[row]["rprec_top3"]}
    vals |= {s: json.loads((HERE / f"{kind}_seed{s}_eval.json").read_text())["rprec_top3"] for s in (1, 2)}
    x = np.array(list(vals.values()))
    half = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x))
    return {"per_seed": vals, "mean": x.mean(), "sd": x.std(ddof=1), "ci95": [x.mean() - half, x.mean() + half]}


out = {"level0": top3("level0", "level0"), "untrained": top3("untrained", "untrained")}
w = stats.ttest_ind(list(out["level0"]["per_seed"].values()), list(out["untrained"]["per_seed"].values()),
                    equal_var=False)
out["welch"] = {"t": w.statistic, "p": w.pvalue}
(HERE / "summary.json").write_text(json.dumps(out, indent=1, default=float) + "\n")
print(json.dumps(out, indent=1, default=float))
