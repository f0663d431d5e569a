"""Known-answer tests for the kinematic descriptors (handx_jax/annotation/descriptors.py)."""

from __future__ import annotations

import numpy as np
import pytest

from handx_jax.annotation import descriptors as ft
from handx_jax.annotation.events import FLEXING
from handx_jax.annotation.segment import _labels
from handmade_hands import clip, mirror, pair, right_hand, still

FLEX = {n: i for i, n in enumerate(ft.FLEX_JOINTS)}


def _flex_deg(bends, hand=1):
    h = right_hand(bends)
    x = clip(pair(mirror(h), h)[None])
    return np.degrees(ft.finger_flexion(x)[0, 0, hand])


def test_straight_hand_has_zero_flexion_and_closed_spacing():
    x = still(T=2)
    assert np.allclose(ft.finger_flexion(x), 0.0, atol=1e-6)
    sp = np.degrees(ft.finger_spacing(x))
    assert np.all(sp < 20.0)


@pytest.mark.parametrize("hand", [0, 1])
def test_pip_bent_45_degrees_is_partially_bent(hand):
    deg = _flex_deg({("index", 2): 45.0}, hand)
    assert deg[FLEX["index_pip"]] == pytest.approx(45.0, abs=0.5)
    assert abs(deg[FLEX["index_mcp"]]) < 1e-3 and abs(deg[FLEX["middle_pip"]]) < 1e-3
    label = FLEXING.state_names[_labels(np.radians([deg[FLEX["index_pip"]]]), FLEXING.state_edges)[0]]
    assert label == "partially bent"


@pytest.mark.parametrize("hand", [0, 1])
def test_hyperextended_mcp_is_negative(hand):
    deg = _flex_deg({("middle", 1): -30.0}, hand)
    assert deg[FLEX["middle_mcp"]] == pytest.approx(-30.0, abs=0.5)
    label = FLEXING.state_names[_labels(np.radians([deg[FLEX["middle_mcp"]]]), FLEXING.state_edges)[0]]
    assert label == "hyper extend"


def test_dead_zone_zeroes_small_bends():
    deg = _flex_deg({("ring", 3): 8.0})
    assert deg[FLEX["ring_dip"]] == 0.0
    deg = _flex_deg({("ring", 3): 70.0})
    assert deg[FLEX["ring_dip"]] == pytest.approx(70.0, abs=0.5)


def test_spacing_of_spread_fingers():
    h = right_hand(spread_deg={"index": 15.0, "middle": 0.0, "ring": -10.0, "pinky": -35.0})
    sp = np.degrees(ft.finger_spacing(clip(pair(mirror(h), h)[None])))[0, 0, 1]
    assert sp == pytest.approx([15.0, 10.0, 25.0], abs=0.01)


def test_tip_distances_and_contact_frames():
    x = still(T=3).copy()
    # Frame 1: the left index tip 1 cm from the right thumb tip.
    x[0, 1, 0, 17] = x[0, 1, 1, 16] + [0.0, 0.0, 0.01]
    intra, inter = ft.tip_distances(x)
    assert inter[0, 1, 1, 0] == pytest.approx(0.01, abs=1e-6)  # left index (row 1) vs right thumb (col 0)
    assert intra.shape == (1, 3, 2, 4) and inter.shape == (1, 3, 5, 5)
    assert ft.contact_frames(x).tolist() == [[False, True, False]]


def test_contact_segments_stats():
    c = np.zeros((2, 60), bool)
    c[0, 10:40] = True  # one 1-s run
    c[1, 0:15] = True
    c[1, 45:60] = True  # two 0.5-s runs
    st = ft.contact_segments_stats(c, fps=30)
    assert st["ratio"] == pytest.approx(60 / 120)
    assert st["duration_s"] == pytest.approx(20 / 30)
    assert st["events_per_min"] == pytest.approx(3 / (4 / 60))


def test_palm_weights_fixed_and_inside_triangles():
    cfg = ft.FeatureConfig()
    W = ft.palm_weights(cfg)
    assert W.shape == (100, 21) and np.array_equal(W, ft.palm_weights(cfg))
    assert np.allclose(W.sum(1), 1.0, atol=1e-6) and (W >= 0).all()
    assert set(np.flatnonzero(W.any(0))) == {0, 1, 4, 7, 10, 13}


def _brute_palm(c_2xPx3, k=30):
    D = np.linalg.norm(c_2xPx3[1][None] - c_2xPx3[0][:, None], axis=-1).ravel()
    o = np.argsort(D)[:k]
    l, r = o // c_2xPx3.shape[1], o % c_2xPx3.shape[1]
    return D[o].mean(), (c_2xPx3[1][r] - c_2xPx3[0][l]).mean(0)


@pytest.mark.parametrize("gap", [0.15, 0.06, 0.0])
def test_palm_relation_matches_brute_force(gap):
    rng = np.random.default_rng(1)
    h = right_hand()
    frames = []
    for t in range(8):
        left = mirror(h) + rng.normal(0, 0.01, 3)
        right = h + [0, 0.02 * t, 0.01 * (t % 3)] + rng.normal(0, 0.01, 3)
        frames.append(pair(left, right, gap))
    x = clip(frames)
    clouds = ft.palm_clouds(x)
    d, v = ft.palm_relation(clouds)
    for t in range(8):
        bd, bv = _brute_palm(clouds[0, t].astype(np.float64))
        assert d[0, t] == pytest.approx(bd, abs=2e-4)
        assert np.allclose(v[0, t], bv, atol=2e-3)


def test_palm_relation_direction_and_centroid_option():
    x = still(T=1)  # right palm 30 cm to the right
    d, v = ft.palm_relation(ft.palm_clouds(x))
    assert v[0, 0, 0] > 0.2 and abs(v[0, 0, 1]) < 0.05 and abs(v[0, 0, 2]) < 0.01
    cfg = ft.FeatureConfig(palm_relation="centroid")
    dc, vc = ft.palm_relation(ft.palm_clouds(x, cfg), cfg)
    assert vc[0, 0, 0] == pytest.approx(0.30, abs=0.03)
    assert d[0, 0] > 0.2 and dc[0, 0] > 0.2


def test_finger_palm_distance_touching_tip():
    h = right_hand()
    left = mirror(h) + [-0.15, 0, 0]
    right = h + [0.15, 0, 0]
    W = ft.palm_weights()
    palm_left = W @ left
    # Put the right index tip 1 cm above (on the z axis) the left palm's centre.
    right[17] = palm_left.mean(0) + [0, 0, 0.01]
    x = clip(np.stack([left, right])[None])
    fp = ft.finger_palm_distance(x, ft.palm_clouds(x))
    assert fp.shape == (1, 1, 2, 5)
    assert 0.01 <= fp[0, 0, 1, 1] < 0.02  # near the 5 closest points, ≥ the 1 cm height
    assert fp[0, 0, 0].min() > 0.15


def test_compute_features_shapes_and_dtype():
    f = ft.compute_features(still(T=5))
    assert f.flexion_NxTx2x14.shape == (1, 5, 2, 14)
    assert f.spacing_NxTx2x3.shape == (1, 5, 2, 3)
    assert f.palm_vec_NxTx3.shape == (1, 5, 3)
    assert f.wrist_NxTx2x3.shape == (1, 5, 2, 3)
    assert all(a.dtype == np.float32 for a in vars(f).values())
    with pytest.raises(ValueError):
        ft.compute_features(np.zeros((5, 2, 21, 3)))


def test_descriptors_survive_an_ulp_change_in_float_kernels(monkeypatch):
    """Issue 14.5: numpy/BLAS builds differ in the last bit of arctan2, sqrt and GEMMs. The descriptors
    are computed in float64 and rounded to float32, so such a change leaves (almost) every descriptor
    bit-identical and the captions with them; computed in float32, it changed most of them (and one
    caption record in 2000 of a corpus)."""
    from handx_jax.synthesis import bimanual as synth

    class UlpNumpy:
        def __getattr__(self, name):
            return getattr(np, name)

        @staticmethod
        def arctan2(a, b):
            r = np.arctan2(a, b)
            return np.nextafter(r, np.asarray(np.inf, r.dtype))

        @staticmethod
        def sqrt(x):
            r = np.sqrt(x)
            return np.nextafter(r, np.asarray(np.inf, r.dtype))

        @staticmethod
        def matmul(a, b, *args, **kw):
            r = np.matmul(a, b, *args, **kw)
            return np.nextafter(r, np.asarray(-np.inf, r.dtype))

        @staticmethod
        def einsum(*args, **kw):
            r = np.einsum(*args, **kw)
            return np.nextafter(r, np.asarray(-np.inf, r.dtype))

    seq = synth.synth_chunk(1, 0, synth.SynthConfig(chunk_size=2, defect_prob=0.0)).joints
    clips = seq.reshape(-1, 60, 2, 21, 3)[:6]
    ref = ft.compute_features(clips)
    monkeypatch.setattr(ft, "np", UlpNumpy())
    moved = ft.compute_features(clips)
    monkeypatch.undo()
    for name in ref.__dataclass_fields__:
        a, b = getattr(ref, name), getattr(moved, name)
        assert a.dtype == np.float32
        assert np.mean(a != b) < 1e-3, f"{name}: {np.mean(a != b):.1%} of the values changed"
