"""The evaluation's metric rows: every embedding and motion metric over G generation groups, as (point value,
95% half-width), with the point averaged over re-blockings and re-drawn pairs and the interval over groups
or a prompt bootstrap (:mod:`handx_jax.metrics.intervals` says which, and why)."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.metrics.chunking import MOTION_CHUNK
from handx_jax.metrics.config import MetricConfig
from handx_jax.metrics.contact import NamedContacts, contact_feasibility_counts
from handx_jax.metrics.embedding import (diversity_indices, expected_hit, fid, fid_resampled, pair_distances,
                                         replicated_ranks, resampled_pair_mean)
from handx_jax.metrics.hand_papers import (apd_mm, interhand_penetration, mpjpe_pa_mm, mpjpe_ra_mm,
                                           penetration_stats)
from handx_jax.metrics.intervals import (CI_BOOTSTRAP, CI_GROUPS, bootstrap_half_width, bootstrap_indices, ci_method,
                                         mean_ci, per_prompt_ci, resample_counts)
from handx_jax.metrics.motion import acceleration_jitter, contact_labels, mpjpe_mm, palm_barycentric


def replicate_embedding_metrics(text_NxD, gen_GxNxD, gt_NxD, cfg: MetricConfig = MetricConfig(),
                                timings: dict | None = None) -> dict:
    """R-Precision, MM-Dist, FID, Diversity (and MultiModality if G > 1) as (point value, 95% half-width).

    ``gen_GxNxD`` holds G generation groups for the same N prompts; pass the GT embeddings as the
    single group to get the "Ground Truth" row. Point values average the ``replications`` re-blockings
    (R-Precision, MM-Dist) and re-drawn pairs (Diversity, MultiModality) over all groups; intervals
    are over groups or a prompt bootstrap, as :func:`ci_method` says (``intervals``' docstring). ``timings``, if
    given, receives the seconds of each part (rprec_mm_dist, fid, diversity, multimodality).
    """
    last = time.perf_counter()

    def lap(name):  # seconds since the previous lap, into ``timings``
        nonlocal last
        now = time.perf_counter()
        if timings is not None:
            timings[name] = timings.get(name, 0.0) + now - last
        last = now

    text = jnp.asarray(text_NxD, jnp.float32)
    gen = jnp.asarray(gen_GxNxD, jnp.float32)
    gt = np.asarray(gt_NxD, np.float64)
    G, N, _ = gen.shape
    R = cfg.replications
    if R < 1:
        raise ValueError(f"replications must be >= 1, got {R}")
    rng = np.random.default_rng([cfg.seed, 0x4E])
    perms = np.stack([rng.permutation(N) for _ in range(R)])  # (R, N)
    boot = bootstrap_indices(N, cfg)
    counts = resample_counts(boot, N)

    def summarise(name, per_group_G, per_prompt_N=None, resampled_B=None):
        """Point value = mean over groups; the ± from the groups or the prompt bootstrap."""
        point = float(np.mean(per_group_G))
        if ci_method(name, G) == CI_GROUPS:
            return point, mean_ci(per_group_G)[1]
        if resampled_B is not None:
            return point, bootstrap_half_width(resampled_B)
        return point, per_prompt_ci(per_prompt_N, counts)

    (closer_RxGxN, tied_RxGxN), dist_RxGxN, valid_RxGxN = jax.tree.map(
        np.asarray, replicated_ranks(text, gen, jnp.asarray(perms), block=cfg.rprec_block))
    n_valid_GxN = valid_RxGxN.sum(0).astype(np.float64)
    out = {}
    for k in range(1, cfg.top_k + 1):
        hit_RxGxN = np.asarray(expected_hit(closer_RxGxN, tied_RxGxN, k), np.float64) * valid_RxGxN
        per_group = hit_RxGxN.sum((0, 2)) / valid_RxGxN.sum((0, 2))
        per_prompt = np.where(n_valid_GxN[0] > 0, hit_RxGxN[:, 0].sum(0) / np.maximum(n_valid_GxN[0], 1), np.nan)
        out[f"rprec_top{k}"] = summarise(f"rprec_top{k}", per_group, per_prompt)
    mm_group = (dist_RxGxN * valid_RxGxN).sum((0, 2)) / valid_RxGxN.sum((0, 2))
    mm_prompt = np.where(n_valid_GxN[0] > 0, (dist_RxGxN[:, 0] * valid_RxGxN[:, 0]).sum(0)
                         / np.maximum(n_valid_GxN[0], 1), np.nan)
    out["mm_dist"] = summarise("mm_dist", mm_group, mm_prompt)
    lap("rprec_mm_dist")

    fids_G = [fid(gt, np.asarray(gen[g])) for g in range(G)]
    fid_boot = None
    if ci_method("fid", G) == CI_BOOTSTRAP:
        fid_boot = fid_resampled(gt, np.asarray(gen[0]), counts)
    out["fid"] = summarise("fid", fids_G, resampled_B=fid_boot)
    lap("fid")

    pairs = [diversity_indices(N, cfg.diversity_pairs, cfg.seed + r) for r in range(R)]
    i1, i2 = (jnp.asarray(np.concatenate(p)) for p in zip(*pairs))  # the R pair sets, (R·k,) each
    div_G = [float(jnp.mean(pair_distances(gen[g], i1, i2))) for g in range(G)]
    div_boot = None
    if ci_method("diversity", G) == CI_BOOTSTRAP:
        div_boot = resampled_pair_mean(gen[0], i1, i2, boot)
    out["diversity"] = summarise("diversity", div_G, resampled_B=div_boot)
    lap("diversity")

    if G > 1:
        m = min(G - 1, cfg.multimodality_pairs)
        per_prompt = np.zeros(N)
        for r in range(R):
            rr = np.random.default_rng([cfg.seed, 0x33, r])
            g1, g2 = rr.choice(G, m, replace=False), rr.choice(G, m, replace=False)
            per_prompt += np.asarray(jnp.linalg.norm(gen[g1] - gen[g2], axis=-1)).mean(0) / R  # (N,)
        out["multimodality"] = (float(per_prompt.mean()), per_prompt_ci(per_prompt, counts))
        lap("multimodality")
    return out


def replicate_motion_metrics(gen_GxNxTx2x21x3, gt_NxTx2x21x3, cfg: MetricConfig = MetricConfig(),
                             named: NamedContacts | None = None) -> dict:
    """MPJPE (also G-HTT's -RA and -PA per hand), acceleration, jitter, contact P/R/F1, inter-hand
    penetration and, given the contacts the prompts' records name (``named``), contact feasibility, as
    (point value, 95% half-width): the point is the mean over generation groups; the ± is over groups
    (G > 1) or a bootstrap over clips (G = 1). With G > 1, APD per hand over the first
    ``cfg.apd_samples`` groups (all for 0), its ± a bootstrap over prompts (a between-group quantity)."""
    gen = np.asarray(gen_GxNxTx2x21x3, np.float32)
    G, N = gen.shape[:2]
    # The per-clip programs run on N zero-padded to a multiple of MOTION_CHUNK, their padded rows dropped
    # (``[:N]``): each row is computed on its own, so the values are those of the unpadded call, and one
    # compiled program of each serves every N up to the next multiple (a test session, or a sweep's
    # evaluate stages, compile them once, not once per reference size: ~0.5-2 CPU-s each).
    n_pad = -(-N // MOTION_CHUNK) * MOTION_CHUNK - N
    pad = lambda a: np.pad(a, [(0, n_pad)] + [(0, 0)] * (a.ndim - 1))  # noqa: E731
    gt = jnp.asarray(pad(np.asarray(gt_NxTx2x21x3, np.float32)))
    W = jnp.asarray(palm_barycentric(cfg.palm_points, cfg.seed))
    gt_intra, gt_inter = (np.asarray(a, bool)[:N] for a in contact_labels(gt, W, cfg.intra_contact_m,
                                                                          cfg.inter_contact_m))
    rows, per_clip = [], []
    for g in range(G):
        x = jnp.asarray(pad(gen[g]))
        intra, inter = (np.asarray(a, bool)[:N] for a in contact_labels(x, W, cfg.intra_contact_m,
                                                                        cfg.inter_contact_m))
        acc, jit_ = acceleration_jitter(x)
        clip = {"mpjpe": np.asarray(mpjpe_mm(x, gt, cfg.mpjpe_root), np.float64),
                "acceleration": np.asarray(acc, np.float64), "jitter": np.asarray(jit_, np.float64)}
        for name, v in (("ra", mpjpe_ra_mm(x, gt)), ("pa", mpjpe_pa_mm(x, gt))):
            v = np.asarray(v, np.float64)
            clip[f"mpjpe_{name}_left"], clip[f"mpjpe_{name}_right"] = v[:, 0], v[:, 1]
        clip["pen_1cm"], clip["pen_depth"] = penetration_stats(interhand_penetration(x), cfg.pen_threshold_m)
        if named is not None and len(named):
            clip["cf_hit"], clip["cf_named"] = contact_feasibility_counts(x, named, W)
        clip = {k: v[:N] for k, v in clip.items()}
        # Per-clip TP/FP/FN: contact P/R/F1 are micro-averaged, so a resample sums its clips' counts.
        for scope, p, q in (("intra", intra, gt_intra), ("inter", inter, gt_inter)):
            clip[f"tp_{scope}"] = (p & q).sum(1).astype(np.float64)
            clip[f"fp_{scope}"] = (p & ~q).sum(1).astype(np.float64)
            clip[f"fn_{scope}"] = (~p & q).sum(1).astype(np.float64)
        per_clip.append(clip)
        rows.append(_motion_row({k: v.sum() if _is_count(k) else v.mean() for k, v in clip.items()}))
    counts = resample_counts(bootstrap_indices(N, cfg), N)  # (B, N)
    if G > 1:
        out = {k: mean_ci([r[k] for r in rows]) for k in rows[0]}
        K = G if cfg.apd_samples == 0 else cfg.apd_samples
        if not 2 <= K <= G:
            raise ValueError(f"APD over {K} samples per prompt needs 2 <= K <= {G} (the groups given)")
        apd_Nx2 = apd_mm(np.pad(gen[:K], [(0, 0), (0, n_pad)] + [(0, 0)] * (gen.ndim - 2)))[:N]
        for h, side in enumerate(("left", "right")):
            out[f"apd_{side}"] = (float(apd_Nx2[:, h].mean()), per_prompt_ci(apd_Nx2[:, h], counts))
        return out
    resampled = _motion_row({k: counts @ v / (1.0 if _is_count(k) else N) for k, v in per_clip[0].items()})
    return {k: (float(rows[0][k]), bootstrap_half_width(np.asarray(resampled[k])[np.isfinite(resampled[k])]))
            for k in rows[0]}


def _is_count(key: str) -> bool:
    return key[:3] in ("tp_", "fp_", "fn_", "cf_")


def _prf(tp, fp, fn):
    """Micro-averaged precision/recall/F1 from summed counts (reference §5.4, as :func:`contact_prf`)."""
    prec = tp / (tp + fp + 1e-8)
    rec = tp / (tp + fn + 1e-8)
    return prec, rec, 2 * prec * rec / (prec + rec + 1e-8)


def _motion_row(m: dict) -> dict:
    """Metric values from per-group means (mpjpe, acceleration, jitter) and summed contact counts."""
    row = {k: m[k] for k in ("mpjpe", "acceleration", "jitter", "mpjpe_ra_left", "mpjpe_ra_right", "mpjpe_pa_left",
                             "mpjpe_pa_right", "pen_1cm", "pen_depth")}
    for scope in ("intra", "inter"):
        p, r, f = _prf(m[f"tp_{scope}"], m[f"fp_{scope}"], m[f"fn_{scope}"])
        row.update({f"contact_precision_{scope}": p, f"contact_recall_{scope}": r, f"contact_f1_{scope}": f})
    if "cf_named" in m:  # realised / named over the clips (a resample with none named has no value)
        named = np.asarray(m["cf_named"], np.float64)
        row["contact_feasibility"] = np.where(named > 0, m["cf_hit"] / np.where(named > 0, named, 1.0), np.nan)
    return {k: (float(v) if np.ndim(v) == 0 else v) for k, v in row.items()}
