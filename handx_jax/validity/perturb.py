"""Perturbations of ground-truth motion for the validity suite (issue 40).

Each perturbation is a pure function ``(joints_NxTx2x21x3, amplitude_m, rng) -> joints`` and is
either CAPTION-PRESERVING (what a caption says should survive it: sensor-scale noise, a small offset
of the whole clip) or MEANING-CHANGING (what a caption says should not survive it: the clip played
backwards, another clip's motion, and the edits of *which* hand or finger does what, issue 55: the two
hands swapped, two pairs of fingers swapped, one hand's fingers held still). The suite measures what the
annotation and the evaluator do under both kinds, against the millimetres each one moves the joints
(:func:`mean_shift_mm`).

The which/who edits keep the clip a physically valid pair of hands: every bone keeps its length, a left
hand stays a left hand and a right hand a right one (``swap_hands`` mirrors, it does not relabel), and the
swaps are involutions (applied twice they give the clip back). The evaluator's training takes them as hard
negatives of a clip's own caption (``models.evaluator.EvaluatorConfig.hard_negatives``).

Amplitudes are per coordinate, in metres: ``white`` 1 mm means N(0, 1 mm) on each x, y and z of each
frame (a mean joint shift of about 1.6 mm). Noise is never put on the wrists (joint 0): a wrist
carries the whole hand, so wrist noise is a different, larger perturbation of every other joint's
global position, and the tracking noise the suite imitates is a finger-level effect.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.ndimage import gaussian_filter1d

from handx_jax import skeleton as sk

Perturb = Callable[[np.ndarray, float, np.random.Generator], np.ndarray]

_FINGERS = np.arange(1, sk.NUM_JOINTS)  # every joint but the wrist


def white(x_NxTx2x21x3: np.ndarray, amp_m: float, rng: np.random.Generator) -> np.ndarray:
    """Independent N(0, amp) per coordinate and frame on every joint but the wrists."""
    y = np.array(x_NxTx2x21x3, dtype=np.float32, copy=True)
    n = rng.standard_normal(y[..., _FINGERS, :].shape).astype(np.float32)
    y[..., _FINGERS, :] += np.float32(amp_m) * n
    return y


def lowfreq(x_NxTx2x21x3: np.ndarray, amp_m: float, rng: np.random.Generator, *,
            sigma_frames: float = 4.0) -> np.ndarray:
    """Noise Gaussian-filtered over time (σ = 4 frames, ~0.13 s: the tracking wobble of a fit),
    rescaled to ``amp`` RMS per coordinate, on every joint but the wrists."""
    y = np.array(x_NxTx2x21x3, dtype=np.float32, copy=True)
    n = rng.standard_normal(y[..., _FINGERS, :].shape)
    n = gaussian_filter1d(n, sigma_frames, axis=1, mode="reflect")
    n /= max(float(np.sqrt(np.mean(n * n))), 1e-12)
    y[..., _FINGERS, :] += np.float32(amp_m) * n.astype(np.float32)
    return y


def offset(x_NxTx2x21x3: np.ndarray, amp_m: float, rng: np.random.Generator) -> np.ndarray:
    """One constant offset per clip and joint (a calibration error): N(0, amp) per coordinate, fixed
    over time, on every joint but the wrists."""
    y = np.array(x_NxTx2x21x3, dtype=np.float32, copy=True)
    N = y.shape[0]
    n = rng.standard_normal((N, 1, 2, len(_FINGERS), 3)).astype(np.float32)
    y[..., _FINGERS, :] += np.float32(amp_m) * n
    return y


def shift(x_NxTx2x21x3: np.ndarray, amp_m: float, rng: np.random.Generator) -> np.ndarray:
    """The whole clip (both hands, every joint and frame) moved by ``amp`` along a random direction."""
    y = np.array(x_NxTx2x21x3, dtype=np.float32, copy=True)
    d = rng.standard_normal((y.shape[0], 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return y + (amp_m * d).astype(np.float32)[:, None, None, None, :]


def reverse(x_NxTx2x21x3: np.ndarray, amp_m: float, rng: np.random.Generator) -> np.ndarray:
    """The clip played backwards (same poses, opposite order of events)."""
    return np.ascontiguousarray(np.asarray(x_NxTx2x21x3, dtype=np.float32)[:, ::-1])


def other_clip(x_NxTx2x21x3: np.ndarray, amp_m: float, rng: np.random.Generator) -> np.ndarray:
    """Another clip's motion: a random derangement of the clips (no clip keeps its own)."""
    x = np.asarray(x_NxTx2x21x3, dtype=np.float32)
    N = x.shape[0]
    if N < 2:
        raise ValueError("another clip's motion needs at least 2 clips")
    perm = rng.permutation(N)
    perm = np.where(perm == np.arange(N), np.roll(perm, 1), perm)
    while np.any(perm == np.arange(N)):  # rare: a fixed point survived the roll
        perm = rng.permutation(N)
    return np.ascontiguousarray(x[perm])


def swap_hands(x_NxTx2x21x3: np.ndarray, amp_m: float, rng: np.random.Generator) -> np.ndarray:
    """The left hand's motion played by the right hand and the right's by the left, each mirrored through the
    clip's sagittal plane: the plane bisecting the two wrists in frame 0 (normal along left wrist → right
    wrist, through their midpoint). In the corpus's canonical frame (``skeleton.canonicalize``: +x from the
    left wrist to the right one, right wrist at the origin in frame 0) this is ``x → x_L − x`` with ``x_L``
    the frame-0 left wrist's x, and the result is canonical again (the new right wrist starts at the origin).

    A reflection is an isometry that reverses handedness, so the mirrored left hand is a right hand (the
    corpus's left hand is its right hand mirrored, ``synthesis/hand.py``), every bone length and every
    distance between the two hands is kept (contacts and penetration unchanged), and applying it twice gives
    the clip back (the two frame-0 wrists exchange places, so the plane is the same)."""
    y = np.asarray(x_NxTx2x21x3, np.float64)
    lw, rw = y[:, 0, sk.LEFT, 0], y[:, 0, sk.RIGHT, 0]
    n = rw - lw
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError("swap_hands: the two wrists coincide in frame 0 (no sagittal plane)")
    n /= norm
    mid = 0.5 * (lw + rw)
    d = np.einsum("ntkjc,nc->ntkj", y - mid[:, None, None, None], n)
    y = y - 2.0 * d[..., None] * n[:, None, None, None, :]
    return np.ascontiguousarray(y[:, :, ::-1]).astype(np.float32)


# The finger pairs ``swap_fingers`` exchanges: index <-> middle and ring <-> pinky (the four fingers the
# captions name one by one; the thumb, which the corpus's captions rarely name, is left alone). Disjoint
# pairs, so the edit is an involution.
FINGER_SWAPS = (("index", "middle"), ("ring", "pinky"))


def _min_rotation(u_Xx3: np.ndarray, v_Xx3: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit ``u`` onto unit ``v`` (Rodrigues about u × v), (..., 3, 3). Its inverse
    is the one taking ``v`` onto ``u``. Metacarpals of neighbouring fingers are some 10-20 degrees apart, far
    from the antiparallel case where the axis is undefined."""
    w = np.cross(u_Xx3, v_Xx3)
    c = np.sum(u_Xx3 * v_Xx3, -1)
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return np.eye(3) + K + (K @ K) / (1.0 + c)[..., None, None]


def swap_fingers(x_NxTx2x21x3: np.ndarray, amp_m: float, rng: np.random.Generator) -> np.ndarray:
    """Index and middle, and ring and pinky, exchange their motion relative to the palm, on both hands.

    Finger a's three bones (MCP → PIP → DIP → tip) take finger b's bone directions, turned by the smallest
    rotation that takes b's metacarpal (wrist → b's MCP) onto a's, and keep a's own lengths, from a's own
    MCP. Preserved exactly: the palm (wrist, thumb and the four MCPs do not move), every bone length, and the
    shape of each finger relative to its own metacarpal, now worn by the other finger (the flexion angles at
    its MCP, PIP and DIP are the other finger's, and so is its splay about the metacarpal). What changes is
    which finger curls: what the captions say finger by finger. Applied twice, it gives the clip back."""
    y = np.array(x_NxTx2x21x3, dtype=np.float64, copy=True)
    x = np.asarray(x_NxTx2x21x3, np.float64)
    w = x[..., :1, :]
    for fa, fb in FINGER_SWAPS:
        ca, cb = list(sk.CHAINS[fa][1:]), list(sk.CHAINS[fb][1:])  # MCP, PIP, DIP, tip
        ja, jb = x[..., ca, :], x[..., cb, :]
        ua = ja[..., 0, :] - w[..., 0, :]
        ub = jb[..., 0, :] - w[..., 0, :]
        ua /= np.linalg.norm(ua, axis=-1, keepdims=True)
        ub /= np.linalg.norm(ub, axis=-1, keepdims=True)
        r_ba = _min_rotation(ub, ua)  # b's metacarpal onto a's; its transpose the other way
        for dst, j_dst, j_src, r in ((ca, ja, jb, r_ba), (cb, jb, ja, np.swapaxes(r_ba, -1, -2))):
            bone_dst = np.diff(j_dst, axis=-2)
            bone_src = np.diff(j_src, axis=-2)
            length = np.linalg.norm(bone_dst, axis=-1, keepdims=True)
            unit = bone_src / np.linalg.norm(bone_src, axis=-1, keepdims=True)
            turned = np.einsum("...ij,...kj->...ki", r, unit)
            y[..., dst[1:], :] = j_dst[..., :1, :] + np.cumsum(turned * length, axis=-2)
    return y.astype(np.float32)


def still_fingers(x_NxTx2x21x3: np.ndarray, amp_m: float, rng: np.random.Generator) -> np.ndarray:
    """One hand per clip (left or right, drawn from ``rng``) keeps its frame-0 shape all clip long: the hand
    moves as one rigid body with its wrist frame (``representation.geometry.wrist_frames``), so its wrist path
    and turning stay and only its fingers stop. Who moves the fingers changes; bone lengths are the frame-0
    ones at every frame, the other hand is untouched, and applying it again (same draw) changes nothing."""
    from handx_jax.representation.geometry import local_positions, wrist_frames

    y = np.array(x_NxTx2x21x3, dtype=np.float32, copy=True)
    x = np.asarray(x_NxTx2x21x3, np.float64)
    hand = rng.integers(0, 2, x.shape[0])
    R = wrist_frames(x)  # (N, T, 2, 3, 3), columns the local axes
    local0 = local_positions(x[:, :1])  # (N, 1, 2, 21, 3)
    rigid = np.einsum("nthij,nhkj->nthki", R, local0[:, 0]) + x[..., :1, :]
    pick = np.arange(x.shape[0])
    y[pick, :, hand] = rigid[pick, :, hand].astype(np.float32)
    return y


@dataclass(frozen=True)
class Kind:
    """A perturbation kind: its function, whether it should keep the captions, and its amplitudes
    (metres; one entry 0 for kinds without an amplitude)."""

    name: str
    fn: Perturb
    preserving: bool
    amplitudes_m: tuple[float, ...]
    label: str


# The suite's default grid: sensor-scale noise from 0.3 to 10 mm (issue 40: "at least 0.3–10 mm"),
# small per-clip offsets, a global shift, and the meaning-changing kinds: order (reversal), everything
# (another clip), and which hand or finger does what (issue 55).
KINDS: dict[str, Kind] = {k.name: k for k in (
    Kind("white", white, True, (0.0003, 0.001, 0.003, 0.01), "white noise on the fingers"),
    Kind("lowfreq", lowfreq, True, (0.0003, 0.001, 0.003, 0.01), "low-frequency noise (σ 4 frames)"),
    Kind("offset", offset, True, (0.001, 0.003), "one offset per clip and joint"),
    Kind("shift", shift, True, (0.05,), "whole clip shifted"),
    Kind("reverse", reverse, False, (0.0,), "time reversed"),
    Kind("other", other_clip, False, (0.0,), "another clip's motion"),
    Kind("swap_hands", swap_hands, False, (0.0,), "left and right hands swapped (mirrored)"),
    Kind("swap_fingers", swap_fingers, False, (0.0,), "index<->middle and ring<->pinky swapped"),
    Kind("still_fingers", still_fingers, False, (0.0,), "one hand's fingers held still"),
)}


# The meaning-changing kinds that edit a clip into another valid clip of the same scene (not another clip, not
# the reversal, which ``reverse_negative`` already takes): the evaluator's hard negatives (issue 55).
HARD_NEGATIVE_KINDS = ("swap_hands", "swap_fingers", "still_fingers")


def reads_the_same(kind: str, left: str, right: str, interaction: str, level: int) -> bool:
    """Does ``kind``'s edit of a clip whose captions at ``level`` are (left, right, interaction) read as the clip
    itself, known from the captions alone? Only where the annotation gives a rule: it is mirror-symmetric, so
    a clip with its hands swapped reads (right, left, interaction) at level 0 (tests/test_validity_which.py
    holds it on every clip of a build), the same exactly when both hands' texts are equal. Elsewhere
    (other kinds, other levels, whose texts name the sides) False: taken as reading differently, the
    assumption the reversal negative makes."""
    return kind == "swap_hands" and level == 0 and left == right


def apply(kind: str, x_NxTx2x21x3: np.ndarray, amp_m: float, seed: int) -> np.ndarray:
    """Perturb with a seeded stream that depends only on (seed, kind, amplitude)."""
    k = KINDS[kind]
    rng = np.random.default_rng([seed, list(KINDS).index(kind), int(round(amp_m * 1e6))])
    return k.fn(x_NxTx2x21x3, amp_m, rng)


def mean_shift_mm(a_NxTx2x21x3: np.ndarray, b_NxTx2x21x3: np.ndarray) -> float:
    """Mean Euclidean distance between corresponding joints, in millimetres."""
    d = np.asarray(a_NxTx2x21x3, np.float64) - np.asarray(b_NxTx2x21x3, np.float64)
    return float(np.sqrt(np.sum(d * d, -1)).mean() * 1000.0)
