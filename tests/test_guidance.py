"""The contact energy for sampling-time guidance (issue 33 item 2; handx_jax/guidance.py): its distances are
the metric's, its gradient matches finite differences, and descending it realises a requested contact."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import enable_x64

import handmade_hands as hh
from handx_jax import guidance as Gd
from handx_jax import metrics as M
from handx_jax import skeleton as sk

CH = M.CONTACT_CHANNELS
THUMBS = CH[("finger_tip_contact", "left_thumb_tip, right_thumb_tip")]
INDEX_PALM = CH[("finger_palm_distance", "left_index_tip, right_palm")]


def _pair(T: int = 12, gap: float = 0.04, seed: int = 0) -> np.ndarray:
    """(1, T, 2, 21, 3): the handmade pair 2·gap apart, jittered so that no two distances tie."""
    x = hh.still(T=T).astype(np.float64)
    x[0, :, 0] += [0.15 - gap, 0.0, 0.0]
    x[0, :, 1] += [-0.15 + gap, 0.0, 0.0]
    return x + np.random.default_rng(seed).normal(0, 0.003, x.shape)


def _request(T: int, cells) -> np.ndarray:
    r = np.zeros((1, T, M.N_CONTACT_CHANNELS))
    for ch, s, e in cells:
        r[0, s:e, ch] = 1.0
    return r


def test_distances_are_the_metrics():
    x = _pair().astype(np.float32)
    W = M.palm_barycentric()
    np.testing.assert_allclose(np.asarray(Gd.channel_distances(jnp.asarray(x), jnp.asarray(W))),
                               np.asarray(M.contact_channel_distances(x, W)), atol=1e-6)


def test_gradient_matches_finite_differences():
    with enable_x64():
        x = jnp.asarray(_pair(seed=1))
        W = jnp.asarray(M.palm_barycentric(), jnp.float64)
        req = jnp.asarray(_request(12, [(THUMBS, 2, 8), (INDEX_PALM, 5, 12), (CH[("left_hand_events",
                                                                                "index_tip, thumb_tip")], 0, 12)]))
        f = jax.jit(lambda y: jnp.sum(Gd.contact_energy(y, req, W)))
        assert float(f(x)) > 1e-5  # the requested pairs are apart: the energy is active
        g = np.asarray(jax.grad(f)(x))
        rng = np.random.default_rng(2)
        h = 1e-6
        for _ in range(4):  # directional derivatives along random directions
            v = rng.normal(size=x.shape)
            fd = (float(f(x + h * v)) - float(f(x - h * v))) / (2 * h)
            assert np.sum(g * v) == pytest.approx(fd, rel=1e-5, abs=1e-12)
        for idx in [(0, 3, 0, sk.TIPS[0], 0), (0, 6, 1, 0, 2), (0, 9, 0, sk.TIPS[1], 1)]:  # single coordinates
            e = np.zeros(x.shape)
            e[idx] = 1.0
            fd = (float(f(x + h * e)) - float(f(x - h * e))) / (2 * h)
            assert g[idx] == pytest.approx(fd, rel=1e-5, abs=1e-12)
        # Joints that no requested channel reads get no gradient (the right hand's pinky DIP here).
        assert np.all(g[0, :, 1, sk.JOINT_INDEX["pinky_dip"]] == 0.0)


def test_descending_the_energy_realises_the_requested_contact():
    """Gradient steps on the joints alone (a stand-in for guided x̂0 updates) bring the requested thumbs
    together in the requested frames: the contact-feasibility metric goes from 0 to 1, the energy to 0,
    and frames outside the request do not move."""
    T = 12
    x0 = jnp.asarray(_pair(T, gap=0.03).astype(np.float32))
    W = jnp.asarray(M.palm_barycentric())
    req = jnp.asarray(_request(T, [(THUMBS, 4, 8)]), jnp.float32)
    named = M.NamedContacts(np.array([0]), np.array([THUMBS]), np.array([4]), np.array([8]))
    assert M.contact_feasibility_counts(np.asarray(x0), named, W)[0][0] == 0.0
    grad = jax.jit(jax.grad(lambda y: jnp.sum(Gd.contact_energy(y, req, W))))
    x = x0
    for _ in range(60):
        g = grad(x)
        x = x - 0.5 * g / (jnp.linalg.norm(g) + 1e-12) * 0.01  # BimArt's λ_c = 1/‖∇‖, a 5 mm step
    assert float(Gd.contact_energy(x, req, W)[0]) < 1e-8
    assert M.contact_feasibility_counts(np.asarray(x), named, W)[0][0] == 1.0
    np.testing.assert_array_equal(np.asarray(x)[:, :4], np.asarray(x0)[:, :4])


def test_request_from_named_marks_the_ranges():
    named = M.NamedContacts(np.array([0, 1]), np.array([THUMBS, INDEX_PALM]), np.array([2, 50]), np.array([5, 70]))
    r = Gd.request_from_named(named, 2, 60)
    assert r.shape == (2, 60, 43) and r.sum() == 3 + 10
    assert r[0, 2:5, THUMBS].all() and r[1, 50:60, INDEX_PALM].all()
