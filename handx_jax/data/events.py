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

import math
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Sequence

import numpy as np

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

    def __post_init__(self):
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

    def __post_init__(self):
        if not 0.5 < self.sign_ratio <= 1.0:
            raise ValueError("sign_ratio must lie in (0.5, 1]")


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
    lab = _labels(x, spec.state_edges) if spec.diff_state else None
    # Series that never move by delta cannot produce an event: skip their (i, j) tables.
    live = np.ones(S, bool) if spec.delta is None else (x.max(1) - x.min(1)) >= np.float32(spec.delta)
    live_idx = np.flatnonzero(live)
    ev_s, ev_i, ev_j = [], [], []
    for b in range(0, len(live_idx), block):
        idx = live_idx[b:b + block]
        bestj = _best_ends(x[idx], v[idx], None if lab is None else lab[idx], spec, ratio,
                           spec.speed_edges[0] if ignore_still else None)
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


def contact_runs(dist_SxT: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Maximal runs with distance < threshold: (series, start, end) with half-open [start, end)."""
    m = np.asarray(dist_SxT) < threshold
    d = np.diff(np.pad(m.astype(np.int8), ((0, 0), (1, 1))), axis=1)
    s0, st = np.nonzero(d == 1)
    _, en = np.nonzero(d == -1)
    return s0, st, en


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
    f = ft.compute_features(x, cfg.features)
    records = [_empty_record(T, cfg.fps) for _ in range(N)]
    if ids is not None:
        for r, cid in zip(records, ids):
            r["id"] = cid
    seg = lambda arr, spec: segment(arr, spec, fps=cfg.fps, sign_ratio=cfg.sign_ratio, block=cfg.scan_block,
                                    trim_fraction=cfg.trim_fraction, ignore_still=cfg.ignore_still)

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
    s, st, en = contact_runs(series(f.intra_tip_NxTx2x4), cfg.tip_contact_m)
    for s_, a, b in zip(s.tolist(), st.tolist(), en.tolist()):
        c, k = divmod(s_, 8)
        records[c][_HANDS_KEYS[k // 4]]["finger_tip_contact"].setdefault(_INTRA_KEYS[k % 4], []).append(
            {"start": a, "end": b, "state": "contact"})
    s, st, en = contact_runs(series(f.inter_tip_NxTx5x5), cfg.tip_contact_m)
    for s_, a, b in zip(s.tolist(), st.tolist(), en.tolist()):
        c, k = divmod(s_, 25)
        records[c]["two_hand_relationships"]["finger_tip_contact"].setdefault(_INTER_KEYS[k], []).append(
            {"start": a, "end": b, "state": "contact"})
    return records
