"""The contact energy for sampling-time guidance (issue 33 item 2; handx_jax/families/diffusion/guidance.py): its distances are
the metric's, its gradient matches finite differences, and descending it realises a requested contact."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import enable_x64

import handmade_hands as hh
from handx_jax.families.diffusion import guidance as Gd
from handx_jax import metrics as M
from handx_jax import skeleton as sk

CH = M.CONTACT_CHANNELS
# compiled once for the tests below (run op by op, each of their many operations is its own compile)
distances = jax.jit(Gd.channel_distances)
to_joints = jax.jit(Gd.x0_to_joints)
energy_of = jax.jit(Gd.contact_energy)
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
    np.testing.assert_allclose(np.asarray(distances(jnp.asarray(x), jnp.asarray(W))),
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
    assert float(energy_of(x, req, W)[0]) < 1e-8
    assert M.contact_feasibility_counts(np.asarray(x), named, W)[0][0] == 1.0
    np.testing.assert_array_equal(np.asarray(x)[:, :4], np.asarray(x0)[:, :4])


def test_request_from_named_marks_the_ranges():
    named = M.NamedContacts(np.array([0, 1]), np.array([THUMBS, INDEX_PALM]), np.array([2, 50]), np.array([5, 70]))
    r = Gd.request_from_named(named, 2, 60)
    assert r.shape == (2, 60, 43) and r.sum() == 3 + 10
    assert r[0, 2:5, THUMBS].all() and r[1, 50:60, INDEX_PALM].all()


# ------------------------------------------------------------------------------------------------
# Guidance inside the sampler (guidance.make_steer in process.sample's scan)

from handx_jax import representation as rep  # noqa: E402
from handx_jax.families.diffusion import process as D  # noqa: E402

SIGMA = 0.05  # the toy's normalisation: xyz / 5 cm, no mean (a z-score with mean 0)
MEAN, STD = np.zeros((42, 4), np.float32), np.full((42, 4), SIGMA, np.float32)


@functools.lru_cache  # the tests below share its compiled programs
def _toy_sampler(gap: float = 0.12, feedback: float = 0.2):
    """A denoiser that ignores the text: x̂0 = P + feedback·x_t, P the handmade pair (30 frames; thumb tips ~7 cm
    apart at gap 0.12, no contact anywhere). Through x_t, guidance at one step moves the later predictions too."""
    P = rep.to_diffusion(_pair(30, gap=gap)[0]).astype(np.float32) / SIGMA  # (30, 42, 4) normalised
    cfg = D.DiffusionConfig(steps=100, guidance=1.0)
    sched = D.cosine_schedule(cfg.steps)

    @jax.jit
    def fn(rng, req, s):  # one compile per request/no request (None is a different input structure)
        steer = None if req is None else Gd.make_steer(req, s, "late", sched.alphas_cumprod, MEAN, STD)
        return D.sample(lambda x, t, u: jnp.asarray(P) + feedback * x, sched, (2, 30, 42, 4), rng, cfg,
                        sampler="ddim", steps=10, steer=steer)

    def run(request=None, strength=1.0, lower=False):
        args = (jax.random.PRNGKey(0), None if request is None else jnp.asarray(request, jnp.float32),
                jnp.float32(strength))
        if lower:
            return fn.lower(*args).as_text()
        x = np.asarray(fn(*args))
        return x, to_joints(jnp.asarray(x), MEAN, STD)

    return run


def test_a_guided_toy_sample_reaches_the_requested_contact_and_an_unguided_one_does_not():
    run = _toy_sampler()
    W = jnp.asarray(M.palm_barycentric())
    req = Gd.request_from_spec("L.thumb-R.thumb@10:20", 2, 30)
    x_off, j_off = run()
    # A 10-frame request spreads one unit-norm step (BimArt's) over 10 frames: ~2.2 cm per frame per step
    # here; strength 5 lets the last steps close the ~7 cm gap.
    x_on, j_on = run(req, strength=5.0)
    thr = float(M.contact_thresholds()[THUMBS])
    d_off = np.asarray(distances(j_off, W))[..., THUMBS]
    d_on = np.asarray(distances(j_on, W))[..., THUMBS]
    assert d_off.min() > 2 * thr  # unguided: the thumbs never meet
    assert d_on[:, 10:20].max() < thr  # guided: in contact on every requested frame, in both samples
    named = M.NamedContacts(np.array([0, 1]), np.array([THUMBS] * 2), np.array([10] * 2), np.array([20] * 2))
    assert M.contact_feasibility_counts(np.asarray(j_on), named, W)[0].tolist() == [1.0, 1.0]
    assert M.contact_feasibility_counts(np.asarray(j_off), named, W)[0].tolist() == [0.0, 0.0]
    # The energy is per frame and the toy denoiser treats frames alone: unrequested frames are the
    # unguided sample's, bit for bit; so is everything under an empty request.
    np.testing.assert_array_equal(x_on[:, :10], x_off[:, :10])
    np.testing.assert_array_equal(x_on[:, 20:], x_off[:, 20:])
    np.testing.assert_array_equal(run(np.zeros_like(req), strength=5.0)[0], x_off)
    # A weaker step gets less far (strength is a traced input: the same compiled program).
    d_weak = np.asarray(distances(run(req, strength=1.0)[1], W))[..., THUMBS]
    assert d_on[:, 10:20].max() < d_weak[:, 10:20].min() < d_off[:, 10:20].min()


def test_guidance_off_traces_no_guidance():
    """No request: the sampler's program has none of the energy's operations (the palm cloud's top-k)."""
    run = _toy_sampler()
    assert "top_k" not in run(lower=True) and "top_k" in run(Gd.request_from_spec("L.index-R.palm", 2, 30), lower=True)


def test_one_step_closes_a_single_gap_exactly_or_moves_by_its_length():
    """A known answer for the step rule: for one tip pair under a uniform z-score σ, the energy's gradient moves
    the two tips straight toward each other, so a step of normalised length ℓ shortens their distance by σ·ℓ·√2
    (each tip moves σℓ/√2), and the Gauss–Newton cap stops it exactly at TARGET_FRACTION × threshold."""
    x = rep.to_diffusion(_pair(1, gap=0.12, seed=3)[0]).astype(np.float32)[None] / SIGMA  # (1, 1, 42, 4)
    W = jnp.asarray(M.palm_barycentric())
    req = jnp.asarray(_request(1, [(THUMBS, 0, 1)]), jnp.float32)
    energy = lambda y: Gd.contact_energy(Gd.x0_to_joints(y, MEAN, STD), req, W)  # noqa: E731

    def dist(y):
        return float(distances(to_joints(jnp.asarray(y), MEAN, STD), W)[0, 0, THUMBS])

    step = jax.jit(lambda y, ell: Gd.guide_step(y, energy, ell))
    d0 = dist(x)
    ell = 0.1
    assert dist(step(jnp.asarray(x), ell)) == pytest.approx(d0 - SIGMA * ell * np.sqrt(2), abs=1e-6)
    thr = float(M.contact_thresholds()[THUMBS])
    assert dist(step(jnp.asarray(x), 100.0)) == pytest.approx(Gd.TARGET_FRACTION * thr, abs=1e-6)


@pytest.mark.parametrize("spec, channels", [
    ("L.thumb-R.index@20:40", [CH[("finger_tip_contact", "left_thumb_tip, right_index_tip")]]),
    ("R.index-L.thumb", [CH[("finger_tip_contact", "left_thumb_tip, right_index_tip")]]),
    ("left.index-right.palm@0:60", [CH[("finger_palm_distance", "left_index_tip, right_palm")]]),
    ("R.palm-L.index", [CH[("finger_palm_distance", "left_index_tip, right_palm")]]),
    ("r.thumb-r.ring@:5", [CH[("right_hand_events", "ring_tip, thumb_tip")]]),
    ("L.tips-R.tips", [CH[("finger_tip_contact", f"left_{f}_tip, right_{f}_tip")] for f in sk.FINGER_NAMES]),
    ("R.tips-L.palm", [CH[("finger_palm_distance", f"right_{f}_tip, left_palm")] for f in sk.FINGER_NAMES]),
])
def test_contact_specs_name_the_metrics_channels(spec, channels):
    assert [c for c, _, _ in Gd.parse_contacts(spec)] == channels
    r = Gd.request_from_spec(spec + ", L.pinky-R.pinky@58:60", 1, 60)
    frames = {"@20:40": range(20, 40), "@0:60": range(60), "@:5": range(5)}.get(spec[spec.find("@"):], range(60))
    assert r[0][:, channels].sum() == len(frames) * len(channels) and r[0][list(frames)][:, channels].all()
    assert r[0, 58:, CH[("finger_tip_contact", "left_pinky_tip, right_pinky_tip")]].tolist() == [1.0, 1.0]  # up to T


@pytest.mark.parametrize("spec, says", [
    ("L.thum-R.index", "bad side 'L.thum'"), ("X.index-R.palm", "bad side 'X.index'"),
    ("L.index", "two sides joined by '-'"), ("L.palm-R.palm", "palm–palm"), ("L.index-L.palm", "OTHER hand's palm"),
    ("L.index-L.middle", "only thumb–finger"), ("L.index-R.index@40:20", "frames '40:20' are empty"),
    ("L.index-R.index@a:20", "frame 'a'"), ("L.index-R.index@20", "want START:END"), ("L.index-R.index,", "empty"),
])
def test_bad_contact_specs_name_the_token(spec, says):
    with pytest.raises(ValueError, match=None) as e:
        Gd.parse_contacts(spec)
    assert says in str(e.value) and "\n" not in str(e.value)
