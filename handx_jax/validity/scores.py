"""What an evaluator makes of perturbed ground truth: Top-3 R-Precision and FID of the perturbed test
clips scored as if generated (``handx eval run`` on them), each Top-3 beside the unperturbed ground
truth's as a ratio.

A yardstick that reads what captions say keeps the ground truth's score under caption-preserving
perturbations (ratio near 1), loses it under meaning-changing ones (time reversal: the order of
events; another clip's motion: chance), and keeps most of it on a good tokenizer's reconstruction
(text-to-motion evaluators keep 0.95–1.0, issue 40). FID is reported as is: the ground truth's own
FID is 0 by construction (it is its own reference set), so there is no ratio to take.
"""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np


class Scorer:
    """Scores joints ``(N, 60, 2, 21, 3)`` aligned with ``clips`` (indices into the dataset's test
    split, with their prompts) under one evaluator, in this process."""

    def __init__(self, ev, ds, clips: Sequence[int], prompts, *, block: int = 32, cache=None):
        from handx_jax.metrics import MetricConfig

        self.ev, self.ds, self.clips, self.prompts = ev, ds, list(clips), list(prompts)
        self.cfg = MetricConfig(rprec_block=block)
        self.cache = cache if cache is not None else False

    def score(self, joints_NxTx2x21x3: np.ndarray) -> dict:
        """``handx eval run`` of these joints as generated, in memory (no .npz written and read back)."""
        from handx_jax.evaluation import evaluate_generated
        from handx_jax.generation import generated_entries

        entries = generated_entries(np.asarray(joints_NxTx2x21x3, np.float32), [[p] for p in self.prompts],
                                    source_clips=[self.ds.ids[c] for c in self.clips], groups=[0] * len(self.clips))
        res = evaluate_generated(self.ev, entries, self.ds, self.cfg, cache=self.cache).flat()
        return {k: float(res[k]) for k in ("rprec_top1", "rprec_top3", "rprec_top3_ci", "fid") if k in res}


def tokenizer_reconstruction(tok_dir, gt_NxTx2x21x3: np.ndarray) -> np.ndarray:
    """Ground truth through an FSQ tokenizer run (a folder, or one ``tokenizer.load`` opened) and back
    (encode → codes → decode), as global joints placed at each clip's first right-wrist position (the AR
    family's features integrate the root)."""
    import jax.numpy as jnp

    from handx_jax import representation as rep
    from handx_jax.families import tokenizer as T
    from handx_jax.models import fsq as Q

    gt = np.asarray(gt_NxTx2x21x3, np.float32)
    tok = T.load(tok_dir) if isinstance(tok_dir, (str, os.PathLike)) else tok_dir
    gt_u = rep.to_ar(gt.astype(np.float64)).astype(np.float32)
    out = []
    for s in range(0, len(gt_u), 256):  # bounded memory on long test splits
        xh = tok.model.apply(tok.params, jnp.asarray(tok.norm.normalize(gt_u[s:s + 256]), jnp.float32))[0]
        pr_u = np.asarray(tok.norm.denormalize(np.asarray(xh)), np.float32)
        out.append(np.asarray(Q.global_joints(jnp.asarray(pr_u))))
    root0 = gt[:, 0, 1, 0]
    return np.concatenate(out) + root0[:, None, None, None, :]


def finger_error_mm(a_NxTx2x21x3: np.ndarray, b_NxTx2x21x3: np.ndarray) -> float:
    """Mean wrist-relative error of the 20 finger joints, in millimetres (the precision a hand needs:
    1.7 % of a 19 cm hand is ~3 mm)."""
    a = np.asarray(a_NxTx2x21x3, np.float64)
    b = np.asarray(b_NxTx2x21x3, np.float64)
    ra, rb = a[..., 1:, :] - a[..., :1, :], b[..., 1:, :] - b[..., :1, :]
    return float(np.linalg.norm(ra - rb, axis=-1).mean() * 1000.0)


def wrist_path_error_mm(a_NxTx2x21x3: np.ndarray, b_NxTx2x21x3: np.ndarray) -> float:
    """Mean distance between the two wrists' global positions, in millimetres."""
    a = np.asarray(a_NxTx2x21x3, np.float64)[..., 0, :]
    b = np.asarray(b_NxTx2x21x3, np.float64)[..., 0, :]
    return float(np.linalg.norm(a - b, axis=-1).mean() * 1000.0)


def hybrids(gt_NxTx2x21x3: np.ndarray, rec_NxTx2x21x3: np.ndarray) -> dict[str, np.ndarray]:
    """A reconstruction's errors, each alone on the ground truth:

    - ``shape``: the reconstruction's joints relative to its wrists, placed on the ground truth's wrists
      (the hand's shape and orientation as reconstructed, the wrist path true);
    - ``articulation``: the same with each hand turned onto the ground truth's palm orientation
      (``palm_aligned``): the fingers' articulation error alone;
    - ``wrist_path``: the ground truth moved, per hand and frame, onto the reconstruction's wrists.

    The AR features integrate the root, so a tokenizer's wrist path drifts by centimetres; which part costs
    the evaluator's score is what limits the tokenizer (issue 40, item 5).
    """
    gt = np.asarray(gt_NxTx2x21x3, np.float32)
    rec = np.asarray(rec_NxTx2x21x3, np.float32)
    w_gt, w_rec = gt[..., :1, :], rec[..., :1, :]
    return {"shape": rec - w_rec + w_gt, "articulation": palm_aligned(gt, rec), "wrist_path": gt - w_gt + w_rec}


def palm_aligned(gt_NxTx2x21x3: np.ndarray, rec_NxTx2x21x3: np.ndarray) -> np.ndarray:
    """The reconstruction's hands turned, per hand and frame, about their wrists onto the ground truth's palm
    orientation (the rotation that best maps the rigid palm, wrist and four MCPs, onto the ground truth's:
    ``metrics.best_rotation``) and placed on the ground truth's wrists. What is left of the error is the
    fingers' articulation alone."""
    import jax.numpy as jnp

    from handx_jax import skeleton as sk
    from handx_jax.metrics import best_rotation

    gt = np.asarray(gt_NxTx2x21x3, np.float32)
    rec = np.asarray(rec_NxTx2x21x3, np.float32)
    rel_gt, rel_rec = gt - gt[..., :1, :], rec - rec[..., :1, :]
    palm = [0, *sorted(sk.MCPS.values())]
    r, _ = best_rotation(jnp.asarray(rel_rec[..., palm, :]), jnp.asarray(rel_gt[..., palm, :]))
    return np.asarray(jnp.einsum("...ij,...kj->...ki", r, jnp.asarray(rel_rec))) + gt[..., :1, :]


def caption_reader_top3(ev, clean_text_NxD, captions, *, block: int = 32) -> float:
    """Top-3 R-Precision of a reader of captions alone: the perturbed clips' own level-0 captions, through the
    evaluator's text side, stand in for their motion embeddings and are ranked against the clean captions'
    embeddings ``clean_text_NxD`` (``ev.embed_text`` of them, computed once by the caller).

    It is what an evaluator that read exactly what the annotation says would score. Where it stays high
    under a meaning-changing perturbation, the captions themselves still pick the clip out of a block of
    unrelated ones (time reversal keeps the same fingers and actions in another order), and no evaluator
    that reads captions should score lower."""
    import jax.numpy as jnp

    from handx_jax.metrics import r_precision

    t_pert = ev.embed_text(*zip(*captions))
    top, _ = r_precision(jnp.asarray(clean_text_NxD), jnp.asarray(t_pert), block, 3)
    return float(top[2])


def order_test(ev, gt_NxTx2x21x3, reversed_NxTx2x21x3, clean_captions, reversed_captions, clean_text_NxD) -> dict:
    """Does the evaluator read the order of events? On the clips whose reversal reads differently at level 0,
    a two-way choice between the clip's caption and its reversal's caption: the share of forward clips
    nearer their own caption, and of reversed clips nearer the reversed caption (chance 0.5 each; a
    yardstick blind to order scores 0.5). Any other edit of a clip's own motion takes the reversal's place
    (``reversed_*``: the edited clips and their captions): the suite's which test of swapped hands and fingers."""
    differs = np.array([a != b for a, b in zip(clean_captions, reversed_captions)])
    if not differs.any():
        return {"clips": 0}
    pick = np.flatnonzero(differs)
    t_f = np.asarray(clean_text_NxD)[pick]
    t_r = ev.embed_text(*zip(*[reversed_captions[i] for i in pick]))
    m_f = ev.embed_motion(np.asarray(gt_NxTx2x21x3)[pick])
    m_r = ev.embed_motion(np.asarray(reversed_NxTx2x21x3)[pick])
    d = lambda a, b: np.linalg.norm(a - b, axis=-1)  # noqa: E731  the evaluator's distance (metrics.r_precision)
    fwd = float(np.mean(d(m_f, t_f) < d(m_f, t_r)))
    rev = float(np.mean(d(m_r, t_r) < d(m_r, t_f)))
    return {"clips": int(len(pick)), "forward_picks_own": fwd, "reversed_picks_reversed": rev,
            "mean": (fwd + rev) / 2}
