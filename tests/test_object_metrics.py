"""BimArt's hand -> object metrics (handx_jax/metrics/objects.py) against independent numpy code on random
cases and against known answers: a hand 1.5 cm inside a box is in Pen 1cm, a hand on the lid while it opens
counts for Art, a hand on the base does not."""

import itertools
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from handx_jax import objects as O
from handx_jax.metrics import objects as M
from tests.handmade_hands import right_hand

RNG = np.random.default_rng(3)
UPRIGHT = (math.pi / 2, 0.0, 0.0)  # canonical +y (the box's up) -> world +z


def test_frame_metrics_match_independent_loops():
    T, H = 40, 2
    near = RNG.uniform(-0.02, 0.03, size=(T, H, 2))
    moving, art = RNG.random(T) < 0.6, RNG.random(T) < 0.4
    pen1 = pen5 = depth = 0.0
    con_hits = art_hits = 0
    for t in range(T):
        deepest = max(0.0, max(-near[t, h, p] for h in range(H) for p in range(2)))
        pen1 += deepest > 0.01
        pen5 += deepest > 0.005
        depth += deepest
        con_hits += moving[t] and any(near[t, h, p] < 0.005 for h in range(H) for p in range(2))
        art_hits += art[t] and any(near[t, h, 0] < 0.005 for h in range(H))
    got = M.obj_penetration(near)
    assert got["obj_pen_1cm"] == pytest.approx(100 * pen1 / T) and got["obj_pen_5mm"] == pytest.approx(100 * pen5 / T)
    assert got["obj_pen_depth_m"] == pytest.approx(depth / T)
    assert M.obj_contact(near, moving) == pytest.approx(100 * con_hits / moving.sum())
    assert M.obj_articulation(near, art) == pytest.approx(100 * art_hits / art.sum())
    assert math.isnan(M.obj_contact(near, np.zeros(T, bool)))
    # Part contact F1 by counting cells.
    pred, true = M.part_contacts(near), RNG.random((T, H, 2)) < 0.3
    cells = list(zip(pred.ravel(), true.ravel()))
    tp = sum(p and t for p, t in cells)
    fp = sum(p and not t for p, t in cells)
    fn = sum(t and not p for p, t in cells)
    f = M.obj_part_contact_f1(pred, true)
    assert f["obj_part_f1"] == pytest.approx(2 * tp / (2 * tp + fp + fn))
    assert f["obj_part_precision"] == pytest.approx(tp / (tp + fp)) and f["obj_part_recall"] == pytest.approx(tp / (tp + fn))
    assert M.obj_part_contact_f1(true, true)["obj_part_f1"] == 1.0


def test_mul_accel_cm_match_independent_loops():
    S, T, H, P = 4, 6, 2, 5
    x = RNG.normal(size=(S, T, H, P, 3))
    pairs = [np.mean([np.linalg.norm(x[a, t, h, k] - x[b, t, h, k]) for t in range(T) for h in range(H)
                      for k in range(P)]) for a, b in itertools.combinations(range(S), 2)]
    assert M.obj_multimodality(x) == pytest.approx(np.mean(pairs))
    acc = np.mean([np.linalg.norm(x[0, t, h, k] - 2 * x[0, t - 1, h, k] + x[0, t - 2, h, k])
                   for t in range(2, T) for h in range(H) for k in range(P)])
    got = M.obj_accel(x[0])
    assert got["obj_accel_m_per_frame2"] == pytest.approx(acc) and got["obj_accel_m_s2"] == pytest.approx(acc * 900)
    # A constant-velocity motion has no acceleration; identical samples have no diversity.
    line = np.arange(T)[:, None, None, None] * np.ones((T, H, P, 3)) * 0.01
    assert M.obj_accel(line)["obj_accel_m_per_frame2"] == pytest.approx(0, abs=1e-12)
    assert M.obj_multimodality(np.stack([x[0]] * 3)) == 0.0
    a, b = RNG.random((T, 2, 2, 16)), RNG.random((T, 2, 2, 16))
    assert M.obj_cm_l1(a, b) == pytest.approx(np.abs(a - b).sum() / a.size)


def _big_box():
    return O.CATEGORIES["box"].build(dict(width=0.30, height=0.10, depth=0.24, lid_thickness=0.01))


def _np_box_sdf(q, half):
    d = np.abs(q) - half
    return np.linalg.norm(np.maximum(d, 0), axis=-1) + np.minimum(d.max(-1), 0)


def test_hand_part_distances_match_numpy_geometry():
    box = _big_box()
    T, P = 3, 573
    states = np.c_[RNG.uniform(0, 1.9, T), RNG.normal(size=(T, 3)), RNG.normal(size=(T, 3)) * 0.1]
    pts = RNG.normal(size=(T, 2, P, 3)) * 0.15 + states[:, None, None, 4:7]
    size, trans = np.asarray(box.size_Px3, float), np.asarray(box.trans_Px3, float)
    want = np.zeros((T, 2, 2))
    for t in range(T):
        Rg = Rotation.from_rotvec(states[t, 1:4]).as_matrix()
        a = states[t, 0]
        hinge = Rotation.from_rotvec([0, 0, -a]).as_matrix()
        for part, R in ((0, Rg @ hinge), (1, Rg)):
            q = (pts[t] - states[t, 4:7]) @ R  # world -> part canonical (rows times R = R^T x)
            want[t, :, part] = _np_box_sdf(q - trans[part], size[part]).min(-1)
    np.testing.assert_allclose(M.hand_part_distances(box, states, pts), want, atol=2e-6)


def test_known_answers_pen_and_contact():
    box = _big_box()
    state = np.r_[math.radians(110), UPRIGHT, 0, 0, 0]
    # A flat right hand palm-down over the open box's base (world z = 0 is the base's top face), its lowest
    # surface point 1.5 cm and 7 mm inside, 2 mm and 3 cm above; far (> 5 cm) from the other faces and the
    # raised lid. The left hand is 1 m away. Surface points move rigidly with the joints, so one evaluation
    # of the surface serves every height.
    j = right_hand() + np.array([-0.15, -0.09, 0.0])
    joints = np.stack([np.stack([j, j + np.array([0.0, 0.0, 1.0])])] * 4)
    pts0 = M.hand_points_from_joints(joints)
    heights = np.array([-0.015, -0.007, 0.002, 0.03])
    pts = pts0 + (heights - pts0[0, 0, :, 2].min())[:, None, None, None] * np.array([0, 0, 1.0])
    near = M.hand_part_distances(box, np.stack([state] * 4), pts)
    deepest = -near.min(axis=(1, 2))
    np.testing.assert_allclose(deepest, -heights, atol=1e-6)
    pen = M.obj_penetration(near)
    assert pen["obj_pen_1cm"] == 25.0 and pen["obj_pen_5mm"] == 50.0
    assert pen["obj_pen_depth_m"] == pytest.approx((0.015 + 0.007) / 4, abs=1e-6)
    # The object moves in every frame after the first: the hands within 5 mm are the first three.
    assert M.obj_contact(near, np.ones(4, bool)) == 75.0


def test_known_answers_articulation_while_opening():
    box = _big_box()
    T = 12
    states = np.c_[np.linspace(0.3, 1.3, T), np.tile(UPRIGHT, (T, 1)), np.zeros((T, 3))]
    lid, lid_n = (np.asarray(v) for v in O.surface_samples(box, O.TOP, 512, 0))
    base, base_n = (np.asarray(v) for v in O.surface_samples(box, O.BOTTOM, 512, 0))
    on_lid = lid[lid[:, 1] > 0.009] + 0.003 * lid_n[lid[:, 1] > 0.009]  # 3 mm above the lid's top face
    front = (base[:, 0] < -0.2999) & (base[:, 1] < -0.05)  # the base's front face, its lower half
    on_base = base[front] + 0.003 * base_n[front]
    k = min(len(on_lid), len(on_base))
    samples = np.stack([on_lid[:k], on_base[:k]])  # any object points serve to tell moving frames
    # The object's own points in the world, by the metric module's jitted transform (both parts in one call).
    world = np.asarray(M._object_points_world(O.anonymous(box), states.astype(np.float32),
                                              samples.astype(np.float32)))
    # Padded to the hands' 573 points by repeating the first (a min is unchanged): one compiled program
    # serves this test and the others.
    pad = lambda a: np.concatenate([a, np.repeat(a[:, :1], 573 - k, 1)], 1)
    pts_lid, pts_base = pad(world[:, :k]), pad(world[:, k:])
    moving, art = M.moving_frames(box, states, samples), M.articulating_frames(states)
    assert not moving[0] and moving[1:].all() and art[1:].all()
    resting_on_lid = M.hand_part_distances(box, states, np.stack([pts_lid, pts_base], 1))
    np.testing.assert_allclose(resting_on_lid[:, 0, 0], 0.003, atol=1e-5)
    assert M.obj_articulation(resting_on_lid, art) == 100.0 and M.obj_contact(resting_on_lid, moving) == 100.0
    # Only the hand on the base: it touches the moving object (Con) but not the opening lid (Art).
    on_base_only = M.hand_part_distances(box, states, np.stack([pts_base, pts_base + 1.0], 1))
    assert M.obj_articulation(on_base_only, art) == 0.0 and M.obj_contact(on_base_only, moving) == 100.0
    # A still object: nothing moves, Con is undefined; a grab (angle constant) has no articulating frame.
    still = np.tile(states[:1], (T, 1))
    assert not M.moving_frames(box, still, samples).any() and not M.articulating_frames(still).any()
    metrics = M.object_metrics(box, states, np.stack([pts_lid, pts_base], 1), samples,
                               true_contacts_TxHx2=M.part_contacts(resting_on_lid))
    assert metrics["obj_art"] == 100.0 and metrics["obj_part_f1"] == 1.0 and metrics["obj_pen_1cm"] == 0.0
