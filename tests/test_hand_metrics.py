"""G-HTT's MPJPE-RA / MPJPE-PA and APD, BimArt's inter-hand penetration and contact feasibility
(issue 33; handx_jax/metrics.py): known answers derived from the geometry, not from the code."""

import numpy as np
import pytest

import handmade_hands as hh
from handx_jax import hand_surface as hs
from handx_jax import metrics as M
from handx_jax import skeleton as sk


def _rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q  # a proper rotation


def _hands(T: int = 6) -> np.ndarray:
    """(1, T, 2, 21, 3): a bent, non-planar hand pair that moves from frame to frame."""
    h = hh.right_hand(bends={("index", 1): 40, ("middle", 2): 60, ("pinky", 3): 30})
    rng = np.random.default_rng(0)
    return hh.clip([hh.pair(hh.mirror(h), h) + rng.normal(0, 0.004, (2, 21, 3)) for _ in range(T)]).astype(np.float64)


def test_procrustes_copy_has_zero_pa_error_but_not_ra():
    gt = _hands()
    pred = np.empty_like(gt)
    for t in range(gt.shape[1]):  # its own rotation, scale and translation per frame and hand
        for h in range(2):
            R, s, c = _rotation(10 * t + h), 0.7 + 0.1 * t + 0.3 * h, np.array([0.1 * t, -0.2, 0.05 * h])
            pred[0, t, h] = s * gt[0, t, h] @ R.T + c
    pa, ra = np.asarray(M.mpjpe_pa_mm(pred, gt)), np.asarray(M.mpjpe_ra_mm(pred, gt))
    assert pa.shape == (1, 2) and np.all(pa < 1e-3)
    assert np.all(ra > 10.0)
    # A mirror image is not a similarity with a proper rotation: PA keeps an error.
    assert np.all(np.asarray(M.mpjpe_pa_mm(gt * np.array([-1.0, 1.0, 1.0]), gt)) > 1.0)


def test_root_aligned_error_known_values():
    gt = _hands()
    moved = gt + np.array([0.3, -0.1, 0.2])  # both hands translated: RA removes it, plain MPJPE does not
    assert np.all(np.asarray(M.mpjpe_ra_mm(moved, gt)) < 1e-3)
    assert np.asarray(M.mpjpe_mm(moved, gt))[0] == pytest.approx(1000 * np.linalg.norm([0.3, -0.1, 0.2]), rel=1e-5)
    # Left wrist moved by 7 mm: relative to it, the 20 other left joints are 7 mm off, the wrist itself 0.
    off = gt.copy()
    off[:, :, sk.LEFT, 0] += [0.0, 0.007, 0.0]
    ra = np.asarray(M.mpjpe_ra_mm(off, gt))[0]
    assert ra[0] == pytest.approx(20 / 21 * 7.0, rel=1e-4) and ra[1] < 1e-4


def test_apd_known_values():
    x = _hands().astype(np.float32)
    same = np.repeat(x[None], 4, 0)  # K = 4 identical samples
    np.testing.assert_allclose(M.apd_mm(same), 0.0, atol=1e-6)
    c = np.array([0.018, 0.0, -0.024], np.float32)  # |c| = 30 mm
    two = np.stack([x, x + c])
    np.testing.assert_allclose(M.apd_mm(two), [[30.0, 30.0]], rtol=1e-4)
    # Offsets 0, a, 2a on the right hand only: pair distances a, a, 2a → mean 4a/3; the left hand is 0.
    three = np.stack([x, x, x])
    three[1, ..., sk.RIGHT, :, :] += c
    three[2, ..., sk.RIGHT, :, :] += 2 * c
    np.testing.assert_allclose(M.apd_mm(three), [[0.0, 40.0]], atol=1e-3)
    with pytest.raises(ValueError):
        M.apd_mm(x[None])


def _flat_hands(dz_T) -> np.ndarray:
    """(1, T, 2, 21, 3): one flat hand shape (all joints at z = 0) for both hands, the second dz above."""
    h = hh.right_hand() * np.array([1.0, 1.0, 0.0])
    return hh.clip([np.stack([h, h + [0.0, 0.0, dz]]) for dz in dz_T])


def test_penetration_known_depths():
    # Hands 30 cm apart (handmade pair): no frame penetrates.
    depth = np.asarray(M.interhand_penetration(hh.still(T=8)))
    assert np.all(depth == 0.0)
    pen1, mean = M.penetration_stats(depth)
    assert pen1[0] == 0.0 and mean[0] == 0.0
    # Stacked flat hands dz apart: every left capsule axis is >= dz from every right one, and each palm
    # bone lies exactly dz above its copy, so the deepest overlap is 2 * palm radius - dz. dz = 6 mm gives
    # 20 mm in half the frames; 30 cm apart in the other half gives 0: Pen 1cm 50 %, mean depth 10 mm.
    r_palm = hs.PALM_RADIUS_M
    assert r_palm == pytest.approx(float(max(hs.CAPSULE_RADII_M)))
    dz = 2 * r_palm - 0.020
    depth = np.asarray(M.interhand_penetration(_flat_hands([dz, 0.3] * 5)))
    np.testing.assert_allclose(depth[0, ::2], 0.020, atol=1e-6)
    np.testing.assert_allclose(depth[0, 1::2], 0.0)
    pen1, mean = M.penetration_stats(depth)
    assert pen1[0] == pytest.approx(50.0) and mean[0] == pytest.approx(10.0, abs=1e-3)


def _touching_clip(T: int = 60) -> np.ndarray:
    """Handmade pair 30 cm apart, except frames 10–19 where the right hand is moved so that its index tip
    sits 5 mm from the left index tip (a contact under the 2 cm tip threshold)."""
    x = hh.still(T=T).astype(np.float64)
    li, ri = x[0, 0, sk.LEFT, sk.JOINT_INDEX["index_tip"]], x[0, 0, sk.RIGHT, sk.JOINT_INDEX["index_tip"]]
    x[0, 10:20, sk.RIGHT] += (li + [0.0, 0.0, 0.005]) - ri
    return x.astype(np.float32)


def test_contact_feasibility_one_realised_one_not():
    x = _touching_clip()
    contact = lambda s, e: [{"start": s, "end": e, "state": "contact"}]
    rec = {"frame_count": 60, "fps": 30, "left_hand_events": {}, "right_hand_events": {},
           "two_hand_relationships": {"finger_tip_contact": {"left_index_tip, right_index_tip": contact(10, 20),
                                                             "left_thumb_tip, right_thumb_tip": contact(30, 40)}}}
    named = M.named_contacts([rec])
    W = M.palm_barycentric()
    hit, n = M.contact_feasibility_counts(x, named, W)
    assert (hit[0], n[0]) == (1.0, 2.0)  # 0.5: the index tips meet, the thumbs never do
    # The same pair named for frames 30–39, where the hands are apart, is not realised: the range counts.
    rec["two_hand_relationships"]["finger_tip_contact"]["left_index_tip, right_index_tip"] = contact(30, 40)
    hit, n = M.contact_feasibility_counts(x, M.named_contacts([rec]), W)
    assert (hit[0], n[0]) == (0.0, 2.0)
    # Through the scoring path: G = 1 and G = 2 groups of this clip.
    out = M.replicate_motion_metrics(x[None], x, M.MetricConfig(bootstrap=20), named)
    assert out["contact_feasibility"][0] == pytest.approx(0.5)
    out = M.replicate_motion_metrics(np.stack([x, x]), x, M.MetricConfig(bootstrap=20), named)
    assert out["contact_feasibility"] == pytest.approx((0.5, 0.0)) and out["apd_left"][0] == pytest.approx(0.0)


def test_the_records_own_motion_realises_every_named_contact():
    """annotate's records name the contacts (tip–tip, and tip–palm through the finger–palm states);
    the motion they were read from realises all of them, and a motion without the touch realises none."""
    from handx_jax.annotation.events import annotate

    x = _touching_clip()
    # Frames 40–49: the left index tip pressed onto the centre of the right palm's cloud.
    W = M.palm_barycentric()
    centre = (W @ x[0, 45, sk.RIGHT]).mean(0)
    x[0, 40:50, sk.LEFT] += centre - x[0, 45, sk.LEFT, sk.JOINT_INDEX["index_tip"]]
    rec = annotate(x)[0]
    named = M.named_contacts([rec])
    keys = {k for k, i in M.CONTACT_CHANNELS.items() if i in set(named.channel_E.tolist())}
    assert ("finger_tip_contact", "left_index_tip, right_index_tip") in keys
    assert ("finger_palm_distance", "left_index_tip, right_palm") in keys
    hit, n = M.contact_feasibility_counts(x, named, W)
    assert n[0] >= 2 and hit[0] == n[0]
    apart = hh.still(T=60)
    hit, n = M.contact_feasibility_counts(apart, named, W)
    assert hit[0] == 0.0
