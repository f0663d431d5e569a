"""Clip extraction around defective frames (paper A.3) and the intensity filter (paper A.4).

A long sequence ``(T, 2, 21, 3)`` is cut into non-overlapping 60-frame windows placed inside the
maximal runs of valid frames (Eq. C and the interval partition of A.3). Each window is then scored
with the weighted joint angular-velocity intensity (Eq. D–F; reference §7) and kept when both hands
reach ``tau_hand`` and their mean reaches ``tau_avg`` (deg/s).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from handx_jax import skeleton as sk


@dataclass(frozen=True)
class ClipConfig:
    clip_len: int = sk.CLIP_LEN
    fps: int = sk.FPS
    # Intensity thresholds in deg/s (paper A.4: tau_hand = 25, tau_avg = 30).
    tau_hand: float = 25.0
    tau_avg: float = 30.0
    # Proximal / middle / distal weights λ (reference §7: 9, 3, 1).
    weights: tuple[float, float, float] = (9.0, 3.0, 1.0)
    # Defective-frame detection (A.3 leaves the criteria open; these are ours):
    # a joint moving more than this between consecutive frames is an "abrupt change" (4.5 m/s at 30 fps),
    max_joint_step_m: float = 0.15
    # a bone deviating more than this fraction from the sequence's median length is a broken pose,
    max_bone_deviation: float = 0.5
    # and hands further apart than this are not a bimanual pose (tracking failure).
    max_wrist_distance_m: float = 1.5


def interior_angles_deg(joints_Nx2x21x3: np.ndarray) -> np.ndarray:
    """Inter-segment angle θ (Eq. D) at the 15 interior joints, degrees, shape (..., 2, 15).

    Zero-length bones give a zero direction, i.e. an angle of 0 (the reference's arccos gives 90°;
    neither occurs for valid clips, which have no zero-length bones).
    """
    # float64: the intensity filter thresholds these angles' rates, and a float32 arctan2 can differ in its
    # last bit between numpy builds; a clip must be kept or dropped alike everywhere (issue 14.5).
    x = np.asarray(joints_Nx2x21x3, dtype=np.float64)
    tri = np.asarray(sk.INTERIOR_TRIPLES)
    pre = x[..., tri[:, 1], :] - x[..., tri[:, 0], :]
    nxt = x[..., tri[:, 2], :] - x[..., tri[:, 1], :]
    def unit(v):
        n = np.linalg.norm(v, axis=-1, keepdims=True)
        return np.where(n > 0, v / np.where(n > 0, n, 1), 0)
    u, v = unit(pre), unit(nxt)
    # atan2(|u×v|, u·v) equals arccos(u·v) but stays accurate near 0° and 180°, where arccos of a
    # float32 dot product loses ~0.03° and would add spurious angular velocity to still fingers.
    sin = np.linalg.norm(np.cross(u, v), axis=-1)
    return np.degrees(np.arctan2(sin, np.sum(u * v, axis=-1)))


def hand_intensity(joints_NxTx2x21x3: np.ndarray, cfg: ClipConfig = ClipConfig()) -> np.ndarray:
    """Per-hand intensity ω̄_h (Eq. E) in deg/s, shape (N, 2), for clips ``(N, T, 2, 21, 3)``.

    ω is |Δθ| · fps at each interior joint; the weighted average uses λ by position in the chain
    (proximal 9, middle 3, distal 1), over all T−1 differences.
    """
    theta = interior_angles_deg(joints_NxTx2x21x3)  # (N, T, 2, 15)
    omega = np.abs(np.diff(theta, axis=1)) * cfg.fps  # (N, T-1, 2, 15)
    lam = np.tile(np.asarray(cfg.weights, dtype=np.float64), 5)  # chain-major: (p, m, d) × 5
    return (omega * lam).sum(-1).mean(1) / lam.sum()


def keep_mask(intensity_Nx2: np.ndarray, cfg: ClipConfig = ClipConfig()) -> np.ndarray:
    """The filtering rule of A.4: both hands ≥ tau_hand and their mean ≥ tau_avg."""
    i = np.asarray(intensity_Nx2)
    return (i[:, 0] >= cfg.tau_hand) & (i[:, 1] >= cfg.tau_hand) & (i.mean(1) >= cfg.tau_avg)


def defective_frames(seq_Tx2x21x3: np.ndarray, cfg: ClipConfig = ClipConfig()) -> dict[str, np.ndarray]:
    """Boolean masks (T,) of defective frames, one per reason. A frame is defective for any reason."""
    x = np.asarray(seq_Tx2x21x3, dtype=np.float64)
    T = x.shape[0]
    nonfinite = ~np.isfinite(x).reshape(T, -1).all(1)
    xs = np.where(np.isfinite(x), x, 0.0)
    # Abrupt change: a joint jumps between consecutive *finite* frames. Both frames of the jump are
    # marked, since we cannot tell which one is wrong.
    step = np.linalg.norm(np.diff(xs, axis=0), axis=-1).reshape(T - 1, -1).max(1) if T > 1 else np.zeros(0)
    jump_pair = (step > cfg.max_joint_step_m) & ~nonfinite[1:] & ~nonfinite[:-1]
    jump = np.zeros(T, bool)
    jump[1:] |= jump_pair
    jump[:-1] |= jump_pair
    bones = sk.bone_lengths(xs)  # (T, 2, 20)
    ok = ~nonfinite
    if ok.any():
        med = np.median(bones[ok], axis=0)
        dev = np.abs(bones - med) / np.maximum(med, 1e-6)
        broken = (dev > cfg.max_bone_deviation).reshape(T, -1).any(1) & ok
    else:
        broken = np.zeros(T, bool)
    apart = (np.linalg.norm(xs[:, 0, 0] - xs[:, 1, 0], axis=-1) > cfg.max_wrist_distance_m) & ok
    return {"nonfinite": nonfinite, "jump": jump & ~nonfinite, "broken_pose": broken, "hands_apart": apart}


def defect_reasons_help(cfg: ClipConfig = ClipConfig()) -> str:
    """What the cut report's ``defective_frames`` counts mean (for --help texts)."""
    return ("defective_frames counts frames cut out before windowing, by reason (paper A.3): "
            f"nonfinite = a NaN/inf coordinate; jump = a joint moves more than {cfg.max_joint_step_m} m between "
            f"consecutive frames (both frames); broken_pose = a bone's length is more than "
            f"{cfg.max_bone_deviation:.0%} off its median length over the sequence; hands_apart = the wrists are "
            f"more than {cfg.max_wrist_distance_m} m apart. rejected_intensity counts windows below the "
            f"intensity filter (paper A.4: each hand >= {cfg.tau_hand:g} deg/s and their mean >= {cfg.tau_avg:g}).")


def valid_intervals(valid_T: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of valid frames as half-open [a, b) intervals."""
    v = np.concatenate([[False], np.asarray(valid_T, bool), [False]])
    d = np.diff(v.astype(np.int8))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return list(zip(starts.tolist(), ends.tolist()))


def window_starts(valid_T: np.ndarray, clip_len: int = sk.CLIP_LEN) -> list[int]:
    """Start frames of disjoint windows of ``clip_len`` inside every valid run, stride = clip_len."""
    starts = []
    for a, b in valid_intervals(valid_T):
        starts.extend(range(a, b - clip_len + 1, clip_len))
    return starts


@dataclass
class ClipReport:
    """How many frames and windows were cut, and why."""

    sequences: int = 0
    frames: int = 0
    defective_frames: Counter = field(default_factory=Counter)
    frames_in_short_runs: int = 0  # valid frames left over: runs shorter than a clip, and remainders
    windows: int = 0
    rejected_intensity: Counter = field(default_factory=Counter)
    kept: int = 0

    def merge(self, other: "ClipReport") -> None:
        self.sequences += other.sequences
        self.frames += other.frames
        self.defective_frames.update(other.defective_frames)
        self.frames_in_short_runs += other.frames_in_short_runs
        self.windows += other.windows
        self.rejected_intensity.update(other.rejected_intensity)
        self.kept += other.kept

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["defective_frames"] = dict(self.defective_frames)
        d["rejected_intensity"] = dict(self.rejected_intensity)
        return d


def extract_clips(seq_Tx2x21x3: np.ndarray, cfg: ClipConfig = ClipConfig()
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, ClipReport]:
    """Cut one sequence into filtered clips.

    Returns (clips (K, L, 2, 21, 3) float32, start frames (K,), intensity (K, 2), report). Only kept
    clips are returned; the report counts what was cut and why.
    """
    seq = np.asarray(seq_Tx2x21x3)
    if seq.ndim != 4 or seq.shape[1:] != (2, sk.NUM_JOINTS, 3):
        raise ValueError(f"expected a sequence of shape (T, 2, 21, 3), got {seq.shape}")
    rep = ClipReport(sequences=1, frames=seq.shape[0])
    masks = defective_frames(seq, cfg)
    bad = np.zeros(seq.shape[0], bool)
    for reason, m in masks.items():  # count each frame once, under its first reason
        rep.defective_frames[reason] += int((m & ~bad).sum())
        bad |= m
    starts = window_starts(~bad, cfg.clip_len)
    rep.windows = len(starts)
    rep.frames_in_short_runs = int((~bad).sum()) - len(starts) * cfg.clip_len
    if not starts:
        empty = np.zeros((0, cfg.clip_len, 2, sk.NUM_JOINTS, 3), np.float32)
        return empty, np.zeros(0, np.int64), np.zeros((0, 2), np.float32), rep
    clips = np.stack([seq[s:s + cfg.clip_len] for s in starts]).astype(np.float32)
    inten = hand_intensity(clips, cfg)
    keep = keep_mask(inten, cfg)
    for i in np.flatnonzero(~keep):
        li, ri = inten[i]
        reason = ("left_below_tau_hand" if li < cfg.tau_hand else
                  "right_below_tau_hand" if ri < cfg.tau_hand else "mean_below_tau_avg")
        rep.rejected_intensity[reason] += 1
    rep.kept = int(keep.sum())
    return clips[keep], np.asarray(starts)[keep], inten[keep], rep
