"""The hand surface (handx_jax/hand_surface.py) against answers derived without it: closed-form segment
distances, a hand facing its own mirror image across a plane at a known gap, a half-space object at a known
depth, finite differences of the signed distances, and the sampled points' own capsules."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import handmade_hands as hh
from handx_jax import hand_surface as hs
from handx_jax import skeleton as sk


def test_segment_distance_closed_forms_and_brute_force():
    # Skew perpendicular segments crossing above each other at height 0.03; parallel, overlapping along x,
    # 0.02 apart; collinear with a gap of 0.5; a point against a segment. Then random segments: never above
    # the densely sampled minimum, and within its sampling error. One batched call (one compiled shape).
    closed = np.array([[[-1, 0, 0], [1, 0, 0], [0, -1, 0.03], [0, 1, 0.03]],
                       [[0, 0, 0], [1, 0, 0], [0.5, 0.02, 0], [2, 0.02, 0]],
                       [[0, 0, 0], [1, 0, 0], [1.5, 0, 0], [3, 0, 0]],
                       [[0, 0, 0], [0, 0, 0], [-1, 0.3, 0.4], [1, 0.3, 0.4]]])
    P = np.random.default_rng(1).normal(size=(40, 4, 3))
    allP = np.concatenate([closed, P]).astype(np.float32)
    d = np.asarray(hs.segment_distance(*(allP[:, i] for i in range(4))))
    np.testing.assert_allclose(d[:4], [0.03, 0.02, 0.5, 0.5], atol=1e-6)
    s = np.linspace(0, 1, 201)[None, :, None]
    a, b = P[:, None, 0] + s * (P[:, 1] - P[:, 0])[:, None], P[:, None, 2] + s * (P[:, 3] - P[:, 2])[:, None]
    brute = np.linalg.norm(a[:, :, None] - b[:, None], axis=-1).min((1, 2))
    assert np.all(d[4:] <= brute + 1e-5) and np.all(brute - d[4:] < 0.01)


def test_two_capsules_at_known_distance():
    # Radii 10 and 8 mm, axes crossing 12 mm apart: 6 mm deep; 25 mm apart: a 7 mm gap; end to end along one
    # line, the rounded caps are 0.1 − 0.01 − 0.008 apart.
    seg = np.array([[[-1, 0, 0], [1, 0, 0], [0, -1, 0.012], [0, 1, 0.012]],
                    [[-1, 0, 0], [1, 0, 0], [0, -1, 0.025], [0, 1, 0.025]],
                    [[0, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [0.5, 0, 0]]], np.float32)
    r1, r2 = np.float32(0.010), np.float32(0.008)
    sd = np.asarray(hs.capsule_signed_distance(seg[:, 0], seg[:, 1], r1, seg[:, 2], seg[:, 3], r2))
    np.testing.assert_allclose(sd, [-0.006, 0.007, 0.082], atol=1e-6)
    pen = np.asarray(hs.capsule_penetration(seg[:, 0], seg[:, 1], r1, seg[:, 2], seg[:, 3], r2))
    np.testing.assert_allclose(pen, [0.006, 0.0, 0.0], atol=1e-6)


def _posed_right_hand() -> np.ndarray:
    """A right hand with the index flexed 90° at the PIP (its middle phalanx along the palm normal: the
    surface frame's fallback) and other bends, turned by a fixed rotation and moved off the origin."""
    h = hh.right_hand(bends={("index", 2): 90, ("middle", 1): 40, ("middle", 2): 50, ("pinky", 3): 30},
                      spread_deg={"ring": -8})
    a, b = 0.7, -0.4
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return h @ (Rz @ Rx).T + [0.1, -0.2, 0.3]


def _point_to_segment(x, p, q) -> np.ndarray:
    d = q - p
    t = np.clip(np.sum((x - p) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-18), 0, 1)
    return np.linalg.norm(x - (p + t[..., None] * d), axis=-1)


def test_surface_points_lie_on_their_capsules_with_outward_unit_normals():
    x = _posed_right_hand()
    pts, nrm = (np.asarray(a, np.float64) for a in hs.surface_points(jnp.asarray(x, jnp.float32)))
    assert pts.shape == nrm.shape == (hs.N_SURFACE_POINTS, 3) == (573, 3)
    c = hs.SURFACE_CAPSULE
    r = hs.CAPSULE_RADII_M[c].astype(np.float64)
    p, q = x[hs.CAPSULE_A[c]], x[hs.CAPSULE_B[c]]
    # The distal capsules end their radius short of the tip, computed here from the joints.
    d = q - p
    L = np.linalg.norm(d, axis=-1, keepdims=True)
    q = np.where(hs.CAPSULE_IS_TIP[c][:, None], p + d * np.clip(L - r[:, None], 0, None) / L, q)
    np.testing.assert_allclose(_point_to_segment(pts, p, q), r, atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=-1), 1.0, atol=1e-6)
    # Outward: the point minus r·normal is on the axis, and a step out along the normal moves off the capsule.
    np.testing.assert_allclose(_point_to_segment(pts - r[:, None] * nrm, p, q), 0.0, atol=2e-6)
    np.testing.assert_allclose(_point_to_segment(pts + 0.002 * nrm, p, q) - r, 0.002, atol=2e-6)
    # Every fingertip keypoint is a surface point (it lies on the skin), with its normal along the bone.
    for tip in sk.TIPS:
        k = np.flatnonzero(np.linalg.norm(pts - x[tip], axis=-1) < 1e-5)
        assert len(k) == 1
        bone = x[tip] - x[sk.PARENTS[tip]]
        np.testing.assert_allclose(nrm[k[0]], bone / np.linalg.norm(bone), atol=1e-5)
    # The whole set is on the hand's surface or inside it (never outside the union of capsules).
    sdf = np.asarray(hs.hand_sdf(jnp.asarray(pts[None], jnp.float32), jnp.asarray(x[None], jnp.float32)))[0]
    assert np.all(sdf < 2e-6) and np.mean(np.abs(sdf) < 2e-6) > 0.5


def _flat_right_hand() -> np.ndarray:
    return hh.right_hand() * np.array([1.0, 1.0, 0.0])


def test_hand_facing_its_mirror_image_at_a_known_gap():
    # The flat handmade right hand's outermost surface on the +x side is its little-finger MCP (x = 0.032,
    # where the palm fan and the knuckle capsule end) plus the palm radius. Mirror it across the plane
    # x = c: the closest capsules are each one's own image, so the surfaces are 2 (0.032 + r_palm − c)... a
    # gap of g when c = 0.032 + r_palm + g / 2; negative g is an overlap that deep.
    right = _flat_right_hand()
    assert right[:, 0].max() == pytest.approx(hh.MCP_X["pinky"])
    gaps = np.array([0.02, 0.005, 0.0, -0.006, -0.015])
    frames = []
    for g in gaps:
        c = hh.MCP_X["pinky"] + hs.PALM_RADIUS_M + g / 2
        left = right * [-1, 1, 1] + [2 * c, 0, 0]
        frames.append(np.stack([left, right]))
    x = np.stack(frames).astype(np.float32)
    # (clips, frames) leading axes: per-frame values, the second clip the first reversed.
    xx = jnp.asarray(np.stack([x, x[::-1]]))
    np.testing.assert_allclose(np.asarray(hs.interhand_signed_distance(xx)), np.stack([gaps, gaps[::-1]]), atol=2e-6)


def test_surface_against_a_half_space_object_at_a_known_depth_and_slope():
    # A flat hand (joints at z = 0) over the object z < h. Its lowest surface is the palm capsules' bottom,
    # z = −r_palm, and a ring point sits exactly there (the rings start along the palm normal), so a surface
    # point is h + r_palm deep when that is positive; lifting the hand by ε lessens that depth by ε.
    flat = jnp.asarray(_flat_right_hand(), jnp.float32)
    depth = jax.jit(jax.vmap(jax.value_and_grad(
        lambda z, h: hs.object_penetration(z[None], lambda p: p[:, 2] - h)[0]), in_axes=(None, 0)))
    hz = np.array([-hs.PALM_RADIUS_M + 0.004, -0.02, 0.0], np.float32)
    d, g = depth(flat, jnp.asarray(hz))
    np.testing.assert_allclose(np.asarray(d), [0.004, 0.0, hs.PALM_RADIUS_M], atol=2e-6)
    np.testing.assert_allclose(np.asarray(g)[[0, 2]].sum(1), [[0.0, 0.0, -1.0]] * 2, atol=1e-5)
    np.testing.assert_allclose(np.asarray(g)[1], 0.0)


def test_gradients_finite_and_match_finite_differences_and_known_slopes():
    grad_sd = jax.jit(jax.grad(lambda z: hs.interhand_signed_distance(z)))
    # Overlapping hands (the posed hand against a shifted mirror image: the surfaces interpenetrate): the
    # gradient against central differences along random directions (one batched call for the shifts).
    right = _posed_right_hand()
    pair = np.stack([right * [-1, 1, 1] + [2 * right[:, 0].max() - 0.015, 0.003, 0.0], right]).astype(np.float32)
    assert float(hs.interhand_signed_distance(jnp.asarray(pair))) < 0
    g = np.asarray(grad_sd(jnp.asarray(pair)), np.float64)
    assert np.all(np.isfinite(g))
    v = np.random.default_rng(0).normal(size=(4, *pair.shape))
    h, v = 1e-4, v / np.linalg.norm(v.reshape(4, -1), axis=1)[:, None, None, None]  # unit directions
    vals = np.asarray(hs.interhand_signed_distance(jnp.asarray(np.concatenate([pair + h * v, pair - h * v]),
                                                               jnp.float32)), np.float64)
    np.testing.assert_allclose(np.sum(g * v, axis=(1, 2, 3)), (vals[:4] - vals[4:]) / (2 * h), atol=2e-3)
    # Known slopes: the flat hand and its mirror image 2 cm apart across x = c (their pinky sides face along
    # x): moving the right hand by ε along +x opens the gap by ε, moving the left one closes it.
    flat = _flat_right_hand()
    c = hh.MCP_X["pinky"] + hs.PALM_RADIUS_M + 0.01
    mirror = np.stack([flat * [-1, 1, 1] + [2 * c, 0, 0], flat]).astype(np.float32)  # left is the image: +x of right
    g = np.asarray(grad_sd(jnp.asarray(mirror)), np.float64)
    np.testing.assert_allclose(g[1].sum(0), [-1.0, 0.0, 0.0], atol=1e-5)  # the right hand lies on the −x side
    np.testing.assert_allclose(g[0].sum(0), [1.0, 0.0, 0.0], atol=1e-5)
    # Segments that intersect exactly (distance 0): the gradient is finite, not NaN.
    z = jnp.asarray([[-1.0, 0, 0], [1.0, 0, 0], [0, -1.0, 0], [0, 1.0, 0]])
    assert np.all(np.isfinite(np.asarray(jax.grad(lambda z: hs.segment_distance(z[0], z[1], z[2], z[3]))(z))))
