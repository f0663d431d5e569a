"""Known-answer tests for event segmentation and the per-clip record (handx_jax/annotation/events.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from handx_jax.annotation import events as ev
from handmade_hands import clip, mirror, pair, right_hand, still


def _wrist_clip(speed_mps=0.3, start=20, stop=40, axis=0, T=60):
    frames = still(T=T)[0].copy()
    t = np.arange(T)
    off = np.clip(t - (start - 1), 0, stop - start) * speed_mps / 30.0  # moves on frames start..stop-1
    frames[:, 1, :, axis] += off[:, None]
    return clip(frames)


def test_constant_signal_gives_one_constant_event():
    out = ev.segment(np.full((3, 60), 0.7, np.float32), ev.FLEXING)
    assert out.series.tolist() == [0, 1, 2]
    assert out.constant.all() and out.start.tolist() == [0, 0, 0] and out.end.tolist() == [60] * 3
    assert ev.FLEXING.state_names[out.const_state[0]] == "partially bent"


def test_ramp_gives_one_transition_with_states_and_speed():
    x = np.zeros((1, 60), np.float32)
    x[0, 10:30] = np.linspace(0, np.pi / 2, 21)[1:]  # 0° → 90° over frames 10–29
    x[0, 30:] = np.pi / 2
    out = ev.segment(x, ev.FLEXING, trim_fraction=0.0, ignore_still=False)  # reference: holds absorbed
    assert (out.start.tolist(), out.end.tolist()) == ([0], [60])
    out = ev.segment(x, ev.FLEXING, trim_fraction=0.1, ignore_still=True)
    assert (out.start.tolist(), out.end.tolist()) == ([9], [30])
    assert ev.FLEXING.state_names[out.start_state[0]] == "fully extend"
    assert ev.FLEXING.state_names[out.end_state[0]] == "fully bent"
    assert ev.SPEEDS[out.speed[0]] == "fast"  # (π/2) / (21/30 s) = 2.2 rad/s ≥ 1.3


def test_bend_and_release_gives_two_events():
    x = np.zeros((1, 60), np.float32)
    x[0, 5:15] = np.linspace(0, 1.2, 11)[1:]
    x[0, 15:35] = 1.2
    x[0, 35:45] = np.linspace(1.2, 0, 11)[1:]
    out = ev.segment(x, ev.FLEXING, ignore_still=False)
    assert len(out.start) == 1  # the reference rule swallows the hold and half the release
    out = ev.segment(x, ev.FLEXING, trim_fraction=0.1, ignore_still=True)
    names = ev.FLEXING.state_names
    # Bend, then release. The 80 % rule lets the first event run two frames into the release
    # (10 of 12 moving frames still rise), so it ends "partially bent"; the release ends straight.
    assert len(out.start) == 2
    assert names[out.start_state[0]] == "fully extend" and names[out.end_state[0]] != "fully extend"
    assert names[out.end_state[1]] == "fully extend"
    assert out.start[0] == 4 and out.end[0] <= out.start[1] + 1 and out.end[1] == 45


def test_sign_consistency_is_vectorised_like_the_scalar_rule():
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(0, 0.15, (64, 60)), 1).astype(np.float32)
    out = ev.segment(x, ev.FLEXING, trim_fraction=0.0, ignore_still=False)
    # Scalar reimplementation of the reference scan (§6.2) for comparison.
    edges = np.asarray(ev.FLEXING.state_edges)
    for s in range(64):
        v = np.r_[0.0, np.diff(x[s].astype(np.float64)) * 30]
        lab = np.searchsorted(edges, x[s], side="right")
        i, got = 0, []
        while i < 60:
            found = None
            for j in range(60, i, -1):
                if j - i < 6:
                    break
                if abs(x[s, j - 1] - x[s, i]) < np.float32(np.pi / 6):
                    continue
                seg = v[i:j]
                if ((seg >= 0).sum() * 5 >= 4 * (j - i) or (seg <= 0).sum() * 5 >= 4 * (j - i)) and lab[i] != lab[j - 1]:
                    found = j
                    break
            if found is None:
                i += 1
            else:
                got.append((i, found))
                i = found
        mine = [(a, b) for q, a, b, c in zip(out.series, out.start, out.end, out.constant) if q == s and not c]
        assert mine == got, s


def test_contact_runs_are_half_open():
    d = np.full((2, 60), 0.05, np.float32)
    d[0, 12:20] = 0.01
    d[1, 0:3] = 0.015
    d[1, 50:60] = 0.0
    s, a, b = ev.contact_runs(d, 0.02)
    assert list(zip(s.tolist(), a.tolist(), b.tolist())) == [(0, 12, 20), (1, 0, 3), (1, 50, 60)]


def test_wrist_moving_right_fast():
    rec = ev.annotate(_wrist_clip(0.3, 20, 40))[0]
    lr = rec["right_hand_events"]["wrist_trajectory"]["left-right"]
    assert len(lr) == 1
    e = lr[0]
    assert e["direction"] == "left-to-right" and e["speed"] == "fast"
    assert (e["start"], e["end"]) == (19, 40)
    assert e["displacement_m"] == pytest.approx(0.2, abs=0.002)
    assert rec["right_hand_events"]["wrist_trajectory"]["down-up"] == [{"start": 0, "end": 60, "state": "still"}]
    assert rec["left_hand_events"]["wrist_trajectory"]["left-right"][0]["state"] == "still"


def test_wrist_moving_down_slowly_is_named_up_to_down():
    rec = ev.annotate(_wrist_clip(-0.06, 0, 60, axis=2))[0]
    e = rec["right_hand_events"]["wrist_trajectory"]["down-up"][0]
    assert e["direction"] == "up-to-down" and e["speed"] == "medium"


def test_record_layout_and_json():
    T = 60
    frames = []
    for t in range(T):
        bend = min(max((t - 10) * 4.5, 0.0), 90.0)
        h = right_hand({("index", 1): bend, ("index", 2): bend, ("index", 3): bend})
        frames.append(pair(mirror(right_hand()), h))
    x = clip(frames)
    # Left index tip touches the right thumb tip on frames 20–29.
    for t in range(20, 30):
        x[0, t, 0, 17] = x[0, t, 1, 16] + [0.005, 0, 0]
    rec = ev.annotate(x, ids=["clip-7"])[0]
    json.dumps(rec)
    assert rec["id"] == "clip-7" and rec["frame_count"] == 60
    assert set(rec) >= {"left_hand_events", "right_hand_events", "two_hand_relationships"}
    rh = rec["right_hand_events"]
    assert set(rh) == {"finger_flexing", "finger_spacing", "finger_tip_contact", "wrist_trajectory"}
    assert len(rh["finger_flexing"]) == 14 and "index_pip" in rh["finger_flexing"]
    assert set(rh["finger_spacing"]) == {"index, middle", "middle, ring", "ring, pinky"}
    assert set(rh["wrist_trajectory"]) == set(ev.AXES)
    pip = rh["finger_flexing"]["index_pip"]
    assert len(pip) == 1 and pip[0]["start_state"] == "fully extend" and pip[0]["end_state"] == "fully bent"
    assert 8 <= pip[0]["start"] <= 12 and 28 <= pip[0]["end"] <= 32
    assert rh["finger_flexing"]["middle_pip"] == [{"start": 0, "end": 60, "state": "fully extend"}]
    two = rec["two_hand_relationships"]
    assert two["finger_tip_contact"] == {"left_index_tip, right_thumb_tip": [{"start": 20, "end": 30, "state": "contact"}]}
    assert set(two) == {"finger_tip_contact", "finger_palm_distance", "palm_palm_distance", "palm_palm_relative_position"}
    assert len(two["finger_palm_distance"]) == 10
    rel = two["palm_palm_relative_position"]
    assert rel["left-right"] == [{"start": 0, "end": 60, "state": "right"}]
    assert two["palm_palm_distance"]["left_palm, right_palm"] == [{"start": 0, "end": 60, "state": "far"}]


def test_intra_hand_pinch_runs():
    x = still()
    x = x.copy()
    for t in list(range(5, 12)) + list(range(30, 40)):
        x[0, t, 0, 17] = x[0, t, 0, 16] + [0.0, 0.0, 0.008]
    rec = ev.annotate(x)[0]
    assert rec["left_hand_events"]["finger_tip_contact"] == {
        "index_tip, thumb_tip": [{"start": 5, "end": 12, "state": "contact"}, {"start": 30, "end": 40, "state": "contact"}]}
    assert rec["right_hand_events"]["finger_tip_contact"] == {}


def test_batch_equals_single_clips():
    a = _wrist_clip(0.3, 20, 40)
    b = _wrist_clip(-0.1, 0, 60, axis=1)
    both = ev.annotate(np.concatenate([a, b]))
    assert both == ev.annotate(a) + ev.annotate(b)
