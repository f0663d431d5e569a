"""The procedural corpus's motion library: what a segment can do. Time profiles, the per-instance random draws
of an action (``ActionContext``), the hand actions (``ACTIONS``: poses and how they move), the bimanual
interactions (``INTERACTIONS``: which actions, paired how, oriented and touching how), and the programs a
chunk's segments run (``sample_programs``). ``bimanual.py`` turns programs into motion; every draw here comes
from the chunk's one rng, in the order ``bimanual.synth_chunk`` calls them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from handx_jax.synthesis import hand as H

if TYPE_CHECKING:
    from handx_jax.synthesis.bimanual import SynthConfig


# ---- time profiles ---------------------------------------------------------------------------
def smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _plateau(t: np.ndarray, f: np.ndarray, phase: np.ndarray, sharp: float = 2.0) -> np.ndarray:
    """A 0..1 oscillation that dwells at both ends (holds a pose) and moves briskly in between."""
    return 0.5 + 0.5 * np.tanh(sharp * np.sin(2 * np.pi * f * t + phase)) / np.tanh(sharp)


class ActionContext:
    """Random draws for n action instances evaluated on the time grid t (n, L) in seconds."""

    def __init__(self, rng: np.random.Generator, t_nxL: np.ndarray, cfg: SynthConfig):
        self.rng, self.t, self.n, self.cfg = rng, t_nxL, t_nxL.shape[0], cfg

    def u(self, lo: float, hi: float, shape: tuple = ()) -> np.ndarray:
        return self.rng.uniform(lo, hi, (self.n,) + shape)

    def freq(self, lo: float, hi: float) -> np.ndarray:
        return (self.u(lo, hi) * self.u(*self.cfg.speed_range))[:, None]

    def phase(self) -> np.ndarray:
        return self.u(0, 2 * np.pi)[:, None]

    @property
    def transition(self) -> bool:
        """Corpus v3's motion (``SynthConfig.motion == "transition"``): a segment goes ONCE from one pose to
        another and holds, instead of oscillating between them (see ``profile``). Corpus v4's ``"chain"`` moves
        the same way, then twice more (``next_move``)."""
        return self.cfg.motion in ("transition", "chain", "surface")

    def amp(self) -> np.ndarray:
        if self.transition:  # a transition reaches its target pose: no partial swings near a threshold
            return np.ones((self.n, 1, 1))
        return self.u(*self.cfg.amplitude_range)[:, None, None]

    def profile(self, fr: tuple[float, float], sharp: float = 2.0) -> np.ndarray:
        """The (n, L) 0..1 time course of a two-pose action.

        ``oscillate`` (corpora v1–v2): back and forth with plateaus (``_plateau``).
        ``transition`` (corpus v3): one monotone smoothstep from 0 to 1, or from 1 to 0, centred in the middle
        of the segment and lasting 0.35–0.8 s (scaled by the speed draw), with holds on both sides. A clip then
        goes from one pose to another, so playing it backwards changes what it does ("closes into a fist"
        becomes "opens from a fist"), and every finger that acts moves the whole way, far more than one that
        does not: a gap the annotation's thresholds can sit in (issue 40, level-0 stability).
        """
        if not self.transition:
            return _plateau(self.t, self.freq(*fr), self.phase(), sharp)
        if self.cfg.motion in ("chain", "surface"):  # corpus v4 (and v5): the first of three moves (CHAIN_MIDS_S)
            dur = (self.u(*CHAIN_DURATION_S) / self.u(*self.cfg.speed_range))[:, None]
            mid = self.u(*CHAIN_MIDS_S[0])[:, None]
            dur = np.minimum(dur, 2.0 * (mid - CHAIN_EDGE_S))
        else:
            dur = (self.u(0.35, 0.8) / self.u(*self.cfg.speed_range))[:, None]
            mid = self.u(0.7, 1.3)[:, None]
        s = smoothstep((self.t - mid) / dur + 0.5)
        return np.where(self.rng.random(self.n)[:, None] < 0.5, s, 1.0 - s)

    def jitter(self, pose_16: np.ndarray, deg: float = 6.0) -> np.ndarray:
        """Per-instance variation of a reference pose; abduction varies less than flexion."""
        scale = np.full(H.NUM_CHANNELS, deg)
        scale[H.ABD] = deg / 3
        return pose_16 + self.rng.normal(0, 1, (self.n, H.NUM_CHANNELS)) * scale

    def hyperextend(self, pose_nx16: np.ndarray) -> np.ndarray:
        """Bend a random non-empty subset of fingers back past −20° at the MCP in some instances."""
        hit = self.rng.random(self.n) < self.cfg.hyperextension_prob
        fingers = self.rng.random((self.n, 4)) < 0.5
        fingers[np.arange(self.n), self.rng.integers(0, 4, self.n)] = True
        angle = self.u(-38, -23, (4,))
        out = pose_nx16.copy()
        out[:, H.MCP] = np.where(hit[:, None] & fingers, angle, out[:, H.MCP])
        return out

    def zeros(self) -> tuple[np.ndarray, np.ndarray]:
        z = np.zeros((self.n, self.t.shape[1], 3))
        return z, z.copy()

    def between(self, a_nx16: np.ndarray, b_nx16: np.ndarray, fr: tuple[float, float] = (0.5, 1.1),
                sharp: float = 2.0) -> np.ndarray:
        """Go back and forth between two poses with random rate, phase and amplitude."""
        s = self.profile(fr, sharp)[..., None] * self.amp()
        return a_nx16[:, None] + s * (b_nx16 - a_nx16)[:, None]


ActionOut = tuple[np.ndarray, np.ndarray, np.ndarray]  # pose (n,L,16) deg, rot (n,L,3) deg, pos (n,L,3) m


def _two_pose(a: Callable[[ActionContext], np.ndarray], b: Callable[[ActionContext], np.ndarray],
              fr: tuple[float, float] = (0.5, 1.1), sharp: float = 2.0) -> Callable[[ActionContext], ActionOut]:
    def action(c: ActionContext) -> ActionOut:
        return (c.between(a(c), b(c), fr, sharp), *c.zeros())
    return action


def _point_pose(c: ActionContext) -> np.ndarray:
    p = c.jitter(H.FIST, 5)
    p[:, 0], p[:, 4] = c.u(-8, 8), c.u(0, 10)  # index straight
    p[:, H.ABD.start] = H.ABD_CLOSED_4[0] + 6
    return p


def _thumbs_up_pose(c: ActionContext) -> np.ndarray:
    p = c.jitter(H.FIST, 5)
    p[:, H.T_CMC_FLEX:] = np.array([-12.0, 5.0, 0.0, -10.0]) + c.rng.normal(0, 4, (c.n, 4))
    return p


def _pinch_channels(finger: int) -> list[int]:
    """The channels a pinch with ``finger`` sets: that finger's MCP, PIP and abduction, and the thumb's."""
    return [finger, 4 + finger, 8 + finger, H.T_CMC_FLEX, H.T_CMC_ABD, H.T_MCP, H.T_IP]


def _pinch(finger: int, others_flat: bool = False) -> Callable[[ActionContext], ActionOut]:
    """Open hand ↔ thumb-tip on finger-tip; the contact channels are not jittered (geometry)."""
    def action(c: ActionContext) -> ActionOut:
        target = np.array(H.pinch_pose(finger, others_flat))
        b = c.jitter(target, 5)
        keep = _pinch_channels(finger)
        b[:, keep] = target[keep]
        a = c.hyperextend(c.jitter(H.SPREAD if others_flat else H.FLAT, 6))
        if others_flat or c.transition:
            # The OK sign keeps the other fingers up, and every corpus-v3 pinch keeps them where they are:
            # only the pinching finger and the thumb travel (no half curl of the others).
            others = [ch for f in range(4) if f != finger for ch in (f, 4 + f)]
            a[:, others] = b[:, others]
        return (c.between(a, b, (0.5, 1.0), 2.5), *c.zeros())
    return action


def _act_finger_tap(c: ActionContext) -> ActionOut:
    """Sequential tapping (index → pinky or back), like drumming on a table."""
    base = c.jitter(H.RELAXED, 5)
    period = 1.0 / c.freq(0.6, 1.2)                                        # (n, 1) seconds per sweep
    order = np.where(c.rng.random(c.n) < 0.5, 1.0, -1.0)[:, None, None] * np.arange(4) / 4
    ph = (c.t[..., None] / period[..., None] + order + c.u(0, 1)[:, None, None]) % 1.0   # (n, L, 4)
    pulse = np.sin(np.pi * np.clip(ph * 4.0, 0, 1)) ** 2                   # one tap per quarter sweep
    pose = np.repeat(base[:, None], c.t.shape[1], 1)
    # Corpus v3 taps deeper, so a tapping finger's curl swings clear of the incidental motion.
    mcp, pip = ((60, 75), (40, 55)) if c.transition else ((30, 50), (15, 30))
    pose[..., H.MCP] += pulse * c.u(*mcp, (1, 1)) * c.amp()
    pose[..., H.PIP] += pulse * c.u(*pip, (1, 1))
    return (pose, *c.zeros())


def _act_count(c: ActionContext) -> ActionOut:
    """Fingers extend one at a time from a fist (thumb or index first), then fold back."""
    fist = c.jitter(H.FIST, 4)
    open_ = c.jitter(H.SPREAD, 4)
    L = c.t.shape[1]
    start = c.u(0.05, 0.3)[:, None]
    step = c.u(0.15, 0.3)[:, None] / c.u(*c.cfg.speed_range)[:, None]
    thumb_first = c.rng.random(c.n) < 0.5
    rank = np.where(thumb_first[:, None], np.arange(5), np.array([4, 0, 1, 2, 3]))   # thumb, index..pinky
    t = c.t[..., None]
    ramp = step[..., None] * 0.8
    up = smoothstep((t - start[..., None] - rank[:, None] * step[..., None]) / ramp)
    if c.transition:  # corpus v3: one way only, extending from the fist or (played backwards) folding into it
        s = np.where((c.rng.random(c.n) < 0.5)[:, None, None], up, up[:, ::-1])      # (n, L, 5) extended 0..1
    else:
        s = up * (1 - smoothstep((t - (L / c.cfg.fps - 0.45)) / 0.35))     # then fold back near the end
    pose = np.repeat(fist[:, None], L, 1)
    fingers = s[..., 1:]
    for blk in (H.MCP, H.PIP, H.ABD):
        pose[..., blk] = fist[:, None, blk] + fingers * (open_ - fist)[:, None, blk]
    pose[..., H.T_CMC_FLEX:] = fist[:, None, H.T_CMC_FLEX:] + s[..., :1] * (open_ - fist)[:, None, H.T_CMC_FLEX:]
    return pose, *c.zeros()


def _act_wave(c: ActionContext) -> ActionOut:
    """Waving: side-to-side wrist swing with the fingers fluttering open and closed."""
    f, ph = c.freq(1.3, 2.2), c.phase()
    if c.transition:  # corpus v3: the wrist waves, the open fingers hold (no flutter near a threshold)
        pose = np.repeat(c.jitter(H.SPREAD, 5)[:, None], c.t.shape[1], 1)
    else:
        pose = c.between(c.jitter(H.SPREAD, 5), c.jitter(H.RELAXED, 5), (1.3, 2.2), 1.0)
    rot, pos = c.zeros()
    rot[..., 0] = c.u(18, 35)[:, None] * np.sin(2 * np.pi * f * c.t + ph)
    rot[..., 1] = c.u(20, 45)[:, None]                                       # hand raised
    pos[..., 0] = c.u(0.005, 0.02)[:, None] * np.sin(2 * np.pi * f * c.t + ph)
    return pose, rot, pos


def _act_wrist_roll(c: ActionContext) -> ActionOut:
    """Pronation/supination; the fingers open as the palm turns up (a natural presenting gesture)."""
    if c.transition:  # corpus v3: the palm turns once, up or down, and the flat fingers hold
        s = c.profile((0.5, 1.1))
        a = b = c.jitter(H.FLAT, 5)
    else:
        f, ph = c.freq(0.5, 1.1), c.phase()
        s = 0.5 - 0.5 * np.cos(2 * np.pi * f * c.t + ph)
        a, b = c.jitter(H.RELAXED, 5), c.hyperextend(c.jitter(H.FLAT, 5))
    pose = a[:, None] + (s[..., None] * c.amp()) * (b - a)[:, None]
    rot, pos = c.zeros()
    rot[..., 2] = c.u(50, 110)[:, None] * s
    return pose, rot, pos


def _act_wrist_flex(c: ActionContext) -> ActionOut:
    """Wrist flexion/extension with tenodesis: the fingers curl as the wrist extends."""
    if c.transition:  # corpus v3: the wrist bends once, one way
        w = 2.0 * c.profile((0.5, 1.2)) - 1.0
    else:
        f, ph = c.freq(0.5, 1.2), c.phase()
        w = np.sin(2 * np.pi * f * c.t + ph)
    a, b = c.jitter(H.FLAT, 5), c.jitter(H.base_pose(45, 55, 0.0, (20, 25, 15, 20)), 5)
    pose = a[:, None] + (0.5 + 0.5 * w)[..., None] * (b - a)[:, None]
    rot, pos = c.zeros()
    rot[..., 1] = c.u(25, 50)[:, None] * w
    return pose, rot, pos


def _act_finger_wiggle(c: ActionContext) -> ActionOut:
    """Independent finger flutter (piano fingers), each finger at its own rate."""
    base = c.jitter(H.RELAXED, 6)
    f = c.u(1.2, 2.6, (5,))[:, None] * c.u(*c.cfg.speed_range)[:, None, None]
    ph = c.u(0, 2 * np.pi, (5,))[:, None]
    w = np.sin(2 * np.pi * f * c.t[..., None] + ph)                          # (n, L, 5)
    pose = np.repeat(base[:, None], c.t.shape[1], 1)
    mcp, pip = ((25, 35), (20, 30)) if c.transition else ((15, 30), (10, 25))  # v3: swings clear of the noise
    pose[..., H.MCP] += c.u(*mcp, (1, 4)) * w[..., :4]
    pose[..., H.PIP] += c.u(*pip, (1, 4)) * w[..., :4]
    pose[..., H.T_MCP] += 15 * w[..., 4]
    return pose, *c.zeros()


def _hyper_pose(c: ActionContext) -> np.ndarray:
    p = c.jitter(H.FLAT, 3)
    # Corpus v3 bends back clear of the hyperextension state's hysteresis band (−20° ± 8°).
    p[:, H.MCP] = c.u(-40, -32, (4,)) if c.transition else c.u(-38, -22, (4,))
    p[:, H.PIP] = c.u(0, 6, (4,))
    return p


ACTION_FNS: dict[str, Callable[[ActionContext], ActionOut]] = {
    "fist": _two_pose(lambda c: c.jitter(H.RELAXED), lambda c: c.jitter(H.FIST, 4)),
    "open_spread": _two_pose(lambda c: c.jitter(H.FIST), lambda c: c.hyperextend(c.jitter(H.SPREAD, 4))),
    # Corpus v3 points from a flat hand, so the index finger holds and the others close the whole way.
    "point": _two_pose(lambda c: c.jitter(H.FLAT if c.transition else H.RELAXED), _point_pose, (0.4, 0.9), 2.5),
    "pinch_index": _pinch(0),
    "pinch_middle": _pinch(1),
    "pinch_ring": _pinch(2),
    "pinch_pinky": _pinch(3),
    # Corpus v3 spreads and closes straight fingers: abduction only, no half curl.
    "spread_close": _two_pose(lambda c: c.jitter(H.base_pose(0, 5, 0.0, (5, 15, 5, 5)) if c.transition
                                                 else H.base_pose(20, 20, 0.0, (5, 15, 5, 5))),
                              lambda c: c.hyperextend(c.jitter(H.SPREAD, 4)), (0.7, 1.5)),
    "wave": _act_wave,
    "finger_tap": _act_finger_tap,
    "count": _act_count,
    "wrist_roll": _act_wrist_roll,
    "wrist_flex": _act_wrist_flex,
    "grasp": _two_pose(lambda c: c.jitter(H.SPREAD), lambda c: c.jitter(H.GRASP, 5), (0.4, 0.9), 3.0),
    "thumbs_up": _two_pose(lambda c: c.jitter(H.RELAXED), _thumbs_up_pose, (0.4, 0.9), 2.5),
    "ok_sign": _pinch(0, others_flat=True),
    "claw": _two_pose(lambda c: c.jitter(H.FLAT), lambda c: c.jitter(H.CLAW, 5), (0.6, 1.2)),
    "finger_wiggle": _act_finger_wiggle,
    # Corpus v3 bends the fingers back from a flat hand: the MCPs move, the curl barely does.
    "hyperextend": _two_pose(lambda c: c.jitter(H.FLAT if c.transition else H.RELAXED), _hyper_pose, (0.5, 1.0)),
}
ACTIONS: tuple[str, ...] = tuple(ACTION_FNS)
# Fingers (0 = index … 3 = pinky) an action leaves free, which the intensity floor may move.
_FIXED_FINGERS = {"pinch_index": (0,), "pinch_middle": (1,), "pinch_ring": (2,), "pinch_pinky": (3,),
                  "ok_sign": (0,), "point": (0,)}
FREE_FINGERS = {a: np.array([f not in _FIXED_FINGERS.get(a, ()) for f in range(4)]) for a in ACTIONS}
_FINGER_ONLY = tuple(a for a in ACTIONS if a not in ("wave", "wrist_roll", "wrist_flex"))


# ---- corpus v4's later moves ("chain") --------------------------------------------------------
# A hand whose action makes one move early in the clip (every action but the rhythmic finger ones, which move all
# clip long) then goes on up to twice more, each time from where it holds to one of these poses: A → B → C → D.
# Moves in a row give the clip an order that reversal changes, and each finger's record more events (issue 40:
# corpus v3 held one move per hand, 35 events per clip against the reference corpus's 59). The poses are the
# actions' own end poses, drawn as the actions draw them.
_CHAIN_POSES: dict[str, Callable[[ActionContext], np.ndarray]] = {
    "flat": lambda c: c.jitter(H.FLAT), "spread": lambda c: c.jitter(H.SPREAD, 4),
    "fist": lambda c: c.jitter(H.FIST, 4), "claw": lambda c: c.jitter(H.CLAW, 5),
    "grasp": lambda c: c.jitter(H.GRASP, 5), "point": _point_pose, "thumbs_up": _thumbs_up_pose}
_PINCH_FINGERS = ("index", "middle", "ring", "pinky")
CHAIN_TARGETS: tuple[str, ...] = tuple(_CHAIN_POSES) + tuple(f"pinch_{f}" for f in _PINCH_FINGERS)
CHAINED_ACTIONS: tuple[str, ...] = tuple(a for a in ACTIONS if a not in ("finger_tap", "finger_wiggle", "count"))
# A finger's curl changes by under CHAIN_STILL_DEG or over CHAIN_MOVE_DEG in a later move, never in between:
# the gist's 20° swing threshold sits in the gap (the same gap corpus v3's first moves keep,
# docs/results/validity/corpus-v3/ranges.txt). A target that would put a finger in it is skipped.
CHAIN_STILL_DEG, CHAIN_MOVE_DEG = 12.0, 32.0
# Three moves in the 2 s clip: the action's own (``ActionContext.profile``), then two more, each a smoothstep of
# CHAIN_DURATION_S (scaled by the speed draw) centred in its window; none runs off the clip's edge.
CHAIN_MIDS_S: tuple[tuple[float, float], ...] = ((0.3, 0.5), (0.95, 1.1), (1.5, 1.65))
CHAIN_DURATION_S = (0.25, 0.45)
CHAIN_EDGE_S = 0.07


def curl_of_pose(pose_x16: np.ndarray) -> np.ndarray:
    """Each finger's whole curl (…, 4) in degrees from its pose channels: the mean flexion of MCP, PIP and DIP
    (DIP = 2/3 PIP), hyperextension counted as flexion, as the annotation's interior angles read it
    (events.finger_curl_deg). Coupling and noise move it by a few degrees."""
    return (np.abs(pose_x16[..., H.MCP]) + pose_x16[..., H.PIP] * (1.0 + H.DIP_PER_PIP)) / 3.0


def _chain_target(c: ActionContext, name: str, held_nx16: np.ndarray) -> np.ndarray:
    if name in _CHAIN_POSES:
        return _CHAIN_POSES[name](c)
    finger = _PINCH_FINGERS.index(name.removeprefix("pinch_"))  # only the pinching finger and the thumb travel
    b = c.jitter(np.array(H.pinch_pose(finger)), 5)
    out, keep = held_nx16.copy(), _pinch_channels(finger)
    out[:, keep] = b[:, keep]
    return out


def _add_way(ways_x4: np.ndarray, curl_change_x4: np.ndarray) -> np.ndarray:
    """The fingers' ways after one more move that changes their curl by ``curl_change_x4`` degrees: a finger
    travels when the change is over CHAIN_MOVE_DEG (+1 curling, −1 straightening); one that has travelled both
    ways reads 2."""
    step = np.where(np.abs(curl_change_x4) > CHAIN_MOVE_DEG, np.sign(curl_change_x4), 0).astype(np.int64)
    return np.where(step == 0, ways_x4, np.where((ways_x4 == 0) | (ways_x4 == step), step, 2))


def finger_ways(start_nx16: np.ndarray, held_nx16: np.ndarray) -> np.ndarray:
    """Which way each finger (n, 4) has travelled in a first move: +1 curled, −1 straightened, 0 stayed (a curl
    change under CHAIN_MOVE_DEG); ``next_move`` adds each later move (2: both ways)."""
    return _add_way(np.zeros(start_nx16.shape[:-1] + (4,), np.int64),
                    curl_of_pose(held_nx16) - curl_of_pose(start_nx16))


def next_move(rng: np.random.Generator, ways_nx4: np.ndarray, held_nx16: np.ndarray, mid_range: tuple[float, float],
              cfg: SynthConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Corpus v4's next move for n hands that hold ``held_nx16``, whose fingers have gone ``ways_nx4`` so far
    (``finger_ways``): the target pose (n, 16), its index into CHAIN_TARGETS (−1: none qualifies, and the hand
    holds), the fingers' ways after it, and the smoothstep's centre and duration (n,), in seconds, centred in
    ``mid_range`` and ending inside the clip.

    Targets are tried in a random order per hand; the first that qualifies is taken:
    - every finger either stays (curl change under CHAIN_STILL_DEG) or travels (over CHAIN_MOVE_DEG), and at
      least one travels: the gist's 20° threshold sits in the gap;
    - at least one finger has gone one way only (+1 or −1). A hand whose every moving finger goes and comes
      back ("curls, then straightens") reads the same played backwards; one such finger beside a one-way
      finger keeps the order visible."""
    n = held_nx16.shape[0]
    c = ActionContext(rng, np.zeros((n, 1)), cfg)
    cand_nxKx16 = np.stack([_chain_target(c, k, held_nx16) for k in CHAIN_TARGETS], 1)
    d_nxKx4 = curl_of_pose(H.clip_to_limits(cand_nxKx16)) - curl_of_pose(held_nx16)[:, None]
    a = np.abs(d_nxKx4)
    ways_nxKx4 = _add_way(ways_nx4[:, None], d_nxKx4)
    ok_nxK = (((a < CHAIN_STILL_DEG) | (a > CHAIN_MOVE_DEG)).all(-1) & (a > CHAIN_MOVE_DEG).any(-1)
              & (np.abs(ways_nxKx4) == 1).any(-1))
    order_nxK = rng.random((n, len(CHAIN_TARGETS))).argsort(1)
    ok_sorted = np.take_along_axis(ok_nxK, order_nxK, 1)
    first = np.where(ok_sorted.any(1), order_nxK[np.arange(n), ok_sorted.argmax(1)], -1)
    k = np.maximum(first, 0)
    target = np.where((first >= 0)[:, None], cand_nxKx16[np.arange(n), k], held_nx16)
    ways = np.where((first >= 0)[:, None], ways_nxKx4[np.arange(n), k], ways_nx4)
    dur = c.u(*CHAIN_DURATION_S) / c.u(*cfg.speed_range)
    mid = c.u(*mid_range)
    dur = np.minimum(dur, 2.0 * (cfg.segment_len / cfg.fps - CHAIN_EDGE_S - mid))  # the move ends in the clip
    return target, first, ways, mid, dur


# ---- interactions ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Interaction:
    right_actions: tuple[str, ...]
    left_actions: tuple[str, ...] | None     # None: the left hand repeats the right hand's action
    pairing: str                              # "mirror", "alternate" or "independent"
    orient_right: tuple[tuple[float, float], ...]  # (yaw, pitch, roll) ranges, degrees, symmetric frame
    orient_left: tuple[tuple[float, float], ...] | None  # None: mirror of the right hand's sample
    contact: str | None = None                # contact geometry (see bimanual._contact_points)
    gap: str | None = None                    # gap schedule (see bimanual._gap_schedule)
    half_sep: tuple[float, float] = (0.06, 0.12)
    flat_fingers: bool = False                # palms meet: fingers may spread or bend back, not curl
    # Corpus v4: which hands (left, right) may move on after their action (next_move). Contact that the hands' points
    # keep whatever the fingers do (tips, knuckles) allows it; a grip, interlocked fingers or pressed palms
    # would let go, so the hands that hold stay with their action.
    chain_hands: tuple[bool, bool] = (True, True)


NATURAL_ORIENTATION = ((-20.0, 25.0), (-20.0, 20.0), (-10.0, 60.0))
INTERACTION_SPECS: dict[str, Interaction] = {
    "fingertip_touch": Interaction(("point",), None, "mirror", ((75, 100), (-10, 15), (-20, 40)), None,
                                    "index_tips", "touch"),
    "palm_press": Interaction(("spread_close", "finger_wiggle", "hyperextend"), None, "mirror",
                               ((-10, 15), (50, 85), (80, 95)), None, "palms", "touch", flat_fingers=True,
                               chain_hands=(False, False)),
    "clap": Interaction(("spread_close", "finger_wiggle", "hyperextend"), None, "mirror",
                         ((-5, 20), (15, 60), (80, 95)), None, "palms", "clap", (0.10, 0.16), flat_fingers=True,
                         chain_hands=(False, False)),
    "tap_palm": Interaction(("finger_tap", "finger_wiggle"), ("spread_close", "finger_wiggle", "hyperextend"),
                             "independent", ((-15, 15), (-40, -20), (-10, 10)),
                             ((-10, 15), (-5, 15), (160, 185)), "tips_on_palm", "tap", chain_hands=(True, False)),
    "interlock": Interaction(("grasp", "fist", "claw"), None, "mirror", ((5, 30), (20, 50), (82, 95)), None,
                              "interlock", "grip", chain_hands=(False, False)),
    "grip_finger": Interaction(("point",), ("grasp", "fist"), "independent", ((75, 100), (-10, 10), (-15, 25)),
                                ((-15, 15), (-5, 15), (-10, 15)), "finger_in_hand", "grip", chain_hands=(False, False)),
    "grip_wrist": Interaction(("grasp", "fist"), _FINGER_ONLY, "independent", ((75, 100), (-15, 5), (-10, 10)),
                               ((-15, 15), (-10, 20), (-10, 30)), "wrist_in_hand", "grip", chain_hands=(True, False)),
    "steeple": Interaction(("claw", "spread_close", "finger_wiggle"), None, "mirror",
                            ((-5, 15), (55, 85), (65, 85)), None, "all_tips", "touch"),
    "fist_bump": Interaction(("fist", "thumbs_up"), None, "mirror", ((80, 100), (-10, 10), (-10, 30)), None,
                              "knuckles", "touch"),
    "circle": Interaction(_FINGER_ONLY, _FINGER_ONLY, "independent", NATURAL_ORIENTATION, NATURAL_ORIENTATION, None, None, (0.07, 0.12)),
    "mirrored": Interaction(ACTIONS, None, "mirror", NATURAL_ORIENTATION, None),
    "alternating": Interaction(ACTIONS, None, "alternate", NATURAL_ORIENTATION, None),
}
INTERACTIONS: tuple[str, ...] = tuple(INTERACTION_SPECS)
_PAIRING = {"independent": 0, "mirror": 1, "alternate": 2}


# ---- programs ----------------------------------------------------------------------------------
@dataclass
class Programs:
    idle_NxS: np.ndarray      # bool
    inter_NxS: np.ndarray     # index into INTERACTIONS, −1 for none
    act_NxSx2: np.ndarray     # index into ACTIONS per hand (left, right), −1 when idle
    pairing_NxS: np.ndarray   # _PAIRING code: left hand shares the right hand's action parameters
    offset_NxS: np.ndarray    # time offset (s) of the left hand in "alternate" pairing
    flat_NxS: np.ndarray      # bool: fingers must stay straight or bend back (palm contact)
    then_NxSxMx2: np.ndarray | None = None  # corpus v4: CHAIN_TARGETS index of each hand's later moves, −1: none

    def to_dicts(self) -> list[list[dict]]:
        out = []
        for n in range(self.idle_NxS.shape[0]):
            row = []
            for s in range(self.idle_NxS.shape[1]):
                idle, i = bool(self.idle_NxS[n, s]), int(self.inter_NxS[n, s])
                left, right = (ACTIONS[a] if a >= 0 else "idle" for a in self.act_NxSx2[n, s])
                seg = {"left": left, "right": right, "interaction": INTERACTIONS[i] if i >= 0 else None, "idle": idle}
                for side, k in (("left", 0), ("right", 1)) if self.then_NxSxMx2 is not None else ():
                    then = [CHAIN_TARGETS[i] for i in self.then_NxSxMx2[n, s, :, k] if i >= 0]
                    if then:
                        seg[f"{side}_then"] = ", ".join(then)
                row.append(seg)
            out.append(row)
        return out


def sample_programs(rng: np.random.Generator, cfg: SynthConfig) -> Programs:
    N, S = cfg.chunk_size, cfg.segments_per_sequence
    idle = rng.random((N, S)) < cfg.idle_prob
    inter = np.where(rng.random((N, S)) < cfg.interaction_prob, rng.integers(0, len(INTERACTIONS), (N, S)), -1)
    inter[idle] = -1
    act = rng.integers(0, len(ACTIONS), (N, S, 2))
    pairing = np.zeros((N, S), np.int64)
    for i, name in enumerate(INTERACTIONS):
        spec, m = INTERACTION_SPECS[name], inter == i
        k = int(m.sum())
        right = np.array([ACTIONS.index(a) for a in spec.right_actions])
        act[..., 1][m] = right[rng.integers(0, len(right), k)]
        if spec.left_actions is None:
            act[..., 0][m] = act[..., 1][m]
        else:
            left = np.array([ACTIONS.index(a) for a in spec.left_actions])
            act[..., 0][m] = left[rng.integers(0, len(left), k)]
        pairing[m] = _PAIRING[spec.pairing]
    act[idle] = -1
    offset = np.where(pairing == _PAIRING["alternate"], rng.uniform(0.25, 0.6, (N, S)), 0.0)
    flat_ids = [i for i, n in enumerate(INTERACTIONS) if INTERACTION_SPECS[n].flat_fingers]
    return Programs(idle, inter, act, pairing, offset, np.isin(inter, flat_ids),
                    np.full((N, S, len(CHAIN_MIDS_S) - 1, 2), -1))
