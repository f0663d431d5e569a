"""BimArt's object features (§3.1, Eq. 1-3; objects/features.py): invariances and the part mapping.

Independent references: scipy rotations for the part poses, brute-force nearest neighbours in numpy for Eq. 2,
and the objects' analytic signed distances for "the mapped point lies on its part".
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jax.numpy as jnp

from handx_jax.objects import BOTTOM, TOP, part_sdf, sample_instance, surface_samples
from handx_jax.objects.bps import basis_points, map_basis, object_scale
from handx_jax.objects.features import bps_features, global_states, mapped_points_world, object_features

K = 32


@pytest.fixture(scope="module")
def box():
    obj = sample_instance("box", 7)
    samples = np.stack([np.asarray(surface_samples(obj, p, 512, 11 + p)[0]) for p in (TOP, BOTTOM)])
    basis = np.asarray(basis_points(K))
    s_o = float(object_scale(obj, jnp.asarray(samples), np.pi))
    return obj, samples, basis, s_o, map_basis(samples, basis, s_o)


def _states(rng, angles):
    T = len(angles)
    return np.concatenate([np.asarray(angles)[:, None], rng.normal(size=(T, 3)) * 0.7,
                           rng.normal(size=(T, 3)) * 0.3], 1).astype(np.float32)


def test_eq2_nearest_sample_by_brute_force(box):
    _, samples, basis, s_o, mapped = box
    for p in (TOP, BOTTOM):
        for k in range(0, K, 5):
            d = [np.linalg.norm(v * s_o - basis[k]) for v in samples[p]]
            np.testing.assert_allclose(mapped[p, k], samples[p][int(np.argmin(d))], atol=1e-7)
    # Eq. 1: the scaled object sits inside the unit ball with the margin (lid opened to pi).
    top_open = samples[TOP] @ Rotation.from_rotvec([0, 0, -np.pi]).as_matrix().T
    r = max(np.linalg.norm(top_open, axis=1).max(), np.linalg.norm(samples[BOTTOM], axis=1).max())
    assert abs(r * s_o - 0.85) < 1e-5


def test_features_invariant_to_global_pose_not_to_angle(box):
    _, _, basis, s_o, mapped = box
    rng = np.random.default_rng(0)
    angles = np.array([0.0, 0.4, 1.1, 1.9])
    a, b = _states(rng, angles), _states(rng, angles)                       # same angles, other global poses
    Oa = np.asarray(bps_features(jnp.asarray(mapped), basis, s_o, a[:, 0]))
    Ob = np.asarray(bps_features(jnp.asarray(mapped), basis, s_o, b[:, 0]))
    np.testing.assert_array_equal(Oa, Ob)
    # The bottom part does not articulate: its features are the same at every angle; the top part's are not.
    np.testing.assert_allclose(Oa[:, BOTTOM], np.broadcast_to(Oa[:1, BOTTOM], Oa[:, BOTTOM].shape), atol=1e-7)
    assert np.abs(Oa[1:, TOP] - Oa[:1, TOP]).max() > 0.05
    # G: translation relative to the first frame (invariant to placing the clip elsewhere), rotation absolute.
    shifted = a.copy()
    shifted[:, 4:7] += np.array([0.3, -1.0, 2.0], np.float32)
    np.testing.assert_allclose(np.asarray(global_states(shifted)), np.asarray(global_states(a)), atol=1e-6)
    np.testing.assert_array_equal(np.asarray(global_states(a))[0, 3:], 0.0)
    f = np.asarray(object_features(jnp.asarray(mapped), basis, s_o, jnp.asarray(a)))
    assert f.shape == (4, 6 * K + 7) and np.all(f[:, -1] == np.float32(s_o))


def test_part_mapping_at_several_angles(box):
    obj, _, basis, s_o, mapped = box
    rng = np.random.default_rng(1)
    angles = np.array([0.0, 0.5, 1.2, 1.9])
    states = _states(rng, angles)
    world = np.asarray(mapped_points_world(jnp.asarray(mapped), jnp.asarray(states)))  # (T, 2, K, 3)
    O = np.asarray(bps_features(jnp.asarray(mapped), basis, s_o, angles))
    for i, s in enumerate(states):
        R_g = Rotation.from_rotvec(s[1:4]).as_matrix()
        R_top = R_g @ Rotation.from_rotvec([0, 0, -s[0]]).as_matrix()  # ARCTIC: top turns about -z, then global
        np.testing.assert_allclose(world[i, TOP], mapped[TOP] @ R_top.T + s[4:7], atol=1e-5)
        np.testing.assert_allclose(world[i, BOTTOM], mapped[BOTTOM] @ R_g.T + s[4:7], atol=1e-5)
        for p in (TOP, BOTTOM):  # each mapped point is on its own part's surface at this frame's state
            d = np.asarray(part_sdf(obj, p, jnp.asarray(s), jnp.asarray(world[i, p])))
            assert np.abs(d).max() < 1e-5
        # The features are the object-centric points (the global pose removed) scaled, minus the basis.
        centric = (world[i] - s[4:7]) @ R_g
        np.testing.assert_allclose(O[i], centric * s_o - basis, atol=1e-5)
