"""Perturbations of ground-truth motion for the validity suite (issue 40).

Each perturbation is a pure function ``(joints_NxTx2x21x3, amplitude_m, rng) -> joints`` and is
either CAPTION-PRESERVING (what a caption says should survive it: sensor-scale noise, a small offset
of the whole clip) or MEANING-CHANGING (what a caption says should not survive it: the clip played
backwards, another clip's motion). The suite measures what the annotation and the evaluator do under
both kinds, against the millimetres each one moves the joints (:func:`mean_shift_mm`).

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
# small per-clip offsets, a global shift, and the two meaning-changing kinds.
KINDS: dict[str, Kind] = {k.name: k for k in (
    Kind("white", white, True, (0.0003, 0.001, 0.003, 0.01), "white noise on the fingers"),
    Kind("lowfreq", lowfreq, True, (0.0003, 0.001, 0.003, 0.01), "low-frequency noise (σ 4 frames)"),
    Kind("offset", offset, True, (0.001, 0.003), "one offset per clip and joint"),
    Kind("shift", shift, True, (0.05,), "whole clip shifted"),
    Kind("reverse", reverse, False, (0.0,), "time reversed"),
    Kind("other", other_clip, False, (0.0,), "another clip's motion"),
)}


def apply(kind: str, x_NxTx2x21x3: np.ndarray, amp_m: float, seed: int) -> np.ndarray:
    """Perturb with a seeded stream that depends only on (seed, kind, amplitude)."""
    k = KINDS[kind]
    rng = np.random.default_rng([seed, list(KINDS).index(kind), int(round(amp_m * 1e6))])
    return k.fn(x_NxTx2x21x3, amp_m, rng)


def mean_shift_mm(a_NxTx2x21x3: np.ndarray, b_NxTx2x21x3: np.ndarray) -> float:
    """Mean Euclidean distance between corresponding joints, in millimetres."""
    d = np.asarray(a_NxTx2x21x3, np.float64) - np.asarray(b_NxTx2x21x3, np.float64)
    return float(np.sqrt(np.sum(d * d, -1)).mean() * 1000.0)
