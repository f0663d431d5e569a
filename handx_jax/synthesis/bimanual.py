"""Procedural two-hand motion corpus: FK hands (hand.py) driven by motion programs (programs.py).

A sequence is ``segments_per_sequence`` segments of 60 frames. Each segment runs one program: an
action for each hand (ACTIONS) and optionally a bimanual interaction (INTERACTIONS), or it is a
deliberately idle segment. Segments are joined by smooth transitions. Contact in an interaction
comes from the geometry: both hands are posed by FK, the contact points are computed on the posed
hands, and the left wrist is translated so they meet, with a gap schedule that lets the distance
come and go. Everything is vectorised over the chunk and over frames; the Python loops run over
segments, actions and interactions only.

Generation order per chunk (one rng, ``default_rng([seed, chunk_index])``):
programs → action channels → neighbour coupling → transitions → intensity floor → angle noise → FK
and wrist rotation → translations (placement, wrist noise, contact alignment, transitions) → global
pose → defects. The tracking-like noise is in the joint angles (before FK) and the wrist translation,
so bones stay rigid (issue 14.4).

One concern: a chunk's motion from its programs, stage by stage in the order above (one rng stream, so
the order is part of the generator's output and of GENERATOR_VERSION).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.dataset import clips
from handx_jax.synthesis import hand as H
from handx_jax.synthesis.surface import resolve_translations
from handx_jax.synthesis.programs import (ACTION_FNS, ACTIONS, CHAINED_ACTIONS, FREE_FINGERS, INTERACTION_SPECS,
                                          INTERACTIONS, NATURAL_ORIENTATION, ActionContext, Programs, sample_programs,
                                          CHAIN_MIDS_S, finger_ways, next_move, smoothstep)

# What a segment's actions do (SynthConfig.motion): corpora v1-v2, v3, v4 and v5. "surface" (corpus v5) is
# "chain" with the two hands resolved against the hand surface (synthesis/surface.py, issue 55).
MOTIONS = ("oscillate", "transition", "chain", "surface")
CHAIN_MOTIONS = ("chain", "surface")


# Bumped whenever the same (seed, SynthConfig) would give different motion; part of a corpus's recipe
# (its identity, dataset.check_compatible). 1: noise on joint positions after FK. 2: noise in the
# joint angles and wrist pose before FK, so bones stay rigid (issue 14.4). 3: FK in float64 (float32
# sin/cos differ by an ulp between numpy builds; see hand.hand_fk), issue 14.5. 4: the clip filter's angles
# and the annotation's features in float64 (same reason; dataset/clips.py, annotation/descriptors.py). The version
# covers the whole build (synthesis, clip filter, annotation): whatever changes a recipe's content.
GENERATOR_VERSION = 4


@dataclass(frozen=True)
class SynthConfig:
    chunk_size: int = 64                     # sequences per chunk
    segments_per_sequence: int = 4           # each segment is one program of segment_len frames
    segment_len: int = sk.CLIP_LEN
    fps: int = sk.FPS
    idle_prob: float = 0.08                  # near-static segments, for the intensity filter to drop
    interaction_prob: float = 0.5            # non-idle segments with a bimanual interaction
    defect_prob: float = 0.05                # sequences with a NaN run or a one-frame teleport
    # Tracking-like noise lives in the joint angles and the wrist pose, before FK, as in MANO fits:
    # bones keep their length within a sequence (issue 14.4). Abduction channels get half of it.
    noise_deg: float = 2.0                   # smooth noise on every pose channel, RMS degrees
    white_noise_deg: float = 0.1             # per-frame jitter on top; kept small, it reads as motion
    wrist_noise_m: float = 0.0015            # smooth noise on each wrist position, RMS metres
    white_noise_m: float = 0.00005           # per-frame wrist position jitter
    noise_knot_frames: int = 15              # correlation length of the smooth noise
    hand_scale_range: tuple[float, float] = (0.85, 1.15)
    bone_jitter: float = 0.03                # per-bone relative length variation within a person
    speed_range: tuple[float, float] = (0.75, 1.35)   # multiplies every action's frequency
    amplitude_range: tuple[float, float] = (0.7, 1.0)
    hyperextension_prob: float = 0.2         # open-hand actions that bend a finger back past −20°
    hand_separation_m: tuple[float, float] = (0.15, 0.40)  # wrist distance without interaction
    min_hand_gap_m: float = 0.06             # clearance kept between non-interacting hands
    transition_frames: int = 10              # ramp length on each side of a segment boundary
    min_intensity_dps: float = 40.0          # per-hand finger intensity a non-idle segment is raised to
    global_translation_m: float = 0.3        # random sequence offset (x, y) and height jitter
    # "oscillate" (corpora v1–v2): a segment's two-pose actions go back and forth. "transition" (corpus v3,
    # issue 40): each goes once from one pose to the other, at full amplitude, and no intensity top-up moves
    # the fingers an action leaves free; see programs.ActionContext.profile. "chain" (corpus v4): the
    # transition early in the clip, then two more moves to other poses (programs.next_move). "surface"
    # (corpus v5): "chain", then the wrists resolved against the hand surface (synthesis/surface.py).
    motion: str = "oscillate"

    def __post_init__(self):
        if self.motion not in MOTIONS:
            raise ValueError(f"SynthConfig.motion must be one of {', '.join(MOTIONS)}, not {self.motion!r}")
        if self.motion != "oscillate" and self.segments_per_sequence != 1:
            # The boundary blend between segments would put half of a pose change at each clip's edges.
            raise ValueError(f"SynthConfig.motion={self.motion!r} needs segments_per_sequence=1")


@dataclass
class SynthChunk:
    joints: np.ndarray              # float32 (chunk_size, T, 2, 21, 3); NaN where defects were injected
    programs: list[list[dict]]      # per sequence, per segment: left, right, interaction, idle



# ---- per-segment channels ----------------------------------------------------------------------
def _sample_orientation(rng: np.random.Generator, ranges: tuple, n: int) -> np.ndarray:
    lo, hi = np.array(ranges, dtype=np.float64).T
    return rng.uniform(lo, hi, (n, 3))


def _chain(rng: np.random.Generator, prog: Programs, pose: np.ndarray, s: int, t_L: np.ndarray,
           cfg: SynthConfig) -> None:
    """Corpus v4: every hand whose action made one move goes on twice more (programs.next_move), where its
    interaction lets it (``Interaction.chain_hands``: not out of a grip or pressed palms). A paired left hand
    makes the right hand's later moves too, shifted in time as its first ("alternate")."""
    a_Nx2 = prog.act_NxSx2[:, s]
    allowed_Ix2 = np.array([INTERACTION_SPECS[n].chain_hands for n in INTERACTIONS] + [(True, True)])
    paired = prog.pairing_NxS[:, s] > 0
    chain_Nx2 = np.isin(a_Nx2, [ACTIONS.index(a) for a in CHAINED_ACTIONS]) & allowed_Ix2[prog.inter_NxS[:, s]]
    own_Nx2 = chain_Nx2 & np.stack([~paired, np.ones_like(paired)], 1)  # a paired left hand follows its right
    seq, hand = np.nonzero(own_Nx2)
    if seq.size == 0:
        return
    sec = np.flatnonzero((hand == 1) & paired[seq] & chain_Nx2[seq, 0])
    held, ways = pose[seq, s, -1, hand], finger_ways(pose[seq, s, 0, hand], pose[seq, s, -1, hand])
    for m, mid_range in enumerate(CHAIN_MIDS_S[1:]):
        target, which, ways, mid, dur = next_move(rng, ways, held, mid_range, cfg)
        prog.then_NxSxMx2[seq, s, m, hand] = which
        prog.then_NxSxMx2[seq[sec], s, m, 0] = which[sec]
        for rows, side, shift in ((np.arange(seq.size), hand, np.zeros(seq.size)),
                                  (sec, 0, prog.offset_NxS[seq[sec], s])):
            s2 = smoothstep((t_L[None] + shift[:, None] - mid[rows, None]) / dur[rows, None] + 0.5)[..., None]
            q = seq[rows]
            pose[q, s, :, side] = pose[q, s, :, side] * (1.0 - s2) + target[rows, None] * s2
        held = target


def _segment_channels(rng: np.random.Generator, prog: Programs, cfg: SynthConfig):
    """Pose (N,S,L,2,16) and wrist rotation (N,S,L,2,3, degrees) and symmetric-frame position
    (N,S,L,2,3, metres) of every segment, before transitions. The left hand's channels are given in
    the mirrored frame, so equal channels mean mirror-symmetric hands."""
    N, S, L = cfg.chunk_size, cfg.segments_per_sequence, cfg.segment_len
    pose = np.empty((N, S, L, 2, H.NUM_CHANNELS))
    rot = np.zeros((N, S, L, 2, 3))
    pos = np.zeros((N, S, L, 2, 3))
    t_L = np.arange(L) / cfg.fps
    for s in range(S):
        a, paired = prog.act_NxSx2[:, s], prog.pairing_NxS[:, s] > 0
        for ai, name in enumerate(ACTIONS):
            prim = a == ai
            prim[:, 0] &= ~paired  # a paired left hand replays its right hand's draws below
            seq, hand = np.nonzero(prim)
            if seq.size == 0:
                continue
            sec = (hand == 1) & paired[seq]
            state = copy.deepcopy(rng) if sec.any() else None
            tt = np.broadcast_to(t_L, (seq.size, L))
            for arr, o in zip((pose, rot, pos), ACTION_FNS[name](ActionContext(rng, tt, cfg))):
                arr[seq, s, :, hand] = o
            if state is not None:  # same parameters, optionally shifted in time (alternating)
                out = ACTION_FNS[name](ActionContext(state, tt + prog.offset_NxS[seq, s][:, None], cfg))
                for arr, o in zip((pose, rot, pos), out):
                    arr[seq[sec], s, :, 0] = o[sec]
        if cfg.motion in CHAIN_MOTIONS:
            _chain(rng, prog, pose, s, t_L, cfg)
        _fill_idle(rng, prog, pose, s, cfg)
    # Pressed or clapping palms leave no room for curled fingers (they would meet first).
    flat = prog.flat_NxS[:, :, None, None, None]
    pose[..., H.MCP] = np.where(flat, np.minimum(pose[..., H.MCP], 0.0), pose[..., H.MCP])
    pose[..., H.PIP] = np.where(flat, np.minimum(pose[..., H.PIP], 5.0), pose[..., H.PIP])
    thumb = slice(H.T_CMC_FLEX, H.T_IP + 1)  # the thumb stays near the palm plane, beside its twin
    pose[..., thumb] = np.where(flat, np.minimum(pose[..., thumb], 0.0), pose[..., thumb])
    base_rot, base_pos = _segment_placement(rng, prog, cfg)
    rot += base_rot[:, :, None]
    pos += base_pos[:, :, None]
    _add_circling(rng, prog, pos, cfg)
    return pose, rot, pos


def _fill_idle(rng: np.random.Generator, prog: Programs, pose: np.ndarray, s: int, cfg: SynthConfig) -> None:
    """Near-static segments: hold a relaxed pose (or the previous idle hold) with a slight drift."""
    seq = np.flatnonzero(prog.idle_NxS[:, s])
    if seq.size == 0:
        return
    hold = H.RELAXED + rng.normal(0, 6, (seq.size, 2, H.NUM_CHANNELS))
    if s > 0:
        cont = prog.idle_NxS[seq, s - 1]
        hold[cont] = pose[seq[cont], s - 1, -1]
    t = np.arange(cfg.segment_len) / cfg.fps
    drift = 1.5 * np.sin(2 * np.pi * rng.uniform(0.1, 0.3, (seq.size, 1, 1, 1)) * t[:, None, None]
                         + rng.uniform(0, 2 * np.pi, (seq.size, 1, 2, H.NUM_CHANNELS)))
    drift -= drift[:, :1]  # starts exactly at the hold, so consecutive idle segments join seamlessly
    pose[seq, s] = hold[:, None] + drift


def _segment_placement(rng: np.random.Generator, prog: Programs, cfg: SynthConfig):
    """Wrist orientation (N,S,2,3) and symmetric-frame position (N,S,2,3) held through a segment."""
    N, S = cfg.chunk_size, cfg.segments_per_sequence
    rot = _sample_orientation(rng, NATURAL_ORIENTATION, N * S * 2).reshape(N, S, 2, 3)
    half = 0.5 * rng.uniform(*cfg.hand_separation_m, (N, S, 1)) + rng.uniform(-0.01, 0.01, (N, S, 2))
    pos = np.stack([half, rng.uniform(0.25, 0.40, (N, S, 2)), rng.uniform(-0.05, 0.08, (N, S, 2))], -1)
    for i, name in enumerate(INTERACTIONS):
        spec = INTERACTION_SPECS[name]
        m = prog.inter_NxS == i
        k = int(m.sum())
        if k == 0:
            continue
        r = _sample_orientation(rng, spec.orient_right, k)
        l = r if spec.orient_left is None else _sample_orientation(rng, spec.orient_left, k)
        rot[m] = np.stack([l, r], 1)
        pos[m, :, 0] = rng.uniform(*spec.half_sep, (k, 1))
    # Consecutive idle segments keep one placement, so nothing moves between them.
    for s in range(1, S):
        cont = prog.idle_NxS[:, s] & prog.idle_NxS[:, s - 1]
        rot[cont, s], pos[cont, s] = rot[cont, s - 1], pos[cont, s - 1]
    return rot, pos


def _add_circling(rng: np.random.Generator, prog: Programs, pos: np.ndarray, cfg: SynthConfig) -> None:
    """The "circle" interaction: the wrists orbit in the sagittal plane in antiphase (hands rolling over each other)."""
    n_idx, s_idx = np.nonzero(prog.inter_NxS == INTERACTIONS.index("circle"))
    if n_idx.size == 0:
        return
    t = np.arange(cfg.segment_len) / cfg.fps
    k = n_idx.size
    w = 2 * np.pi * rng.uniform(0.5, 1.1, (k, 1)) * rng.uniform(*cfg.speed_range, (k, 1))
    ph = rng.uniform(0, 2 * np.pi, (k, 1))
    radius = rng.uniform(0.04, 0.08, (k, 1, 1))
    for hand, shift in ((1, 0.0), (0, np.pi)):
        ang = w * t + ph + shift
        pos[n_idx, s_idx, :, hand, 1:] += radius * np.stack([np.cos(ang), np.sin(ang)], -1)


# ---- transitions and the intensity floor -------------------------------------------------------
def _blend_boundaries(x_NxSxLxD: np.ndarray, idle_NxS: np.ndarray, ramp: int) -> np.ndarray:
    """Make segments join smoothly: the jump at each boundary (beyond the local velocity) is spread
    over ``ramp`` frames on each side. Idle segments stay untouched (their neighbours absorb it),
    so that a near-static window stays near-static."""
    x = x_NxSxLxD.copy()
    S, L = x.shape[1], x.shape[2]
    i = np.arange(ramp)
    up = smoothstep((i + 1) / ramp)[:, None]             # prev segment: 0 → 1 at its last frame
    down = 1.0 - smoothstep(i / ramp)[:, None]           # next segment: 1 at its first frame → 0
    for s in range(1, S):
        prev, nxt = x[:, s - 1], x[:, s]
        v = 0.5 * ((prev[:, -1] - prev[:, -2]) + (nxt[:, 1] - nxt[:, 0]))
        d = nxt[:, 0] - prev[:, -1] - v
        w_prev = np.where(idle_NxS[:, s - 1], 0.0, np.where(idle_NxS[:, s], 1.0, 0.5))[:, None, None]
        prev[:, L - ramp:] += w_prev * d[:, None] * up
        nxt[:, :ramp] -= (1.0 - w_prev) * d[:, None] * down
    return x


def _hand_intensity_from_pose(pose_NxSxLx2x16: np.ndarray, fps: int) -> np.ndarray:
    """clips.hand_intensity of each segment, from the closed-form angles (no FK needed), (N,S,2)."""
    ang = H.interior_angles_from_pose(pose_NxSxLx2x16)
    lam = np.tile(np.asarray(clips.ClipConfig().weights, dtype=np.float64), 5)
    return (np.abs(np.diff(ang, axis=2)) * fps * lam).sum(-1).mean(2) / lam.sum()


def _raise_intensity(rng: np.random.Generator, pose: np.ndarray, prog: Programs, cfg: SynthConfig) -> np.ndarray:
    """Top up a hand whose fingers move too little in a non-idle segment.

    The deficit is filled by ONE coordinated gesture of the fingers the action leaves free (a
    pinching finger keeps its contact): they curl and release together, like a relaxed hand
    opening and closing, sharing one raised-cosine time profile with small per-finger differences —
    amplitude within ±12 % and a lag of up to 1.5/cycles frames per finger, a gentle wave from
    index to pinky or back. Independent per-finger wiggles would read as many unrelated finger events.
    When the action itself flexes the fingers (its mean flexion spans ≥ 15°), the profile is the
    action's own flexion rhythm, so the free fingers curl a little as the hand closes (sympathetic
    co-movement) and their events coincide with the action's; otherwise it is a raised cosine with
    a whole number of cycles, the fewest (1–3) that reach the floor within the amplitude limit.
    Either profile is zero at both ends (the action's is tapered over 8 frames), so it does not
    disturb the transitions; the lag is a time warp that vanishes at both ends. The amplitude is
    solved on the closed-form intensity: a linear first guess (per degree of MCP amplitude, PIP
    1.2×, DIP 0.8×, a finger adds |d profile/dt|·(9 + 3.6 + 0.8)/65 deg/s), then two secant steps.
    """
    L = cfg.segment_len
    omega0 = _hand_intensity_from_pose(pose, cfg.fps)
    need = (~prog.idle_NxS[..., None]) & (omega0 < cfg.min_intensity_dps)
    if not need.any():
        return pose
    n_i, s_i, h_i = np.nonzero(need)
    k = n_i.size
    free = np.stack([FREE_FINGERS[a] for a in ACTIONS])[prog.act_NxSx2[n_i, s_i, h_i]]          # (k, 4)
    k_free = np.maximum(free.sum(-1), 1)
    target = cfg.min_intensity_dps + 5.0
    deficit = target - omega0[n_i, s_i, h_i]
    gain1 = 2 * (cfg.fps / L) * 13.4 / 65 * k_free                       # deg/s per degree, one cycle
    # The fewest cycles that need at most 22° of MCP amplitude: below the 30° change an event
    # needs (events.FLEXING.delta), so the top-up rarely reads as finger events of its own.
    cycles = np.clip(np.ceil(deficit / (22.0 * gain1)), 1, 4)
    famp = rng.uniform(0.88, 1.12, (k, 4)) * free
    # Lag per finger (frames), smaller for faster rhythms: the wave spans < 0.1 cycle.
    lag = rng.uniform(0.0, 1.5, (k, 1)) / cycles[:, None] * np.where(rng.random((k, 1)) < 0.5, 1.0, -1.0)
    t = np.arange(L, dtype=np.float64)
    # Finger i runs the shared profile lag·(i − 1.5) frames late in the middle of the segment.
    warp = t[None, None] - lag[:, :, None] * (np.arange(4)[None, :, None] - 1.5) * np.sin(np.pi * t / L)
    osc = 0.5 - 0.5 * np.cos(2 * np.pi * cycles[:, None, None] * warp / L)                  # (k, 4, L)
    base = pose[n_i, s_i, :, h_i]                                                            # (k, L, 16)
    # Where the action itself flexes the fingers, the free ones follow ITS rhythm instead (they
    # curl a little as the hand closes, a sympathetic co-movement), tapered to zero at both ends.
    act = base[..., H.MCP].mean(-1) + base[..., H.PIP].mean(-1)                             # (k, L)
    span = act.max(1) - act.min(1)
    prof = (act - act.min(1, keepdims=True)) / np.maximum(span, 1e-6)[:, None]
    taper = smoothstep(t / 8.0) * smoothstep((L - 1 - t) / 8.0)
    w0 = np.clip(warp, 0, L - 1)
    i0 = np.floor(w0).astype(np.int64)
    i1 = np.minimum(i0 + 1, L - 1)
    rows = np.arange(k)[:, None, None]
    follow = (prof[rows, i0] * (1 - (w0 - i0)) + prof[rows, i1] * (w0 - i0)) * taper
    use = (span >= 15.0) & ~prog.flat_NxS[n_i, s_i]  # pressed palms: fingers only bend back
    osc = np.where(use[:, None, None], follow, osc)
    flat = prog.flat_NxS[n_i, s_i]
    sign = np.where((base[..., H.MCP].mean((1, 2)) <= 40) & ~flat, 1.0, -1.0)
    shape = np.swapaxes(osc * famp[..., None], 1, 2) * sign[:, None, None]                # (k, L, 4)

    def intensity(amp):
        p = base.copy()
        d = amp[:, None, None] * shape
        p[..., H.MCP] += d
        p[..., H.PIP] += 1.2 * d
        p = H.clip_to_limits(p)
        ang = H.interior_angles_from_pose(p)
        lam = np.tile(np.asarray(clips.ClipConfig().weights, dtype=np.float64), 5)
        return p, (np.abs(np.diff(ang, axis=1)) * cfg.fps * lam).sum(-1).mean(1) / lam.sum()

    om0 = omega0[n_i, s_i, h_i]
    # Linear first guess from the profile's mean rate: per degree of amplitude, each free finger
    # adds |d osc/dt|·(9 + 3.6 + 0.8)/65 deg/s.
    rate = np.abs(np.diff(osc, axis=2)).mean((1, 2)) * cfg.fps
    amp = np.clip(deficit / np.maximum(rate * 13.4 / 65 * k_free, 1e-3), 0.0, 45.0)
    for _ in range(2):
        p, om = intensity(amp)
        short = om < target - 1.0
        if not short.any():
            break
        slope = np.maximum((om - om0) / np.maximum(amp, 1e-6), 0.05 * rate * 13.4 / 65 * k_free)
        amp = np.where(short, np.clip(amp + (target - om) / slope, 0.0, 45.0), amp)
    p, _ = intensity(amp)
    pose = pose.copy()
    pose[n_i, s_i, :, h_i] = p
    return pose


# ---- kinematics and placement -----------------------------------------------------------------
def _rotation(ypr_deg: np.ndarray) -> np.ndarray:
    """Rz(yaw)·Rx(pitch)·Ry(roll), (..., 3, 3): roll about the hand's long axis, pitch lifts the
    fingers, yaw turns about the vertical. Positive roll turns a right palm toward −x (the left)."""
    y, p, r = np.moveaxis(np.radians(ypr_deg), -1, 0)
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    return np.stack([
        np.stack([cy * cr - sy * sp * sr, -sy * cp, cy * sr + sy * sp * cr], -1),
        np.stack([sy * cr + cy * sp * sr, cy * cp, sy * sr - cy * sp * cr], -1),
        np.stack([-cp * sr, sp, cp * cr], -1),
    ], -2)


@lru_cache(maxsize=8)
def _bspline_basis(T: int, knot_frames: int) -> np.ndarray:
    """Uniform cubic B-spline basis (T, K): smooth random curves as basis @ random coefficients."""
    K = T // knot_frames + 4
    u = np.arange(T)[:, None] / knot_frames - (np.arange(K)[None] - 2)
    a = np.abs(u)
    return np.where(a < 1, 2 / 3 - a ** 2 + a ** 3 / 2, np.where(a < 2, (2 - a) ** 3 / 6, 0.0))


def _smooth_noise(rng: np.random.Generator, shape: tuple, T: int, knot_frames: int, rms: float) -> np.ndarray:
    """(N, T, *shape) smooth noise with roughly the given RMS (cubic B-spline: std ≈ 0.69 × coef)."""
    B = _bspline_basis(T, knot_frames)
    coef = rng.normal(0, rms / 0.69, (shape[0], B.shape[1], int(np.prod(shape[1:]))))
    return np.matmul(B, coef).reshape((shape[0], T) + tuple(shape[1:]))


def _pose_noise(rng: np.random.Generator, N: int, T: int, cfg: SynthConfig) -> np.ndarray:
    """(N, T, 2, 16) tracking-like angle noise in degrees: smooth (B-spline) plus per-frame jitter.

    Noise on joint positions after FK (the generator before version 2) changed bone lengths by a
    median 6 % within a sequence; in the angles, FK keeps every bone rigid, as MANO-derived data does.
    """
    scale = np.ones(H.NUM_CHANNELS)
    scale[H.ABD] = 0.5  # abduction has a smaller range than flexion (and is tracked as such)
    smooth = _smooth_noise(rng, (N, 2, H.NUM_CHANNELS), T, cfg.noise_knot_frames, cfg.noise_deg)
    return (smooth + cfg.white_noise_deg * rng.standard_normal((N, T, 2, H.NUM_CHANNELS))) * scale


def _palm(J: np.ndarray, mirrored: bool, scale: np.ndarray):
    """Palm centroid, palm-side unit normal, and the palm surface point 1 cm out, each (..., 3)."""
    w, i, m, r, p = (J[..., j, :] for j in (0, 1, 4, 10, 7))
    n = np.cross(i - w, p - w) * (-1.0 if mirrored else 1.0)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    cen = (w + i + m + r + p) / 5
    return cen, n, cen + 0.01 * scale * n


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _grip_centre(J: np.ndarray) -> np.ndarray:
    """Centre of the cylinder a curled hand encloses: mean MCP–tip chord midpoint of index..ring."""
    return 0.5 * (J[..., [1, 4, 10], :] + J[..., [17, 18, 19], :]).mean(-2)


def _contact_points(kind: str, Jr: np.ndarray, Jl: np.ndarray, scale: np.ndarray):
    """Contact pairs (right (k,L,P,3), left (k,L,P,3)), separation direction (k,L,3) pointing from
    the right hand toward the left, and the distance each pair keeps at contact (k,P), for hands
    (k,L,21,3). The first pair is the intended contact point."""
    s, sc = scale[:, None, None], scale[:, None]
    _, nr, palm_r = _palm(Jr, False, s)
    _, _, palm_l = _palm(Jl, True, s)
    zero = np.zeros((Jr.shape[0], 1))
    if kind == "index_tips":
        return Jr[..., [17], :], Jl[..., [17], :], _unit(Jr[..., 17, :] - Jr[..., 3, :]), 0.004 * sc
    if kind == "palms":
        return palm_r[..., None, :], palm_l[..., None, :], nr, zero
    if kind == "tips_on_palm":
        return Jr[..., [17, 18], :], np.repeat(palm_l[..., None, :], 2, -2), nr, 0.003 * np.repeat(sc, 2, 1)
    if kind == "interlock":  # fingers interleave: offset half a finger across, palms a finger apart
        lat = _unit(Jl[..., 7, :] - Jl[..., 1, :])
        return palm_r[..., None, :], (palm_l + 0.009 * s * lat)[..., None, :], nr, 0.012 * sc
    if kind == "finger_in_hand":
        mid = 0.5 * (Jr[..., 2, :] + Jr[..., 3, :])
        return mid[..., None, :], _grip_centre(Jl)[..., None, :], _unit(Jr[..., 3, :] - Jr[..., 2, :]), zero
    if kind == "wrist_in_hand":
        return _grip_centre(Jr)[..., None, :], Jl[..., [0], :], nr, zero
    if kind == "all_tips":
        tips = list(sk.TIPS)
        return Jr[..., tips, :], Jl[..., tips, :], nr, 0.004 * np.repeat(sc, 5, 1)
    if kind == "knuckles":
        dr, dl = _unit(Jr[..., 4, :] - Jr[..., 0, :]), _unit(Jl[..., 4, :] - Jl[..., 0, :])
        kr = 0.5 * (Jr[..., 2, :] + Jr[..., 5, :]) + 0.008 * s * dr
        kl = 0.5 * (Jl[..., 2, :] + Jl[..., 5, :]) + 0.008 * s * dl
        return kr[..., None, :], kl[..., None, :], dr, zero
    raise ValueError(f"unknown contact kind {kind!r}")


def _gap_schedule(rng: np.random.Generator, kind: str, k: int, cfg: SynthConfig) -> np.ndarray:
    """Distance (k, L) added to the contact distance: 0 is touching; it comes and goes."""
    L = cfg.segment_len
    f = np.arange(L)[None]
    speed = rng.uniform(*cfg.speed_range, (k, 1))
    if kind in ("clap", "tap"):  # |sin| approaches fast and rebounds, with a brief dwell at contact
        hz = rng.uniform(1.2, 2.2, (k, 1)) if kind == "clap" else rng.uniform(1.5, 3.0, (k, 1))
        far = rng.uniform(0.08, 0.2, (k, 1)) if kind == "clap" else rng.uniform(0.015, 0.04, (k, 1))
        x = np.abs(np.sin(np.pi * hz * speed * f / cfg.fps + rng.uniform(0, np.pi, (k, 1))))
        return far * np.clip((x - 0.08) / 0.92, 0.0, 1.0)
    if kind == "touch":
        t_in, t_out, far = rng.uniform(-8, 22, (k, 1)), rng.uniform(38, 68, (k, 1)), rng.uniform(0.04, 0.12, (k, 1))
    else:  # grip: holds most of the segment
        t_in, t_out, far = rng.uniform(-15, 12, (k, 1)), rng.uniform(45, 80, (k, 1)), rng.uniform(0.03, 0.07, (k, 1))
    r = rng.uniform(6, 14, (k, 1)) / speed
    close = smoothstep((f - t_in + r) / r) * (1.0 - smoothstep((f - t_out) / r))
    return far * (1.0 - close)


# Distance kept between a joint and its mirror twin: about two finger half-thicknesses, except the
# tips, which (as in MANO skeletons) already lie on the finger surface.
_TWIN_REST_21 = np.where(np.isin(np.arange(sk.NUM_JOINTS), sk.TIPS), 0.004, 0.012)


def _align_contacts(rng, prog, J0, tr, scale, cfg) -> np.ndarray:
    """Translate the left wrist so that the interaction's contact points meet (plus the gap). Returns the gap
    schedule (N, S, L), m, NaN on segments without a contact program (corpus v5's contact stage reads it)."""
    gaps = np.full(J0.shape[:3], np.nan)
    for i, name in enumerate(INTERACTIONS):
        spec = INTERACTION_SPECS[name]
        n_idx, s_idx = np.nonzero(prog.inter_NxS == i)
        if spec.contact is None or n_idx.size == 0:
            continue
        Jr = J0[n_idx, s_idx, :, 1] + tr[n_idx, s_idx, :, 1, None]
        Jl = J0[n_idx, s_idx, :, 0]
        cr, cl, d, rest = _contact_points(spec.contact, Jr, Jl, scale[n_idx])
        gap = _gap_schedule(rng, spec.gap, n_idx.size, cfg)
        gaps[n_idx, s_idx] = gap
        diff = cr - cl                                                   # (k, L, P, 3)
        lateral = (diff - np.einsum("klpc,klc->klp", diff, d)[..., None] * d[..., None, :]).mean(2)
        lead = np.einsum("klpc,klc->klp", diff, d) + rest[:, None]
        if spec.pairing == "mirror" and spec.contact != "interlock":
            # Mirrored hands collide joint with joint (a curled finger meets its twin before the
            # palms touch), so corresponding joints also keep a finger's thickness apart.
            twin = np.einsum("kljc,klc->klj", Jr - Jl, d) + _TWIN_REST_21 * scale[n_idx, None, None]
            lead = np.concatenate([lead, twin], -1)
        # The closest pair touches: the left moves along d until its smallest lead equals the gap.
        move = (gap + lead.max(-1))[..., None] * d
        tr[n_idx, s_idx, :, 0] = lateral + move
    return gaps


def _separate_hands(prog, J0, tr, cfg) -> None:
    """Without contact, keep a clear gap along x between the hands over the whole segment."""
    free = ~np.isin(prog.inter_NxS, [i for i, n in enumerate(INTERACTIONS) if INTERACTION_SPECS[n].contact])
    right_min = (J0[..., 1, :, 0] + tr[..., 1, None, 0]).min(axis=(2, 3))
    left_max = (J0[..., 0, :, 0] + tr[..., 0, None, 0]).max(axis=(2, 3))
    shift = 0.5 * np.maximum(cfg.min_hand_gap_m - (right_min - left_max), 0.0) * free
    tr[..., 1, 0] += shift[:, :, None]
    tr[..., 0, 0] -= shift[:, :, None]


# ---- the chunk ----------------------------------------------------------------------------------
def _inject_defects(rng: np.random.Generator, joints: np.ndarray, cfg: SynthConfig) -> None:
    """A few sequences get a short NaN run or a one-frame teleport of one hand (a tracking glitch)."""
    N, T = joints.shape[:2]
    hit = np.flatnonzero(rng.random(N) < cfg.defect_prob)
    kind_nan = rng.random(hit.size) < 0.6
    length = rng.integers(1, 7, hit.size)
    start = rng.integers(1, T - 7, hit.size)
    hand = rng.integers(0, 2, hit.size)
    jump = _unit(rng.normal(0, 1, (hit.size, 3))) * rng.uniform(0.25, 0.5, (hit.size, 1))
    for n, nan, ln, st, h, j in zip(hit, kind_nan, length, start, hand, jump):
        if nan:
            joints[n, st:st + ln] = np.nan
        else:
            joints[n, st, h] += j


def synth_chunk(seed: int, chunk_index: int, cfg: SynthConfig = SynthConfig()) -> SynthChunk:
    """Generate ``cfg.chunk_size`` sequences of shape (T, 2, 21, 3), T = segments × segment_len.

    Deterministic in (seed, chunk_index, cfg); chunks are independent and can run in parallel.
    """
    rng = np.random.default_rng([seed, chunk_index])
    N, S, L = cfg.chunk_size, cfg.segments_per_sequence, cfg.segment_len
    T = S * L
    prog = sample_programs(rng, cfg)
    scale = rng.uniform(*cfg.hand_scale_range, N)
    geom = H.hand_geometry(scale, rng.uniform(-cfg.bone_jitter, cfg.bone_jitter, (N, 5, 3)))

    pose, rot, pos = _segment_channels(rng, prog, cfg)
    pose = H.couple_neighbours(pose)
    pose = _blend_boundaries(pose.reshape(N, S, L, -1), prog.idle_NxS, cfg.transition_frames).reshape(pose.shape)
    rot = _blend_boundaries(rot.reshape(N, S, L, -1), prog.idle_NxS, cfg.transition_frames).reshape(rot.shape)
    pose = H.clip_to_limits(pose)
    if cfg.motion == "oscillate":  # corpora v3-v4 add no incidental finger motion (the clip filter decides)
        pose = _raise_intensity(rng, pose, prog, cfg)

    # FK in each hand's frame, then wrist rotation (with a slow orientation drift), then mirroring
    # of the left hand: equal channels give mirror-symmetric hands about the x = 0 plane.
    rot = rot.reshape(N, T, 2, 3) + _smooth_noise(rng, (N, 2, 3), T, 20, 4.0)
    pose = H.clip_to_limits(pose.reshape(N, T, 2, -1) + _pose_noise(rng, N, T, cfg))
    g = {k: v.reshape((N, 1, 1) + v.shape[1:]) for k, v in geom.items()}
    local = H.hand_fk(pose, g)
    J0 = np.matmul(local, np.swapaxes(_rotation(rot), -1, -2))    # batched R·p for every joint
    J0[:, :, 0, :, 0] *= -1.0

    pos = pos + _smooth_noise(rng, (N, 1, 2, 3), T, 20, 0.01).reshape(N, S, L, 2, 3)
    # Wrist tracking noise (the hand moves as one rigid body; the finger noise is in the angles above).
    pos = pos + (_smooth_noise(rng, (N, 2, 3), T, cfg.noise_knot_frames, cfg.wrist_noise_m)
                 + cfg.white_noise_m * rng.standard_normal((N, T, 2, 3))).reshape(N, S, L, 2, 3)
    tr = pos * np.array([[-1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])          # symmetric frame → world
    J0 = J0.reshape(N, S, L, 2, sk.NUM_JOINTS, 3)
    _separate_hands(prog, J0, tr, cfg)
    gaps = _align_contacts(rng, prog, J0, tr, scale, cfg)
    if cfg.motion == "surface":  # corpus v5: contacts surface to surface, no hand through the other
        tr = resolve_translations(J0.reshape(N * S, L, 2, sk.NUM_JOINTS, 3), tr.reshape(N * S, L, 2, 3),
                                  gaps.reshape(N * S, L))[0].reshape(tr.shape)
    tr = _blend_boundaries(tr.reshape(N, S, L, -1), prog.idle_NxS, cfg.transition_frames).reshape(tr.shape)
    joints = (J0 + tr[..., None, :]).reshape(N, T, 2, sk.NUM_JOINTS, 3)

    # Per-sequence placement in the room: any heading, some offset (canonicalize undoes both).
    yaw = rng.uniform(-180, 180, N)
    Rg = _rotation(np.stack([yaw, np.zeros(N), np.zeros(N)], -1))
    off = np.concatenate([rng.uniform(-1, 1, (N, 2)) * cfg.global_translation_m, rng.uniform(-0.1, 0.3, (N, 1))], -1)
    joints = np.matmul(joints.reshape(N, -1, 3), np.swapaxes(Rg, -1, -2)).reshape(joints.shape)
    joints += off.reshape(N, 1, 1, 1, 3)

    _inject_defects(rng, joints, cfg)
    return SynthChunk(joints=joints.astype(np.float32), programs=prog.to_dicts())
