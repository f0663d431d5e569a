"""The comparison tables of README.md from `handx eval prediction` result files, any families and baselines.

    python docs/results/prediction/prefix4000/compare.py LABEL=FILE.json [LABEL=FILE.json ...]

Prints three markdown tables: MPJPE-RA (mean of the K samples) by horizon with the paired difference to
holding the last frame; best-of-K and the error of the samples' mean pose; the observed frames, APD and the
completed clips' FID and top-3. Every value is the file's own (value ± 95% half-width); nothing is recomputed.
"""

import json
import sys


def cell(row, key, digits=1):
    if key not in row:
        return "–"
    return f"{row[key]:.{digits}f} ± {row[key + '_ci']:.{digits}f}"


def main(argv):
    runs = []
    for item in argv:
        label, _, path = item.rpartition("=")  # a label may hold "="; a path here does not
        if not label or not path:
            raise SystemExit(f"compare.py: give LABEL=FILE.json, got {item!r}")
        with open(path) as f:
            runs.append((label, json.load(f)))
    bins = [h["frames"] for h in runs[0][1]["horizons"]]
    if any([h["frames"] for h in r["horizons"]] != bins for _, r in runs):
        raise SystemExit("compare.py: the files score different horizons")
    first = runs[0][1]["first"]["frames"]
    print(f"| predictor | frame {first} | " + " | ".join(bins) + f" | all {runs[0][1]['predicted']['frames']} "
          "| all − held (paired) |")
    print("|---" * (4 + len(bins)) + "|")
    for label, r in runs:
        print(f"| {label} | {cell(r['first'], 'mpjpe_ra_both')} | "
              + " | ".join(cell(h, "mpjpe_ra_both") for h in r["horizons"])
              + f" | {cell(r['predicted'], 'mpjpe_ra_both')} | {cell(r['predicted'], 'mpjpe_ra_vs_last_frame')} |")
    print()
    print("| predictor | best-of-K: " + " | ".join(bins) + " | best-of-K all | best − held (paired) "
          "| RA of the samples' mean | MPJPE-PA all | MPJPE (clip frame) all |")
    print("|---" * (6 + len(bins)) + "|")
    for label, r in runs:
        p = r["predicted"]
        print(f"| {label} | " + " | ".join(cell(h, "mpjpe_ra_best_of_k") for h in r["horizons"])
              + f" | {cell(p, 'mpjpe_ra_best_of_k')} | {cell(p, 'mpjpe_ra_best_of_k_vs_last_frame')} "
              f"| {cell(p, 'mpjpe_ra_sample_mean')} | {cell(p, 'mpjpe_pa_both')} | {cell(p, 'mpjpe_both')} |")
    print()
    print("| predictor | observed: largest joint error (mm) | APD all (L / R) | FID (completed) | top-1 | top-3 |")
    print("|---|---|---|---|---|---|")
    for label, r in runs:
        p, c = r["predicted"], r.get("completed", {})
        apd = f"{cell(p, 'apd_both')} ({p['apd_left']:.1f} / {p['apd_right']:.1f})" if "apd_both" in p else "–"
        print(f"| {label} | {r['observed']['max_joint_error_mm']:.2g} | {apd} | {cell(c, 'fid', 2)} "
              f"| {cell(c, 'rprec_top1', 3)} | {cell(c, 'rprec_top3', 3)} |")


if __name__ == "__main__":
    main(sys.argv[1:])
