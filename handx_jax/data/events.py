"""Event segmentation of the kinematic descriptors and the per-clip structured record.

Reference §6.2 (``split_events``), §6.3 (JSON layout); paper App. B and Table A.

FRAME RANGES ARE HALF-OPEN everywhere in this module and in the records it writes: an event
``{"start": s, "end": e}`` covers frames s, s+1, …, e−1 (so ``end − start`` is its length in frames
and a whole-clip event is ``{"start": 0, "end": T}``). The reference writes contact runs with an
inclusive end; here they are half-open like every other event.

Segmentation of a series x_0 … x_{T−1} (one descriptor of one clip):

1. velocity v_t = (x_t − x_{t−1})·fps, v_0 = 0;
2. greedy scan from i = 0: the event starting at i ends at the LARGEST j (j ≤ T, j − i ≥
   ``min_duration``, T − j a multiple of ``unit_len``) such that |x_{j−1} − x_i| ≥ ``delta``, at
   least ``sign_ratio`` (80 %) of v[i:j] is ≥ 0 or at least 80 % is ≤ 0 (by default counted over
   the moving frames only, ``ignore_still``; see AnnotationConfig), and — for descriptors with
   states — the state labels of x_i and x_{j−1} differ. The event is emitted and the scan continues
   at i = j; if no j qualifies, i advances by ``unit_len``;
3. speed = interval label of |mean v| over the event; start/end states = labels of x_i and x_{j−1};
   the reported range is then trimmed of still frames at both ends (``trim_fraction``; 0 keeps the
   reference's [i, j));
4. a series with no event gets one constant event over the whole clip labelled with the state of
   mean(x) (descriptors without states, the wrist axes, get the state "still").

Contacts (finger–finger, within a hand and across hands) are the maximal runs with distance below
the contact threshold (Table A: [0, 0.02) m).

The scan is vectorised over all series of a batch: every (start i, end j) candidate of every
series is tested at once with prefix sums (the 80 % test is A[j] ≥ A[i] with A[k] = den·#{v ≥ 0 in
v[0:k]} − num·k for sign_ratio = num/den), the largest valid j per (series, i) is taken, and the
sequential scan is then ≤ T vector steps of table look-ups over all series together.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Sequence

import numpy as np
from scipy.ndimage import gaussian_filter1d

from handx_jax import skeleton as sk
from handx_jax.data import features as ft

AXES = ("left-right", "front-back", "down-up")  # world x, y, z of the canonical frame (A.2)
# Wrist direction names by axis and sign (reference §6.2): x+ left-to-right, y+ back-to-front, z+ down-to-up.
DIRECTIONS = {
    "left-right": ("right-to-left", "left-to-right"),
    "front-back": ("front-to-back", "back-to-front"),
    "down-up": ("up-to-down", "down-to-up"),
}
# Palm relative-position states per axis: where the RIGHT palm is relative to the LEFT palm (the
# relation vector points from left to right, paper App. B).
RELATIVE_STATES = {
    "left-right": ("left", "aligned", "right"),
    "front-back": ("behind", "aligned", "in front"),
    "down-up": ("below", "aligned", "above"),
}
SPEEDS = ("slow", "medium", "fast")


@dataclass(frozen=True)
class SegmentSpec:
    """Segmentation constants of one descriptor (reference §6.2 table; paper Table A).

    ``state_edges`` are the ascending interior bounds of the [lo, hi) state intervals and
    ``state_names`` their labels (one more than edges). No states means ``diff_state`` off.
    """

    state_edges: tuple[float, ...]
    state_names: tuple[str, ...]
    speed_edges: tuple[float, ...]
    delta: float | None
    min_duration: int
    unit_len: int = 1
    # Schmitt-trigger margin on the state edges (descriptor units; 0 = the reference's plain interval
    # look-up): a series labelled k moves to a neighbouring state only once it is past the shared
    # edge by this much, so a value hovering at an edge keeps one label (the "stable" annotation).
    hysteresis: float = 0.0

    def __post_init__(self):
        if self.hysteresis < 0:
            raise ValueError("hysteresis must be ≥ 0")
        if self.state_names and len(self.state_names) != len(self.state_edges) + 1:
            raise ValueError("state_names must have one more entry than state_edges")
        if len(self.speed_edges) != len(SPEEDS) - 1:
            raise ValueError("speed_edges must have two entries (slow | medium | fast)")
        if self.min_duration < 1 or self.unit_len < 1:
            raise ValueError("min_duration and unit_len must be ≥ 1")

    @property
    def diff_state(self) -> bool:
        return bool(self.state_names)


_D = math.pi / 180.0

# Finger flexing (rad): the paper's Table A bins, hyperextension below −20°; speeds (rad/s) and
# delta = π/6, min 6 frames, unit 1 from the reference (§6.2).
FLEXING = SegmentSpec((-20 * _D, 30 * _D, 60 * _D), ("hyper extend", "fully extend", "partially bent", "fully bent"),
                      (0.15, 1.3), math.pi / 6, 6, 1)
# Finger spacing (rad): closed [0, 20°), open ≥ 20°; delta π/10.
SPACING = SegmentSpec((20 * _D,), ("closed", "open"), (0.03, 1.3), math.pi / 10, 6, 1)
# Wrist trajectory per axis (m): no states; delta 3 cm, min 4 frames.
WRIST = SegmentSpec((), (), (0.03, 0.15), 0.03, 4, 1)
# Finger–palm distance (m): contact < 2.5 cm, near < 3.5 cm, far. The reference uses these constants
# for left tip → right palm and falls back to defaults (no delta, unit 6) for the other direction
# (§6.2); the paper treats both directions alike, and so do we.
FINGER_PALM = SegmentSpec((0.025, 0.035), ("contact", "near", "far"), (0.025, 0.07), 0.03, 6, 1)
# Palm–palm distance (m): contact < 4 cm, near < 8 cm, medium < 12 cm, far.
PALM_DIST = SegmentSpec((0.04, 0.08, 0.12), ("contact", "near", "medium", "far"), (0.025, 0.07), 0.05, 6, 1)


def _relative_spec(axis: str) -> SegmentSpec:
    # Palm relative position per axis: −/aligned/+ at ±2 cm; delta 5 cm, min 4 frames.
    return SegmentSpec((-0.02, 0.02), RELATIVE_STATES[axis], (0.025, 0.07), 0.05, 4, 1)


@dataclass(frozen=True)
class AnnotationConfig:
    """Everything the event record depends on. Defaults follow the paper where it speaks (Table A)
    and the reference code's constants elsewhere (§6.2)."""

    features: ft.FeatureConfig = field(default_factory=ft.FeatureConfig)
    fps: int = sk.FPS
    sign_ratio: float = 0.8
    flexing: SegmentSpec = FLEXING
    spacing: SegmentSpec = SPACING
    wrist: SegmentSpec = WRIST
    finger_palm: SegmentSpec = FINGER_PALM
    palm_distance: SegmentSpec = PALM_DIST
    palm_relative: tuple[SegmentSpec, SegmentSpec, SegmentSpec] = tuple(_relative_spec(a) for a in AXES)
    # Finger–finger contact threshold (Table A: contact is [0, 0.02) m), intra- and inter-hand.
    tip_contact_m: float = 0.02
    # Reported event ranges are trimmed to where the value changes by more than this fraction of
    # the descriptor's delta (our addition: the reference scan absorbs still frames at both ends of
    # an event, since zero velocity passes either sign test). 0 reproduces the reference ranges.
    # The scan itself and the state labels are unaffected; speed is measured on the trimmed range.
    trim_fraction: float = 0.1
    # Sign test over MOVING frames only (our reading of the paper's "detectable change"): frames
    # slower than the descriptor's "slow" speed edge count for neither sign. The reference counts a
    # zero velocity as both signs, so with exact holds (clean or synthetic motion) one event can
    # swallow a bend, the hold and part of the release. False reproduces the reference test.
    ignore_still: bool = True
    # Series processed per block of the vectorised scan (block × T² cells in memory).
    scan_block: int = 1024
    # --- The "stable" reading (issue 40; all off here, the reference's reading: no smoothing, §6.1) ---
    # Gaussian smoothing of the joints over time (σ in frames) before any descriptor is computed, so
    # velocities and state look-ups see the motion rather than frame-to-frame tracking noise.
    smooth_sigma_frames: float = 0.0
    # Contacts: a run starts below ``tip_contact_m`` and ends only above it plus this margin (m);
    # runs separated by at most ``contact_gap_frames`` frames merge, and runs shorter than
    # ``contact_min_frames`` are dropped (a one-frame graze under noise is not a touch).
    contact_hysteresis_m: float = 0.0
    contact_gap_frames: int = 0
    contact_min_frames: int = 1
    # "greedy": the reference's scan (§6.2) for every descriptor. "states": descriptors with states
    # are segmented by :func:`segment_states` (changes of the hysteretic state sequence; same-way
    # changes ≤ ``merge_gap_frames`` apart merge; ``state_delta`` keeps the delta test); the wrist,
    # which has no states, keeps the scan.
    segmentation: str = "greedy"
    merge_gap_frames: int = 10
    state_delta: bool = True

    def __post_init__(self):
        if self.segmentation not in ("greedy", "states"):
            raise ValueError(f"unknown segmentation {self.segmentation!r}; choose greedy or states")
        if not 0.5 < self.sign_ratio <= 1.0:
            raise ValueError("sign_ratio must lie in (0.5, 1]")
        if self.smooth_sigma_frames < 0 or self.contact_hysteresis_m < 0:
            raise ValueError("smooth_sigma_frames and contact_hysteresis_m must be ≥ 0")
        if self.contact_gap_frames < 0 or self.contact_min_frames < 1:
            raise ValueError("contact_gap_frames must be ≥ 0 and contact_min_frames ≥ 1")


# ---------------------------------------------------------------------------------------------
# Vectorised segmentation


@dataclass(frozen=True)
class _Events:
    """Events of a batch of series, sorted by (series, start); labels are indices."""

    series: np.ndarray
    start: np.ndarray
    end: np.ndarray
    start_state: np.ndarray
    end_state: np.ndarray
    speed: np.ndarray
    delta: np.ndarray  # x_{end−1} − x_start
    constant: np.ndarray  # bool: whole-clip constant event
    const_state: np.ndarray


def _labels(x: np.ndarray, edges: Sequence[float]) -> np.ndarray:
    return np.searchsorted(np.asarray(edges, dtype=np.float64), x, side="right").astype(np.int8)


def _hysteresis_labels(x_SxT: np.ndarray, edges: Sequence[float], h: float) -> np.ndarray:
    """State labels with a Schmitt trigger of margin ``h`` on every edge. A label k is kept while the
    value stays within [edge_{k-1} − h, edge_k + h); otherwise it becomes the state the value has
    clearly entered. A series STARTS in its first clearly-entered state (the first frame not within h
    of an edge): a clip that opens at an edge has no history to say which side it came from, and the
    plain label there would turn noise into a transition at frame 0. h = 0 gives the plain look-up."""
    e = np.asarray(edges, dtype=np.float64)
    if h <= 0 or not len(e):
        return _labels(x_SxT, edges)
    lo = np.searchsorted(e + h, x_SxT, side="right").astype(np.int8)  # lowest label the value allows
    hi = np.searchsorted(e - h, x_SxT, side="right").astype(np.int8)  # highest
    clear = lo == hi
    first = np.argmax(clear, axis=1)
    rows = np.arange(x_SxT.shape[0])
    cur = np.where(clear.any(1), lo[rows, first], _labels(x_SxT.mean(1), edges)).astype(np.int8)
    out = np.empty_like(lo)
    for t in range(x_SxT.shape[1]):
        cur = np.clip(cur, lo[:, t], hi[:, t])
        out[:, t] = cur
    return out


def _best_ends(x_SxT: np.ndarray, v_SxT: np.ndarray, lab_SxT: np.ndarray | None, spec: SegmentSpec,
               ratio: Fraction, still: float | None) -> np.ndarray:
    """``bestj[s, i]``: the largest valid end j for an event starting at i (0 where none).

    ``still is None``: reference sign test, ≥ ratio of v[i:j] is ≥ 0 (or ≤ 0), zeros counting for
    both. Otherwise frames with |v| < still count for neither sign and the ratio is taken over the
    moving frames of v[i:j] (at least one must move).
    """
    S, T = x_SxT.shape
    num, den = ratio.numerator, ratio.denominator
    ppos = np.zeros((S, T + 1), np.int32)
    pneg = np.zeros((S, T + 1), np.int32)
    if still is None:
        np.cumsum(v_SxT >= 0, axis=1, out=ppos[:, 1:])
        np.cumsum(v_SxT <= 0, axis=1, out=pneg[:, 1:])
        pall = np.broadcast_to(np.arange(T + 1, dtype=np.int32), (S, T + 1))
    else:
        np.cumsum(v_SxT >= still, axis=1, out=ppos[:, 1:])
        np.cumsum(v_SxT <= -still, axis=1, out=pneg[:, 1:])
        pall = ppos + pneg
    # "≥ num/den of the counted frames of v[i:j] are positive" ⟺ A[j] ≥ A[i].
    A = den * ppos - num * pall
    B = den * pneg - num * pall
    # Cells [s, i, e] with e = j − 1 ∈ [0, T).
    i_idx = np.arange(T)[:, None]
    e_idx = np.arange(T)[None, :]
    struct = ((e_idx + 1 - i_idx) >= spec.min_duration) & (((T - (e_idx + 1)) % spec.unit_len) == 0)
    ok = (A[:, None, 1:] >= A[:, :T, None]) | (B[:, None, 1:] >= B[:, :T, None])
    if still is not None:
        ok &= pall[:, None, 1:] > pall[:, :T, None]
    ok &= struct[None]
    if spec.delta is not None:
        ok &= np.abs(x_SxT[:, None, :] - x_SxT[:, :, None]) >= np.float32(spec.delta)
    if lab_SxT is not None:
        ok &= lab_SxT[:, None, :] != lab_SxT[:, :, None]
    rev = ok[:, :, ::-1]
    last = np.argmax(rev, axis=2)  # index from the end of the first True
    has = np.take_along_axis(rev, last[:, :, None], axis=2)[:, :, 0]
    return np.where(has, T - last, 0).astype(np.int32)


def _trim(x_SxT: np.ndarray, s_: np.ndarray, i_: np.ndarray, j_: np.ndarray,
          eps: float) -> tuple[np.ndarray, np.ndarray]:
    """Shrink each event [i, j) to where the value actually changes: drop leading frames that stay
    within ``eps`` of x_i (keeping the last of them, where the change starts) and trailing frames
    within ``eps`` of x_{j−1}."""
    T = x_SxT.shape[1]
    t = np.arange(T)[None, :]
    xs = x_SxT[s_]  # (E, T)
    inside = (t >= i_[:, None]) & (t < j_[:, None])
    a = xs[np.arange(len(s_)), i_][:, None]
    b = xs[np.arange(len(s_)), j_ - 1][:, None]
    moved_a = inside & (np.abs(xs - a) > eps)
    moved_b = inside & (np.abs(xs - b) > eps)
    first = np.where(moved_a.any(1), np.argmax(moved_a, 1) - 1, i_)
    last = np.where(moved_b.any(1), T - 1 - np.argmax(moved_b[:, ::-1], 1) + 2, j_)
    ni = np.clip(first, i_, j_ - 1)
    nj = np.clip(last, ni + 1, j_)
    return ni.astype(np.int64), nj.astype(np.int64)


def segment(x_SxT: np.ndarray, spec: SegmentSpec, *, fps: int = sk.FPS, sign_ratio: float = 0.8,
            block: int = 1024, trim_fraction: float = 0.0, ignore_still: bool = False) -> _Events:
    """Greedy event segmentation of S series at once (module docstring, reference §6.2)."""
    x = np.asarray(x_SxT, dtype=np.float32)
    S, T = x.shape
    ratio = Fraction(sign_ratio).limit_denominator(1000)
    v = np.zeros_like(x)
    v[:, 1:] = np.diff(x, axis=1) * fps
    lab = _hysteresis_labels(x, spec.state_edges, spec.hysteresis) if spec.diff_state else None
    still = spec.speed_edges[0] if ignore_still else None
    # Series that never move by delta cannot produce an event: skip their (i, j) tables.
    live = np.ones(S, bool) if spec.delta is None else (x.max(1) - x.min(1)) >= np.float32(spec.delta)
    live_idx = np.flatnonzero(live)
    ev_s, ev_i, ev_j = [], [], []
    for b in range(0, len(live_idx), block):
        idx = live_idx[b:b + block]
        bestj = _best_ends(x[idx], v[idx], None if lab is None else lab[idx], spec, ratio, still)
        n = len(idx)
        cur = np.zeros(n, np.int32)
        rows = np.arange(n)
        for _ in range(T + 1):  # each step advances every active series by ≥ 1 frame
            act = cur < T
            if not act.any():
                break
            r = rows[act]
            c = cur[act]
            j = bestj[r, c]
            hit = j > 0
            ev_s.append(idx[r[hit]])
            ev_i.append(c[hit])
            ev_j.append(j[hit])
            cur[r] = np.where(hit, j, c + spec.unit_len)
    s_ = np.concatenate(ev_s) if ev_s else np.zeros(0, np.int64)
    i_ = np.concatenate(ev_i).astype(np.int64) if ev_i else np.zeros(0, np.int64)
    j_ = np.concatenate(ev_j).astype(np.int64) if ev_j else np.zeros(0, np.int64)
    # States come from the scan's endpoints x_i and x_{j−1} (they differ by construction).
    st0 = lab[s_, i_] if lab is not None else np.zeros(len(s_), np.int8)
    st1 = lab[s_, j_ - 1] if lab is not None else np.zeros(len(s_), np.int8)
    if trim_fraction > 0 and len(s_) and spec.delta is not None:
        i_, j_ = _trim(x, s_, i_, j_, trim_fraction * spec.delta)
    cv = np.zeros((S, T + 1), np.float64)
    np.cumsum(v, axis=1, out=cv[:, 1:])
    mean_v = np.abs(cv[s_, j_] - cv[s_, i_]) / np.maximum(j_ - i_, 1)
    speed = _labels(mean_v, spec.speed_edges)
    dx = (x[s_, j_ - 1] - x[s_, i_]) if len(s_) else np.zeros(0, np.float32)
    # Constant events for series without any event.
    has_ev = np.zeros(S, bool)
    has_ev[s_] = True
    cs = np.flatnonzero(~has_ev)
    cstate = _labels(x[cs].mean(1), spec.state_edges) if spec.diff_state else np.zeros(len(cs), np.int8)
    series = np.concatenate([s_, cs])
    order = np.lexsort((np.concatenate([i_, np.zeros(len(cs), np.int64)]), series))
    cat = lambda a, fill: np.concatenate([a, np.full(len(cs), fill, dtype=np.asarray(a).dtype)])[order]
    return _Events(
        series=series[order],
        start=cat(i_, 0),
        end=cat(j_, T),
        start_state=cat(st0, 0),
        end_state=cat(st1, 0),
        speed=cat(speed, 0),
        delta=cat(dx.astype(np.float32), 0.0),
        constant=np.concatenate([np.zeros(len(s_), bool), np.ones(len(cs), bool)])[order],
        const_state=np.concatenate([np.zeros(len(s_), np.int8), cstate])[order],
    )


def segment_states(x_SxT: np.ndarray, spec: SegmentSpec, *, fps: int = sk.FPS, merge_gap: int = 10,
                   require_delta: bool = True) -> _Events:
    """The stable reading's segmentation of a descriptor WITH states: an event is a change of the
    hysteretic state sequence (Schmitt trigger of margin ``spec.hysteresis`` on Table A's edges).

    1. labels s_t (``_hysteresis_labels``); every t with s_t ≠ s_{t−1} is a change point;
    2. consecutive change points in the same direction at most ``merge_gap`` frames apart are one
       event (extended → partially bent → fully bent in one movement is one bend);
    3. the event spans the movement around its change points: back from the first and forward from
       the last while the velocity keeps the event's sign and exceeds the "slow" speed edge;
    4. with ``require_delta``, an event whose value changes by less than ``spec.delta`` over its span
       is dropped (the reference's detectability threshold, Table A);
    5. speed = label of |mean velocity| over the span; a series without events gets one constant
       event labelled by its mean, as in the reference.

    Every threshold here acts on a smoothed series through a margin, so noise well below the margin
    changes no label; the greedy scan of :func:`segment` instead searches the largest end j for
    every start i, and its sign-ratio, delta and state tests flip independently under noise.
    """
    x = np.asarray(x_SxT, dtype=np.float32)
    S, T = x.shape
    v = np.zeros_like(x)
    v[:, 1:] = np.diff(x, axis=1) * fps
    lab = _hysteresis_labels(x, spec.state_edges, spec.hysteresis)
    still = spec.speed_edges[0]
    # Runs of frames moving up (down): for each frame the first frame of its run and one past its last.
    up, down = v >= still, v <= -still
    def run_bounds(m):
        first = np.zeros((S, T), np.int64)
        last = np.zeros((S, T), np.int64)
        cur = np.zeros(S, np.int64)
        for t in range(T):
            cur = np.where(m[:, t] & (t > 0) & m[:, max(t - 1, 0)], cur, t)
            first[:, t] = cur
        cur = np.full(S, T, np.int64)
        for t in range(T - 1, -1, -1):
            cur = np.where(m[:, t] & (t < T - 1) & m[:, min(t + 1, T - 1)], cur, t + 1)
            last[:, t] = cur
        return first, last
    up_first, up_last = run_bounds(up)
    dn_first, dn_last = run_bounds(down)
    cs, ct = np.nonzero(lab[:, 1:] != lab[:, :-1])
    ct = ct + 1
    sgn = np.sign(lab[cs, ct].astype(np.int64) - lab[cs, ct - 1])
    # Merge same-direction change points of one series at most merge_gap apart.
    new = np.ones(len(cs), bool)
    if len(cs) > 1:
        same = (cs[1:] == cs[:-1]) & (sgn[1:] == sgn[:-1]) & (ct[1:] - ct[:-1] <= merge_gap)
        new[1:] = ~same
    gid = np.cumsum(new) - 1
    first_i = np.flatnonzero(new)
    last_i = np.r_[first_i[1:] - 1, len(cs) - 1] if len(cs) else first_i
    es, c0, c1, d = cs[first_i], ct[first_i], ct[last_i], sgn[first_i]
    # Span: the moving run (in the event's direction) around the first and the last change point;
    # at a change point that is not itself moving, the span starts one frame before it / ends there.
    pos = d > 0
    f0 = np.where(pos, up_first[es, c0], dn_first[es, c0])
    m0 = np.where(pos, up[es, c0], down[es, c0])
    i_ = np.where(m0, np.maximum(f0 - 1, 0), c0 - 1)
    l1 = np.where(pos, up_last[es, c1], dn_last[es, c1])
    m1 = np.where(pos, up[es, c1], down[es, c1])
    j_ = np.where(m1, l1, c1 + 1)
    j_ = np.minimum(j_, T)
    st0 = lab[es, c0 - 1]
    st1 = lab[es, c1]
    dx = x[es, j_ - 1] - x[es, i_] if len(es) else np.zeros(0, np.float32)
    keep = np.ones(len(es), bool)
    if require_delta and spec.delta is not None:
        keep = np.abs(dx) >= np.float32(spec.delta)
    # An earlier event's span may reach into the next one's: clip each start to the previous end.
    es, i_, j_, st0, st1, dx = es[keep], i_[keep], j_[keep], st0[keep], st1[keep], dx[keep]
    if len(es) > 1:
        prev_end = np.r_[0, j_[:-1]]
        same_s = np.r_[False, es[1:] == es[:-1]]
        i_ = np.where(same_s, np.maximum(i_, np.minimum(prev_end, j_ - 1)), i_)
    speed = _labels(_core_speed(x, es, i_, j_, dx, fps), spec.speed_edges)
    has_ev = np.zeros(S, bool)
    has_ev[es] = True
    cstate_s = np.flatnonzero(~has_ev)
    cstate = _labels(x[cstate_s].mean(1), spec.state_edges)
    series = np.concatenate([es, cstate_s])
    order = np.lexsort((np.concatenate([i_, np.zeros(len(cstate_s), np.int64)]), series))
    cat = lambda a, fill: np.concatenate([np.asarray(a), np.full(len(cstate_s), fill, dtype=np.asarray(a).dtype)])[order]
    return _Events(
        series=series[order], start=cat(i_.astype(np.int64), 0), end=cat(j_.astype(np.int64), T),
        start_state=cat(st0.astype(np.int8), 0), end_state=cat(st1.astype(np.int8), 0),
        speed=cat(speed, 0), delta=cat(dx.astype(np.float32), 0.0),
        constant=np.concatenate([np.zeros(len(es), bool), np.ones(len(cstate_s), bool)])[order],
        const_state=np.concatenate([np.zeros(len(es), np.int8), cstate.astype(np.int8)])[order],
    )


def _core_speed(x_SxT: np.ndarray, es: np.ndarray, i_: np.ndarray, j_: np.ndarray, dx: np.ndarray,
                fps: int) -> np.ndarray:
    """|mean velocity| of each event's core: 60 % of its change over the time between the (sub-frame,
    linearly interpolated) first crossings of 20 % and 80 % of the change. A linear ramp gives its own
    velocity, as the reference's |Δx| / duration does, but the span's ends, which move by a frame
    under noise, no longer enter; a 10-frame event measured over 10 ± 1 frames moves its speed by
    10 %, enough to flip a speed label at an edge."""
    if not len(es):
        return np.zeros(0)
    T = x_SxT.shape[1]
    xs = x_SxT[es].astype(np.float64)  # (E, T)
    t = np.arange(T)[None, :]
    inside = (t >= i_[:, None]) & (t < j_[:, None])
    d = np.where(np.abs(dx) > 1e-12, dx, 1e-12).astype(np.float64)
    q = (xs - xs[np.arange(len(es)), i_][:, None]) / d[:, None]
    rows = np.arange(len(es))

    def cross(level: float) -> np.ndarray:
        hit = inside & (q >= level)
        c = np.where(hit.any(1), np.argmax(hit, 1), j_ - 1)
        prev = np.maximum(c - 1, i_)
        q0, q1 = q[rows, prev], q[rows, c]
        frac = np.where((c > i_) & (q1 > q0), (level - q0) / np.where(q1 > q0, q1 - q0, 1.0), 0.0)
        return prev + np.clip(frac, 0.0, 1.0) * (c - prev)

    dur = np.maximum(cross(0.8) - cross(0.2), 0.5)
    return 0.6 * np.abs(dx.astype(np.float64)) / dur * fps


def contact_runs(dist_SxT: np.ndarray, threshold: float, *, hysteresis: float = 0.0, gap: int = 0,
                 min_frames: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Maximal runs with distance < threshold: (series, start, end) with half-open [start, end).

    With ``hysteresis`` a run, once started below ``threshold``, lasts while the distance stays
    below ``threshold + hysteresis``; runs at most ``gap`` frames apart merge; runs shorter than
    ``min_frames`` are dropped. The defaults are the reference's plain runs."""
    dist = np.asarray(dist_SxT)
    m = dist < threshold
    if hysteresis > 0:
        near = dist < threshold + hysteresis
        on = m[:, 0].copy()
        out = np.empty_like(m)
        out[:, 0] = on
        for t in range(1, m.shape[1]):
            on = m[:, t] | (on & near[:, t])
            out[:, t] = on
        m = out
    if gap > 0 or min_frames > 1:
        m = _close_runs(m, gap, min_frames)
    d = np.diff(np.pad(m.astype(np.int8), ((0, 0), (1, 1))), axis=1)
    s0, st = np.nonzero(d == 1)
    _, en = np.nonzero(d == -1)
    return s0, st, en


def _close_runs(m_SxT: np.ndarray, gap: int, min_frames: int) -> np.ndarray:
    """Fill interior gaps of at most ``gap`` frames between True runs, then drop runs shorter than
    ``min_frames``."""
    m = m_SxT.copy()
    S, T = m.shape
    d = np.diff(np.pad(m.astype(np.int8), ((0, 0), (1, 1))), axis=1)
    if gap > 0:
        for k in np.flatnonzero(m.any(1)):
            ends, starts = np.flatnonzero(d[k] == -1), np.flatnonzero(d[k] == 1)
            for e, s2 in zip(ends[:-1], starts[1:]):
                if s2 - e <= gap:
                    m[k, e:s2] = True
        d = np.diff(np.pad(m.astype(np.int8), ((0, 0), (1, 1))), axis=1)
    if min_frames > 1:
        s0, st = np.nonzero(d == 1)
        _, en = np.nonzero(d == -1)
        for k, a, b in zip(s0, st, en):
            if b - a < min_frames:
                m[k, a:b] = False
    return m


# ---------------------------------------------------------------------------------------------
# Record assembly (reference §6.3)

_HANDS_KEYS = ("left_hand_events", "right_hand_events")
_SPACING_KEYS = tuple(f"{a}, {b}" for a, b in ft.SPACING_PAIRS)
_INTRA_KEYS = tuple(f"{f}_tip, thumb_tip" for f in ft.INTRA_TIP_FINGERS)
_INTER_KEYS = tuple(f"left_{a}_tip, right_{b}_tip" for a in sk.FINGER_NAMES for b in sk.FINGER_NAMES)
_FP_KEYS = tuple(f"{h}_{f}_tip, {o}_palm" for h, o in (("left", "right"), ("right", "left")) for f in sk.FINGER_NAMES)


def _empty_record(T: int, fps: int) -> dict:
    rec: dict = {"frame_count": T, "fps": fps}
    for hk in _HANDS_KEYS:
        rec[hk] = {
            "finger_flexing": {j: [] for j in ft.FLEX_JOINTS},
            "finger_spacing": {k: [] for k in _SPACING_KEYS},
            "finger_tip_contact": {},
            "wrist_trajectory": {a: [] for a in AXES},
        }
    rec["two_hand_relationships"] = {
        "finger_tip_contact": {},
        "finger_palm_distance": {k: [] for k in _FP_KEYS},
        "palm_palm_distance": {"left_palm, right_palm": []},
        "palm_palm_relative_position": {a: [] for a in AXES},
    }
    return rec


def _emit(records: list[dict], ev: _Events, per_clip: int, spec: SegmentSpec,
          slot, *, direction: tuple[str, str] | None = None, still: str = "still") -> None:
    """Append the events of one descriptor group to the records; ``slot(k)`` gives the event list
    of within-clip series index k."""
    names = spec.state_names
    cols = (ev.series.tolist(), ev.start.tolist(), ev.end.tolist(), ev.start_state.tolist(),
            ev.end_state.tolist(), ev.speed.tolist(), ev.delta.tolist(), ev.constant.tolist(),
            ev.const_state.tolist())
    for s, i, j, a, b, sp, dx, const, cst in zip(*cols):
        c, k = divmod(s, per_clip)
        target = slot(records[c], k)
        if const:
            target.append({"start": i, "end": j, "state": names[cst] if names else still})
        elif direction is not None:
            target.append({"start": i, "end": j, "direction": direction[dx > 0],
                           "displacement_m": round(abs(dx), 3), "speed": SPEEDS[sp]})
        else:
            target.append({"start": i, "end": j, "start_state": names[a], "end_state": names[b],
                           "speed": SPEEDS[sp]})


def annotate(joints_NxTx2x21x3: np.ndarray, cfg: AnnotationConfig = AnnotationConfig(), *,
             ids: Sequence | None = None) -> list[dict]:
    """Structured event record (reference §6.3 layout) of every clip of a batch.

    Layout: ``frame_count``, ``fps``, ``left_hand_events`` / ``right_hand_events`` with
    ``finger_flexing`` (keyed by joint, e.g. ``index_pip``), ``finger_spacing`` (``"index, middle"``),
    ``finger_tip_contact`` (``"index_tip, thumb_tip"``; only pairs that touch), ``wrist_trajectory``
    (by axis); ``two_hand_relationships`` with ``finger_tip_contact`` (``"left_X_tip, right_Y_tip"``;
    only pairs that touch), ``finger_palm_distance``, ``palm_palm_distance`` and
    ``palm_palm_relative_position`` (by axis). Events are half-open ``[start, end)`` frame ranges:
    transitions ``{start, end, start_state, end_state, speed}``, wrist moves ``{start, end,
    direction, displacement_m, speed}``, constants ``{start, end, state}``, contacts
    ``{start, end, state: "contact"}``. With ``ids``, each record also carries ``"id"``.
    """
    x = ft._as_joints(joints_NxTx2x21x3)
    N, T = x.shape[:2]
    if ids is not None and len(ids) != N:
        raise ValueError(f"{N} clips but {len(ids)} ids")
    if cfg.smooth_sigma_frames > 0:
        # Denoise before differentiation (the stable reading): positions are smoothed over time,
        # clip by clip; "nearest" keeps the first and last frames' values at the clip borders.
        x = gaussian_filter1d(x, cfg.smooth_sigma_frames, axis=1, mode="nearest")
    f = ft.compute_features(x, cfg.features)
    records = [_empty_record(T, cfg.fps) for _ in range(N)]
    if ids is not None:
        for r, cid in zip(records, ids):
            r["id"] = cid
    def seg(arr, spec):
        if cfg.segmentation == "states" and spec.diff_state:
            return segment_states(arr, spec, fps=cfg.fps, merge_gap=cfg.merge_gap_frames,
                                  require_delta=cfg.state_delta)
        return segment(arr, spec, fps=cfg.fps, sign_ratio=cfg.sign_ratio, block=cfg.scan_block,
                       trim_fraction=cfg.trim_fraction, ignore_still=cfg.ignore_still)
    runs = lambda arr: contact_runs(arr, cfg.tip_contact_m, hysteresis=cfg.contact_hysteresis_m,
                                    gap=cfg.contact_gap_frames, min_frames=cfg.contact_min_frames)

    def series(a_NxTx_: np.ndarray) -> np.ndarray:  # (N, T, ...) → (N·K, T), clip-major
        return np.moveaxis(a_NxTx_.reshape(N, T, -1), 1, 2).reshape(-1, T)

    # Finger flexing: 2 hands × 14 joints.
    _emit(records, seg(series(f.flexion_NxTx2x14), cfg.flexing), 2 * ft.NUM_FLEX, cfg.flexing,
          lambda r, k: r[_HANDS_KEYS[k // ft.NUM_FLEX]]["finger_flexing"][ft.FLEX_JOINTS[k % ft.NUM_FLEX]])
    # Finger spacing: 2 hands × 3 pairs.
    _emit(records, seg(series(f.spacing_NxTx2x3), cfg.spacing), 6, cfg.spacing,
          lambda r, k: r[_HANDS_KEYS[k // 3]]["finger_spacing"][_SPACING_KEYS[k % 3]])
    # Wrist trajectory: 2 hands × 3 axes, direction names per axis.
    wr = seg(series(f.wrist_NxTx2x3), cfg.wrist)
    for a, axis in enumerate(AXES):  # one pass per axis so each gets its direction names
        sel = (wr.series % 3) == a
        sub = _Events(*(getattr(wr, n)[sel] for n in _Events.__dataclass_fields__))
        _emit(records, sub, 6, cfg.wrist,
              lambda r, k: r[_HANDS_KEYS[k // 3]]["wrist_trajectory"][AXES[k % 3]], direction=DIRECTIONS[axis])
    # Finger–palm distance: 2 directions × 5 tips.
    _emit(records, seg(series(f.finger_palm_NxTx2x5), cfg.finger_palm), 10, cfg.finger_palm,
          lambda r, k: r["two_hand_relationships"]["finger_palm_distance"][_FP_KEYS[k]])
    # Palm–palm distance.
    _emit(records, seg(f.palm_dist_NxT.reshape(N, T), cfg.palm_distance), 1, cfg.palm_distance,
          lambda r, k: r["two_hand_relationships"]["palm_palm_distance"]["left_palm, right_palm"])
    # Palm relative position: one spec per axis (the state names differ).
    for a, axis in enumerate(AXES):
        _emit(records, seg(f.palm_vec_NxTx3[..., a], cfg.palm_relative[a]), 1, cfg.palm_relative[a],
              lambda r, k, axis=axis: r["two_hand_relationships"]["palm_palm_relative_position"][axis])
    # Contacts: intra-hand thumb-tip pairs (2 × 4) and inter-hand tip pairs (25).
    s, st, en = runs(series(f.intra_tip_NxTx2x4))
    for s_, a, b in zip(s.tolist(), st.tolist(), en.tolist()):
        c, k = divmod(s_, 8)
        records[c][_HANDS_KEYS[k // 4]]["finger_tip_contact"].setdefault(_INTRA_KEYS[k % 4], []).append(
            {"start": a, "end": b, "state": "contact"})
    s, st, en = runs(series(f.inter_tip_NxTx5x5))
    for s_, a, b in zip(s.tolist(), st.tolist(), en.tolist()):
        c, k = divmod(s_, 25)
        records[c]["two_hand_relationships"]["finger_tip_contact"].setdefault(_INTER_KEYS[k], []).append(
            {"start": a, "end": b, "state": "contact"})
    return records


# ---------------------------------------------------------------------------------------------
# Named readings of the annotation (issue 40)


def _stable() -> AnnotationConfig:
    """The STABLE reading: the paper's descriptors and Table A states, computed so that a record
    describes the motion rather than its sensor-scale noise (issue 40). Measured on the standard
    corpus's test clips by the validity suite (``handx standard validity``; docs/results/validity/).

    - joints smoothed over time (Gaussian, σ 2 frames = 67 ms) before any descriptor: 1 mm of white
      noise per frame moves a DIP flexion angle by ~6° RMS per frame (the distal bone is ~2 cm), i.e.
      ~180°/s of velocity, far above every "slow" speed edge; after smoothing ~2.5°;
    - no 11° flexion dead zone: it maps 10.9° to 0 and 11.1° to 11.1°, turning noise at 11° into
      11° jumps; Table A's "fully extend" state (−20°…30°) already calls small bends straight;
    - descriptors with states are segmented by :func:`segment_states`: an event is a change of the
      state sequence under a Schmitt trigger (8° on angles, 3 mm on distances) instead of the greedy
      scan, whose sign-ratio, delta and state tests each flip under noise;
    - contacts end 3 mm above the 2 cm threshold they start under, gaps of ≤ 2 frames merge, and
      one-frame grazes are dropped.
    """
    deg = math.pi / 180.0
    h_ang, h_m = 8 * deg, 0.003
    return AnnotationConfig(
        features=ft.FeatureConfig(flex_dead_zone_deg=0.0, thumb_mcp="projected", dip_coupling=2.0 / 3.0),
        flexing=dataclasses.replace(FLEXING, hysteresis=h_ang),
        spacing=dataclasses.replace(SPACING, hysteresis=h_ang),
        wrist=WRIST,
        finger_palm=dataclasses.replace(FINGER_PALM, hysteresis=h_m),
        palm_distance=dataclasses.replace(PALM_DIST, hysteresis=h_m),
        palm_relative=tuple(dataclasses.replace(_relative_spec(a), hysteresis=h_m) for a in AXES),
        smooth_sigma_frames=2.0,
        contact_hysteresis_m=h_m,
        contact_gap_frames=2,
        contact_min_frames=2,
        segmentation="states",
    )


# "reference": the reference code's reading as this project has always annotated (no smoothing,
# reference §6.1–6.2, with the documented readings of AnnotationConfig's defaults); the default for
# imported official data and for every corpus built before issue 40. "stable": see _stable.
ANNOTATIONS: dict[str, AnnotationConfig] = {"reference": AnnotationConfig(), "stable": _stable()}


def annotation_config(name: str) -> AnnotationConfig:
    """The named reading of the annotation (``ANNOTATIONS``), or a one-line error listing them."""
    try:
        return ANNOTATIONS[name]
    except KeyError:
        raise ValueError(f"unknown annotation {name!r}; choose one of {', '.join(ANNOTATIONS)}") from None
