"""The motion-prediction benchmark (issue 33 item 3): ``handx eval prediction``.

G-HTT (§4.1, "Prediction") observes one 16-frame segment of an action and predicts the rest, K = 20
samples per observation, and scores them by MPJPE-RA / MPJPE-PA and APD (its Tables 2–4). Here each
clip of a dataset split is the action: its first N frames are observed, a trained run (either family,
``run.generate(task="prediction")``) continues it to the clip's length with the clip's own captions as
text, K samples per clip, and the samples are scored against the clip by horizon:

- **Horizon bins** (:func:`horizon_bins`): the frames after the observation in consecutive bins of
  G-HTT's segment length, 16 frames (0.53 s at 30 fps), the last one cut at the clip's end; a last bin
  shorter than half a segment is merged into the one before it. After N = 16 of 60 frames that gives
  frames 17–32, 33–48 and 49–60 (1-based, inclusive); after N = 20: 21–36, 37–52, 53–60; after N = 40:
  41–60 (41–56 and a 4-frame rest merged). ``--horizons 17-32,33-60`` names other bins.
- **Rows**: the observed frames (the check that they are kept: every family returns them as given),
  the first predicted frame alone (a continuation that jumps at the boundary shows there), each bin, and
  all predicted frames together.
- **Metrics per row**, in mm: MPJPE-RA per hand and both (G-HTT's "root aligned": each hand relative to
  its wrist), MPJPE-PA (each hand and frame after its own similarity Procrustes), MPJPE in the clip's
  frame (where the hands are, which RA and PA leave out), each the mean over the K samples, and, with
  K > 1, APD over the K samples (G-HTT's diversity; 0 for K identical samples) and best-of-K MPJPE-RA
  (the sample closest to the clip, per clip: the usual score of stochastic prediction); the MPJPE-RA
  of the K samples' mean pose; and, paired on the same clips, the mean and best-of-K MPJPE-RA minus
  holding the last frame (negative: better than holding still; the interval is the difference's).
- **Completed clips** (``completed``, :func:`evaluator_scores`): the observed frames plus the prediction
  scored as generated clips by an evaluator (the standard one by default), FID and R-Precision top-1/3
  against the clips and their captions, each of the K samples a generation group.
- **Intervals**: 95%, a bootstrap over clips (``metrics.prompt_mean_ci``, the project's
  "bootstrap_prompts" interval) of each clip's value (for MPJPE its mean over the K samples). The clips
  are the benchmark's sample: redrawing the K samples of the same clips moves the numbers far less (not
  at all for a deterministic predictor such as the baseline or greedy decoding), so the interval over
  sample groups that ``handx eval run`` gives for G > 1 would hide the clip-to-clip spread.

``--baseline last-frame`` scores the trivial predictor that holds the last observed frame: the floor a
model must beat to have learned any motion; ``velocity`` continues each joint at its last observed step;
``ground-truth`` is the clip itself, the reference for the completed clips' FID and top-3.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from handx_jax.infra.errors import DataError
from handx_jax.metrics import MetricConfig, apd_frames_mm, joint_error_frames_mm, mpjpe_pa_frames_mm, prompt_mean_ci

HORIZON = 16  # G-HTT's segment length in frames: its observation and its prediction steps (§4.1)
RESULT_FILE = "eval_prediction.json"
CI = ("95%: a bootstrap over clips (metrics.prompt_mean_ci) of each clip's value; for MPJPE its mean over the K "
      "samples")  # the result's _meta.ci
HANDS = ("left", "right")


def horizon_bins(observed: int, frames: int = 60, width: int = HORIZON) -> tuple[tuple[int, int], ...]:
    """The predicted frames in bins of ``width``, as 0-based half-open [start, end): consecutive from the
    first unobserved frame, the last cut at ``frames``, and merged into the one before when it is shorter
    than half a bin (a 2-frame bin would be all noise)."""
    if not 0 < observed < frames:
        raise ValueError(f"--observed-frames must be in (0, {frames}), got {observed}")
    edges = [*range(observed, frames, width), frames]
    bins = list(zip(edges[:-1], edges[1:]))
    if len(bins) > 1 and bins[-1][1] - bins[-1][0] < width / 2:
        bins[-2:] = [(bins[-2][0], frames)]
    return tuple(bins)


def parse_horizons(text: str, observed: int, frames: int = 60) -> tuple[tuple[int, int], ...]:
    """``--horizons``: comma-separated 1-based inclusive frame ranges ("17-32,33-48,49-60", or "60" for
    one frame), each after the observation and within the clip; returned as :func:`horizon_bins` does."""
    bins = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        m = re.fullmatch(r"(\d+)(?:\s*-\s*(\d+))?", item)
        if m is None:
            raise ValueError(f"--horizons: {item!r} is not a frame range like 17-32")
        a, b = int(m[1]), int(m[2] or m[1])
        if not observed < a <= b <= frames:
            raise ValueError(f"--horizons: {item} must lie in frames {observed + 1}-{frames} (after the "
                             f"{observed} observed frames, 1-based) and start at or before its end")
        bins.append((a - 1, b))
    if not bins:
        raise ValueError("--horizons names no frame range")
    return tuple(bins)


def label(start: int, end: int) -> str:
    """A 0-based [start, end) range as the 1-based inclusive frames a reader counts ("17-32")."""
    return f"{start + 1}-{end}"


def last_frame(sources_NxTx2x21x3: np.ndarray, observed: int) -> np.ndarray:
    """The hold-the-last-observed-frame baseline: the observed frames, then frame ``observed`` − 1 repeated."""
    x = np.array(sources_NxTx2x21x3, np.float32, copy=True)
    x[:, observed:] = x[:, observed - 1:observed]
    return x


def velocity(sources_NxTx2x21x3: np.ndarray, observed: int) -> np.ndarray:
    """The constant-velocity baseline: every joint continues along its last observed step (frame
    ``observed`` − 1 minus ``observed`` − 2) at that speed; with one observed frame it holds it."""
    x = np.array(sources_NxTx2x21x3, np.float32, copy=True)
    if observed < 2:
        return last_frame(x, observed)
    step = x[:, observed - 1] - x[:, observed - 2]
    k = np.arange(1, x.shape[1] - observed + 1, dtype=np.float32)[None, :, None, None, None]
    x[:, observed:] = x[:, observed - 1:observed] + k * step[:, None]
    return x


def ground_truth(sources_NxTx2x21x3: np.ndarray, observed: int) -> np.ndarray:
    """The clips themselves (an oracle, not a predictor): the floor of every error and the standard
    evaluator's FID and top-3 of real motion on the same clips, the reference for the completed clips'."""
    return np.array(sources_NxTx2x21x3, np.float32, copy=True)


# ``--baseline NAME``: trivial predictors (sources, observed) -> (N, T, 2, 21, 3), scored like a run.
BASELINES = {"last-frame": last_frame, "velocity": velocity, "ground-truth": ground_truth}


def run_data(run_dir: str | Path) -> str:
    """The dataset a run was trained on (``config.json["data"]["path"]``), for the default ``--data``."""
    from handx_jax.infra.readers import read_json

    path = (read_json(Path(run_dir) / "config.json").get("data") or {}).get("path")
    if not path:
        raise DataError("config.json names no training dataset (data.path); give --data", path=run_dir)
    return str(path)


def _row(err: dict, apd_NxTx2: np.ndarray | None, start: int, end: int, cfg: MetricConfig, held_NxTx2: np.ndarray,
         of_mean_NxTx2: np.ndarray) -> dict:
    """One row's metrics over frames [start, end): name → value and name_ci → 95% half-width."""
    out = {}

    def put(name, v):
        out[name], out[f"{name}_ci"] = v

    for name, e_KxNxTx2 in err.items():
        e_Nx2 = e_KxNxTx2[:, :, start:end].mean((0, 2))  # each clip's mean over its samples and the frames
        for h, side in enumerate(HANDS):
            put(f"{name}_{side}", prompt_mean_ci(e_Nx2[:, h], cfg))
        put(f"{name}_both", prompt_mean_ci(e_Nx2.mean(-1), cfg))
    ra_N = err["mpjpe_ra"][:, :, start:end].mean((0, 2, 3))
    held_N = held_NxTx2[:, start:end].mean((1, 2))
    # Paired with the hold-the-last-frame baseline on the same clips: the clip-to-clip spread, which both
    # share, leaves the interval, so "beats holding still" is read off one number and its sign.
    put("mpjpe_ra_vs_last_frame", prompt_mean_ci(ra_N - held_N, cfg))
    # The error of the K samples' mean pose (each hand relative to its wrist): what averaging a model's
    # samples gives, below the mean error of the samples when they scatter around the clip.
    put("mpjpe_ra_sample_mean", prompt_mean_ci(of_mean_NxTx2[:, start:end].mean((1, 2)), cfg))
    if apd_NxTx2 is not None:  # K > 1
        best_N = err["mpjpe_ra"][:, :, start:end].mean((2, 3)).min(0)
        put("mpjpe_ra_best_of_k", prompt_mean_ci(best_N, cfg))
        put("mpjpe_ra_best_of_k_vs_last_frame", prompt_mean_ci(best_N - held_N, cfg))
        apd_Nx2 = apd_NxTx2[:, start:end].mean(1)  # the mean of per-frame APDs is the bin's APD
        for h, side in enumerate(HANDS):
            put(f"apd_{side}", prompt_mean_ci(apd_Nx2[:, h], cfg))
        put("apd_both", prompt_mean_ci(apd_Nx2.mean(-1), cfg))
    return out


def score(pred_KxNxTx2x21x3, gt_NxTx2x21x3, observed: int, bins, cfg: MetricConfig = MetricConfig()) -> dict:
    """The benchmark's numbers for K predictions of N clips whose first ``observed`` frames were given:
    ``observed`` (with ``max_joint_error_mm``, the largest joint distance over every sample's observed
    frames), ``horizons`` (one row per bin, with its ``frames`` label) and ``predicted`` (all frames
    after the observation)."""
    pred = np.asarray(pred_KxNxTx2x21x3, np.float32)
    gt = np.asarray(gt_NxTx2x21x3, np.float32)
    K, N, T = pred.shape[:3]
    if gt.shape != pred.shape[1:]:
        raise ValueError(f"predictions {pred.shape[1:]} and ground truth {gt.shape} differ in shape")
    err = {"mpjpe_ra": np.stack([np.asarray(joint_error_frames_mm(p, gt, root_aligned=True)) for p in pred]),
           "mpjpe_pa": np.stack([np.asarray(mpjpe_pa_frames_mm(p, gt)) for p in pred]),
           "mpjpe": np.stack([np.asarray(joint_error_frames_mm(p, gt, root_aligned=False)) for p in pred])}
    apd = apd_frames_mm(pred) if K > 1 else None
    held = np.asarray(joint_error_frames_mm(last_frame(gt, observed), gt, root_aligned=True))
    # The K samples' mean pose (joints and wrists averaged): its root-aligned error is the mean prediction's.
    of_mean = np.asarray(joint_error_frames_mm(pred.mean(0), gt, root_aligned=True))
    row = lambda a, b: {"frames": label(a, b), **_row(err, apd, a, b, cfg, held, of_mean)}  # noqa: E731
    obs = row(0, observed)
    obs["max_joint_error_mm"] = float(1000.0 * np.linalg.norm(pred[:, :, :observed] - gt[:, :observed], axis=-1).max())
    # The first predicted frame alone: a continuation that jumps at the boundary shows here, where
    # holding still is a few mm off.
    return {"observed": obs, "first": row(observed, observed + 1), "horizons": [row(a, b) for a, b in bins],
            "predicted": row(observed, T)}


# The standard evaluator's numbers of the completed clips (``completed`` in the result): FID and R-Precision
# (Table 2's), with MM-Dist beside them.
COMPLETED = ("fid", "rprec_top1", "rprec_top3", "mm_dist")


def evaluator_scores(ev, cache, pred_NxKxTx2x21x3: np.ndarray, prompts, clip_ids, ds, split: str,
                     cfg: MetricConfig) -> dict:
    """FID and R-Precision of the completed clips (the observed frames and the prediction, 60 frames)
    against the split's clips and captions, as ``handx eval run`` scores generated clips: each of the K
    samples is a generation group (the intervals are its: over the K groups, or the replications for
    K = 1). Returns the metrics and the evaluator's identity and settings under ``_meta``."""
    from handx_jax.evaluation import evaluate_generated
    from handx_jax.generation import generated_entries

    N, K = pred_NxKxTx2x21x3.shape[:2]
    entries = generated_entries(pred_NxKxTx2x21x3.reshape(N * K, *pred_NxKxTx2x21x3.shape[2:]),
                                [[p] for p in prompts for _ in range(K)],
                                source_clips=[i for i in clip_ids for _ in range(K)],
                                groups=[g for _ in clip_ids for g in range(K)])
    res = evaluate_generated(ev, entries, ds, cfg, split=split, cache=cache)
    flat = res.flat()
    out = {k: flat[k] for name in COMPLETED for k in (name, f"{name}_ci")}
    keep = ("evaluator_id", "evaluator_name", "eval_level", "rprec_block", "rprec_chance", "replications", "groups",
            "prompts", "warnings")
    out["_meta"] = {k: res.meta[k] for k in keep if k in res.meta} | {
        "ci_method": {k: res.meta.get("ci_method", {}).get(k) for k in COMPLETED}}
    return out


def format_completed(completed: dict) -> str:
    """The completed clips' evaluator line."""
    m = completed["_meta"]
    cells = ", ".join(f"{k} {completed[k]:.3f} ± {completed[k + '_ci']:.3f}" for k in COMPLETED)
    return f"completed clips (evaluator {m.get('evaluator_id')}, R-Precision block {m.get('rprec_block')}): {cells}"


# ------------------------------------------------------------------------------------------------
# The printed table

COLUMNS = (("MPJPE-RA L", "mpjpe_ra_left"), ("MPJPE-RA R", "mpjpe_ra_right"), ("MPJPE-RA", "mpjpe_ra_both"),
           ("RA - held", "mpjpe_ra_vs_last_frame"), ("RA of mean", "mpjpe_ra_sample_mean"),
           ("MPJPE-PA", "mpjpe_pa_both"), ("MPJPE", "mpjpe_both"), ("best-of-K RA", "mpjpe_ra_best_of_k"),
           ("best - held", "mpjpe_ra_best_of_k_vs_last_frame"), ("APD", "apd_both"))


def format_table(result: dict) -> str:
    """The rows as a plain-text table, mm, value ± 95% half-width ("–" where K = 1 has no APD)."""
    rows = [("observed " + result["observed"]["frames"], result["observed"]),
            ("first " + result["first"]["frames"], result["first"]),
            *((r["frames"], r) for r in result["horizons"]),
            ("all " + result["predicted"]["frames"], result["predicted"])]
    cell = lambda r, k: f"{r[k]:.1f} ± {r[k + '_ci']:.1f}" if k in r else "–"  # noqa: E731
    table = [("frames", *(c for c, _ in COLUMNS))] + [(name, *(cell(r, k) for _, k in COLUMNS)) for name, r in rows]
    w = [max(len(line[i]) for line in table) for i in range(len(table[0]))]
    return "\n".join("  ".join(s.ljust(w[i]) if i == 0 else s.rjust(w[i]) for i, s in enumerate(line))
                     for line in table)
