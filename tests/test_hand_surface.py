"""The hand surface (handx_jax/hand_surface.py) against answers derived without it: closed-form segment
distances, a hand facing its own mirror image across a plane at a known gap, a half-space object at a known
depth, finite differences of the signed distances, and the sampled points' own capsules."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import enable_x64

import handmade_hands as hh
from handx_jax import hand_surface as hs
from handx_jax import skeleton as sk


def test_segment_distance_closed_forms_and_brute_force():
    f = lambda *v: float(hs.segment_distance(*(np.asarray(a, np.float32) for a in v)))
    # Skew perpendicular segments crossing above each other at height 0.03.
    assert f([-1, 0, 0], [1, 0, 0], [0, -1, 0.03], [0, 1, 0.03]) == pytest.approx(0.03, abs=1e-6)
    # Parallel, overlapping along x, 0.02 apart; collinear with a gap of 0.5; a point against a segment.
    assert f([0, 0, 0], [1, 0, 0], [0.5, 0.02, 0], [2, 0.02, 0]) == pytest.approx(0.02, abs=1e-6)
    assert f([0, 0, 0], [1, 0, 0], [1.5, 0, 0], [3, 0, 0]) == pytest.approx(0.5, abs=1e-6)
    assert f([0, 0, 0], [0, 0, 0], [-1, 0.3, 0.4], [1, 0.3, 0.4]) == pytest.approx(0.5, abs=1e-6)
    # Random segments: never above the densely sampled minimum, and within its sampling error.
    P = np.random.default_rng(1).normal(size=(40, 4, 3))
    d = np.asarray(hs.segment_distance(*(P[:, i].astype(np.float32) for i in range(4))))
    s = np.linspace(0, 1, 201)[None, :, None]
    a, b = P[:, None, 0] + s * (P[:, 1] - P[:, 0])[:, None], P[:, None, 2] + s * (P[:, 3] - P[:, 2])[:, None]
    brute = np.linalg.norm(a[:, :, None] - b[:, None], axis=-1).min((1, 2))
    assert np.all(d <= brute + 1e-5) and np.all(brute - d < 0.01)


def test_two_capsules_at_known_distance():
    pen = lambda *v: float(hs.capsule_penetration(*(np.asarray(a, np.float32) for a in v)))
    sd = lambda *v: float(hs.capsule_signed_distance(*(np.asarray(a, np.float32) for a in v)))
    # Radii 10 and 8 mm, axes crossing 12 mm apart: 6 mm deep; 25 mm apart: a 7 mm gap.
    assert pen([-1, 0, 0], [1, 0, 0], 0.010, [0, -1, 0.012], [0, 1, 0.012], 0.008) == pytest.approx(0.006, abs=1e-6)
    assert pen([-1, 0, 0], [1, 0, 0], 0.010, [0, -1, 0.025], [0, 1, 0.025], 0.008) == 0.0
    assert sd([-1, 0, 0], [1, 0, 0], 0.010, [0, -1, 0.025], [0, 1, 0.025], 0.008) == pytest.approx(0.007, abs=1e-6)
    # End to end along one line: the rounded caps are 0.1 − 0.01 − 0.008 apart.
    assert sd([0, 0, 0], [0.2, 0, 0], 0.010, [0.3, 0, 0], [0.5, 0, 0], 0.008) == pytest.approx(0.082, abs=1e-6)


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
    x = jnp.asarray(np.stack(frames), jnp.float32)
    np.testing.assert_allclose(np.asarray(hs.interhand_signed_distance(x)), gaps, atol=2e-6)
    np.testing.assert_allclose(np.asarray(hs.interhand_penetration_depth(x)), np.maximum(-gaps, 0), atol=2e-6)
    # Vectorised: (clips, frames) leading axes give the per-frame values, and vmap agrees.
    xx = jnp.stack([x, x[::-1]])
    np.testing.assert_allclose(np.asarray(hs.interhand_signed_distance(xx)), np.stack([gaps, gaps[::-1]]), atol=2e-6)
    np.testing.assert_allclose(np.asarray(jax.vmap(hs.interhand_signed_distance)(xx)),
                               np.asarray(hs.interhand_signed_distance(xx)), atol=1e-7)


def test_surface_against_a_half_space_object_at_a_known_depth():
    # A flat hand (joints at z = 0) over the object z < h. Its lowest surface is the palm capsules' bottom,
    # z = −r_palm, and a ring point sits exactly there (the rings start along the palm normal), so a
    # surface point is h + r_palm deep when that is positive.
    x = jnp.asarray(np.stack([_flat_right_hand()] * 3), jnp.float32)
    hs_ = np.array([-hs.PALM_RADIUS_M + 0.004, -0.02, 0.0])
    depth = []
    for h in hs_:
        depth.append(np.asarray(hs.object_penetration(x[:1], lambda p, h=h: p[:, 2] - h))[0])
    np.testing.assert_allclose(depth, [0.004, 0.0, hs.PALM_RADIUS_M], atol=2e-6)


def _fd_check(f, x0: np.ndarray, n_dirs: int = 6, h: float = 1e-6, seed: int = 0) -> None:
    """jax.grad of scalar f at x0 against central differences along random directions, in float64 (one
    compiled gradient, and the 2·n_dirs shifted inputs evaluated in one vmapped call)."""
    with enable_x64():
        x = jnp.asarray(x0, jnp.float64)
        g = np.asarray(jax.jit(jax.grad(f))(x))
        assert np.all(np.isfinite(g)) and np.abs(g).sum() > 0
        v = np.random.default_rng(seed).normal(size=(n_dirs, *x0.shape))
        vals = np.asarray(jax.jit(jax.vmap(f))(jnp.concatenate([x + h * v, x - h * v])))
        fd = (vals[:n_dirs] - vals[n_dirs:]) / (2 * h)
        np.testing.assert_allclose(np.sum(g * v, axis=tuple(range(1, v.ndim))), fd, rtol=1e-4, atol=1e-7)


def test_gradients_finite_and_match_finite_differences():
    right = _posed_right_hand()
    left = right * [-1, 1, 1] + [2 * right[:, 0].max() + 0.01, 0.003, 0.0]
    pair = np.stack([left, right])
    # Overlapping hands (the posed hand against a shifted mirror image: the surfaces interpenetrate).
    pair[0] -= [0.025, 0.0, 0.0]
    assert float(hs.interhand_signed_distance(jnp.asarray(pair, jnp.float32))) < 0
    _fd_check(lambda z: hs.interhand_signed_distance(z), pair)
    # One hand's SDF at fixed points, and the surface against a sphere object, in the joints.
    pts = np.random.default_rng(2).normal(0, 0.03, (40, 3)) + right[0]
    _fd_check(lambda z: jnp.sum(hs.hand_sdf(jnp.asarray(pts)[None], z[None])), right)
    centre = right[sk.JOINT_INDEX["middle_pip"]] + [0.0, 0.0, 0.02]
    sphere = lambda p: jnp.linalg.norm(p - centre, axis=-1) - 0.025
    _fd_check(lambda z: jnp.sum(jnp.minimum(hs.surface_sdf(z, sphere), 0.0)), right)
    # Segments that intersect exactly (distance 0): the gradient is finite, not NaN.
    with enable_x64():
        z = jnp.asarray([[-1.0, 0, 0], [1.0, 0, 0], [0, -1.0, 0], [0, 1.0, 0]])
        g = jax.grad(lambda z: hs.segment_distance(z[0], z[1], z[2], z[3]))(z)
        assert np.all(np.isfinite(np.asarray(g)))
