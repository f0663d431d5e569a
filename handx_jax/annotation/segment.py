"""Vectorised segmentation of descriptor series into events (reference §6.2; paper App. B, Table A).

FRAME RANGES ARE HALF-OPEN: an event ``{"start": s, "end": e}`` covers frames s, …, e−1.

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

from dataclasses import dataclass
from fractions import Fraction
from typing import Sequence

import numpy as np

from handx_jax import skeleton as sk

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


@dataclass(frozen=True)
class Events:
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
            block: int = 1024, trim_fraction: float = 0.0, ignore_still: bool = False) -> Events:
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
    return Events(
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
                   require_delta: bool = True) -> Events:
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
    return Events(
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




def swings(x_SxT: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The swings of at least ``threshold`` of every series: a zigzag whose reversal threshold is
    ``threshold`` (the "gist" reading's whole-finger curl, issue 40). Returns (series, start, end, direction
    +1 up / −1 down) with half-open frame ranges [start, end), sorted by series then start.

    A series starts undecided; its first swing begins at the extreme opposite to the first departure of at
    least ``threshold`` (the lowest frame so far for an upward swing). A swing runs on while the series keeps
    going its way and turns only once the series has come back by ``threshold`` from the swing's extreme;
    the swing then ends at that extreme (inclusive) and the next one starts there. So a monotone change
    is one swing whatever its noise, and a wobble smaller than ``threshold`` never starts or turns one.
    """
    x = np.asarray(x_SxT, np.float64)
    S, T = x.shape
    rows = np.arange(S)
    d = np.zeros(S, np.int8)
    hi, lo = x[:, 0].copy(), x[:, 0].copy()
    hi_t, lo_t = np.zeros(S, np.int64), np.zeros(S, np.int64)
    ext, ext_t = x[:, 0].copy(), np.zeros(S, np.int64)
    starts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []    # (series, start frame, direction)
    ends: list[tuple[np.ndarray, np.ndarray]] = []                  # (series, last frame) of finished swings
    for t in range(1, T):
        v = x[:, t]
        und = d == 0
        up_hi, dn_lo = und & (v > hi), und & (v < lo)
        hi, hi_t = np.where(up_hi, v, hi), np.where(up_hi, t, hi_t)
        lo, lo_t = np.where(dn_lo, v, lo), np.where(dn_lo, t, lo_t)
        begin = und & (hi - lo >= threshold)
        if begin.any():
            up = begin & (hi_t == t)
            dirn = np.where(up, 1, -1).astype(np.int8)
            starts.append((rows[begin], np.where(up, lo_t, hi_t)[begin], dirn[begin]))
            d = np.where(begin, dirn, d)
            ext, ext_t = np.where(begin, v, ext), np.where(begin, t, ext_t)
        going = ~und & ~begin
        further = going & ((v - ext) * d > 0)
        turn = going & ~further & (np.abs(ext - v) >= threshold)
        if turn.any():
            ends.append((rows[turn], ext_t[turn]))
            starts.append((rows[turn], ext_t[turn], (-d[turn]).astype(np.int8)))
            d = np.where(turn, -d, d)
        moved = further | turn
        ext, ext_t = np.where(moved, v, ext), np.where(moved, t, ext_t)
    live = d != 0
    ends.append((rows[live], ext_t[live]))
    if not starts:
        z = np.zeros(0, np.int64)
        return z, z, z, z
    s_s, s_t, s_d = (np.concatenate(a) for a in zip(*starts))
    e_s, e_t = (np.concatenate(a) for a in zip(*ends))
    o_s, o_e = np.lexsort((s_t, s_s)), np.lexsort((e_t, e_s))
    # Each series' swings end in order, one end per start, so the k-th start pairs with the k-th end.
    return s_s[o_s], s_t[o_s], e_t[o_e] + 1, s_d[o_s].astype(np.int64)
