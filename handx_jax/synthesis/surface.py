"""Corpus v5's contact stage (issue 55 item 2): the two hands' wrist translations resolved against the hand
surface (handx_jax/hand_surface.py), so that hands touch surface to surface and never pass through each other.

The stage runs on a chunk's final hands: the finger programs, the wrist paths, the angle and wrist noise and
corpus v4's contact alignment are all composed into the posed hands ``J0`` plus the wrist translations
``tr`` before it, and nothing after it moves one hand relative to the other (the room placement is one rigid
motion of both). So checking and resolving here covers every stage that moves a hand, and a test on the
built clips holds it (tests/test_synthesis_surface.py).

Per frame, with the separating direction u of the closest capsule pair (``hand_surface.interhand_separation``):
the right wrist moves by +δ/2·u and the left by −δ/2·u, which changes the surface distance by δ while that
pair stays the closest. A frame of a contact program (its gap schedule says how far apart the hands are, 0
at contact) is brought to exactly that distance, pulling the hands together or pushing them apart, so
pressed palms, touching fingertips, interlaced or gripping fingers come to rest at contact and not inside
each other. Any other frame only gets pushed, up to ``min_gap_m``. A few passes settle frames where the
closest pair changes as the hands move (fingers of one hand sliding past the other's).
"""

from __future__ import annotations

import numpy as np

from scipy.ndimage import gaussian_filter1d

from handx_jax import hand_surface

MIN_GAP_M = 0.02  # surfaces of hands without a contact program keep 2 cm apart (4x the annotation's 5 mm touch)
PASSES = 4        # pushes along the closest pair's direction
MARCH_STEPS = 24  # then, where the hands are still too close, steps straight apart
TOLERANCE_M = 2e-4
SMOOTH_FRAMES = 3.0  # σ of the temporal smoothing of the corrections (a per-frame solve jerks where the pair changes)
SMOOTH_ROUNDS = 4


def _palm_centres(J_Mx2x21x3: np.ndarray) -> np.ndarray:
    return J_Mx2x21x3[:, :, [0, 1, 4, 7, 10, 13]].mean(2)  # (M, 2, 3): wrist, finger bases


def _separation(J_Kx2x21x3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """hand_surface.interhand_separation of K frames (one compiled shape whatever K is: the solve below
    evaluates only the frames that moved)."""
    sd, u = hand_surface.in_batches(hand_surface.interhand_separation, J_Kx2x21x3)
    return sd.astype(np.float64), u.astype(np.float64)


def _resolve_frames(J0_Mx2x21x3: np.ndarray, tr_Mx2x3: np.ndarray, gap_M: np.ndarray, min_gap_m: float,
                    sd_M: np.ndarray, u_M: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wrist translations (M, 2, 3) of independent frames resolved, and the surface distance (M,) and separating
    direction (M, 3) they leave, from the frames' current distance and separating direction (``sd_M``, ``u_M``).

    First PASSES pushes along the closest pair's separating direction (exact while that pair stays the
    closest). Where the hands are still closer than asked (fingers of one hand between the other's, where
    each push finds a new closest pair), they then step straight apart along the line between the palm
    centres by the remaining deficit: the distance grows by at most the step, so a step never overshoots the
    first contact-free place along that line. Contact frames left farther apart than asked keep that gap.
    Only frames that move are evaluated again."""
    tr, sd, u = np.array(tr_Mx2x3, np.float64), sd_M.copy(), u_M.copy()
    exact = np.isfinite(gap_M)
    want = np.where(exact, gap_M, min_gap_m)

    def update(rows):
        sd[rows], u[rows] = _separation(J0_Mx2x21x3[rows] + tr[rows, :, None, :])

    for _ in range(PASSES):
        delta = np.where(exact, want - sd, np.maximum(want - sd, 0.0))
        rows = np.flatnonzero(np.abs(delta) >= TOLERANCE_M)
        if rows.size == 0:
            return tr, sd, u
        tr[rows, 1] += 0.5 * delta[rows, None] * u[rows]
        tr[rows, 0] -= 0.5 * delta[rows, None] * u[rows]
        update(rows)
    for _ in range(MARCH_STEPS):
        deficit = np.maximum(want - sd, 0.0)
        rows = np.flatnonzero(deficit >= TOLERANCE_M)
        if rows.size == 0:
            break
        c = _palm_centres(J0_Mx2x21x3[rows] + tr[rows, :, None, :])
        w = c[:, 1] - c[:, 0]
        w /= np.maximum(np.linalg.norm(w, axis=-1, keepdims=True), 1e-9)
        step = (deficit[rows] + TOLERANCE_M)[:, None] * w
        tr[rows, 1] += 0.5 * step
        tr[rows, 0] -= 0.5 * step
        update(rows)
    return tr, sd, u


def resolve_translations(J0_NxLx2x21x3: np.ndarray, tr_NxLx2x3: np.ndarray, gap_NxL: np.ndarray,
                         min_gap_m: float = MIN_GAP_M) -> tuple[np.ndarray, np.ndarray]:
    """Wrist translations (N, L, 2, 3) after the contact stage, and the surface distance (N, L) they leave, for
    N sequences of L frames.

    ``gap_NxL``: the distance a contact program asks for on each frame (0 = touching), NaN on frames without
    one; those keep at least ``min_gap_m``. ``J0`` are the posed hands before translation (metres). Each frame
    is solved on its own (:func:`_resolve_frames`); the corrections are then smoothed over time (Gaussian,
    SMOOTH_FRAMES) and the frames solved again from the smoothed ones, SMOOTH_ROUNDS times, so that the
    wrists move smoothly and the last solve leaves only small corrections."""
    N, L = gap_NxL.shape
    J0 = np.asarray(J0_NxLx2x21x3, np.float64).reshape(N * L, 2, -1, 3)
    tr0 = np.asarray(tr_NxLx2x3, np.float64).reshape(N * L, 2, 3)
    gap = np.asarray(gap_NxL, np.float64).reshape(-1)
    sd, u = _separation(J0 + tr0[:, :, None, :])
    tr, sd, u = _resolve_frames(J0, tr0, gap, min_gap_m, sd, u)
    for _ in range(SMOOTH_ROUNDS):
        corr = (tr - tr0).reshape(N, L, 2, 3)
        smooth = tr0 + gaussian_filter1d(corr, SMOOTH_FRAMES, axis=1, mode="nearest").reshape(-1, 2, 3)
        rows = np.flatnonzero(np.abs(smooth - tr).max((1, 2)) > 1e-7)
        tr = smooth
        if rows.size:
            sd[rows], u[rows] = _separation(J0[rows] + tr[rows, :, None, :])
        tr, sd, u = _resolve_frames(J0, tr, gap, min_gap_m, sd, u)
    return tr.reshape(N, L, 2, 3), sd.reshape(N, L)
