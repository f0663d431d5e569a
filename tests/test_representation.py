"""Tests for handx_jax.representation: frames, rotation scalar, diffusion/AR/evaluator features, NormStats."""

from __future__ import annotations

import numpy as np
import pytest

from handx_jax import representation as rep
from handx_jax import skeleton as sk


# ----------------------------------------------------------------------------------------------
# a realistic random-but-smooth bimanual clip

def _rodrigues(aa_x3: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(aa_x3, axis=-1, keepdims=True)[..., None]
    k = aa_x3 / np.maximum(np.linalg.norm(aa_x3, axis=-1, keepdims=True), 1e-12)
    K = np.zeros(aa_x3.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


_BASE_DIR = {"thumb": (0.5, 0.6, -0.3), "index": (1.0, 0.25, 0.0), "middle": (1.0, 0.0, 0.0),
             "ring": (1.0, -0.2, 0.0), "pinky": (0.9, -0.45, 0.0)}
_BASE_LEN = {"thumb": 0.03, "index": 0.09, "middle": 0.09, "ring": 0.085, "pinky": 0.08}
_SEG_LEN = {"thumb": (0.035, 0.03, 0.025), "index": (0.045, 0.025, 0.02), "middle": (0.05, 0.03, 0.022),
            "ring": (0.045, 0.028, 0.02), "pinky": (0.035, 0.02, 0.018)}


def _hand_template(rng: np.random.Generator, mirror: bool) -> np.ndarray:
    """One hand (21, 3) in its own frame: random bone directions around a plausible layout."""
    p = np.zeros((sk.NUM_JOINTS, 3))
    for f in sk.FINGER_NAMES:
        chain = sk.CHAINS[f]
        d = _unit(np.asarray(_BASE_DIR[f]) + rng.normal(scale=0.08, size=3))
        p[chain[1]] = _BASE_LEN[f] * rng.uniform(0.9, 1.1) * d
        for s in (2, 3, 4):
            d = _unit(d + rng.normal(scale=0.25, size=3))
            p[chain[s]] = p[chain[s - 1]] + _SEG_LEN[f][s - 2] * rng.uniform(0.9, 1.1) * d
    if mirror:
        p[:, 1] *= -1.0
    return p


def smooth_clip(seed: int = 0, T: int = sk.CLIP_LEN, dtype=np.float32) -> np.ndarray:
    """(T, 2, 21, 3) clip: two random hands, smooth wrist paths, smooth rotations and finger wiggle."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None] / sk.FPS
    out = np.zeros((T, 2, sk.NUM_JOINTS, 3))
    for h in (sk.LEFT, sk.RIGHT):
        tmpl = _hand_template(rng, mirror=(h == sk.RIGHT))
        w0 = np.array([-0.15 if h == sk.LEFT else 0.15, 0.0, 0.0])
        wrist = w0 + rng.uniform(0.02, 0.08, 3) * np.sin(2 * np.pi * rng.uniform(0.3, 1.2, 3) * t + rng.uniform(0, 6, 3))
        aa = rng.normal(scale=0.5, size=3) + rng.uniform(0.2, 0.6, 3) * np.sin(
            2 * np.pi * rng.uniform(0.2, 1.0, 3) * t + rng.uniform(0, 6, 3))
        R = _rodrigues(aa)  # (T, 3, 3)
        wiggle = 0.006 * np.sin(2 * np.pi * rng.uniform(0.5, 2.0, (1, 21, 3)) * t[:, :, None]
                                + rng.uniform(0, 6, (1, 21, 3)))
        wiggle[:, [0, 1, 4, 7]] = 0.0  # keep the palm rigid
        local = tmpl[None] + wiggle
        out[:, h] = wrist[:, None, :] + np.einsum("tij,tkj->tki", R, local)
    out -= out[0, sk.RIGHT, 0]  # released clips: right wrist at the origin in frame 0 (§1.7)
    return out.astype(dtype)


# ----------------------------------------------------------------------------------------------
# wrist frames

@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_wrist_frames_orthonormal_right_handed(dtype):
    j = np.stack([smooth_clip(1, dtype=dtype), smooth_clip(2, dtype=dtype)])  # (2, T, 2, 21, 3)
    R = rep.wrist_frames(j)
    assert R.shape == (2, sk.CLIP_LEN, 2, 3, 3) and R.dtype == dtype
    R64 = R.astype(np.float64)
    tol = 1e-5 if dtype == np.float32 else 1e-12
    np.testing.assert_allclose(np.swapaxes(R64, -1, -2) @ R64, np.broadcast_to(np.eye(3), R64.shape), atol=tol)
    np.testing.assert_allclose(np.linalg.det(R64), 1.0, atol=tol)
    # column 0 is the wrist→middle-MCP direction; index MCP lies in the local x–y plane with y > 0
    j64 = j.astype(np.float64)
    np.testing.assert_allclose(R64[..., :, 0], _unit(j64[..., 4, :] - j64[..., 0, :]), atol=tol)
    loc = rep.local_positions(j64)
    np.testing.assert_allclose(loc[..., 1, 2], 0.0, atol=1e-12)
    assert np.all(loc[..., 1, 1] > 0)
    np.testing.assert_allclose(loc[..., 4, 1:], 0.0, atol=1e-12)


def test_wrist_frames_degenerate_raises():
    j = smooth_clip(3)
    bad = j.copy()
    bad[7, sk.RIGHT, 4] = bad[7, sk.RIGHT, 0]
    with pytest.raises(ValueError, match=r"degenerate wrist frame.*\(7,\).*right"):
        rep.wrist_frames(bad)
    bad = j.copy()
    w = bad[2, sk.LEFT, 0]
    bad[2, sk.LEFT, 1] = w + 0.5 * (bad[2, sk.LEFT, 4] - w)  # index MCP on the wrist→middle line
    with pytest.raises(ValueError, match="parallel"):
        rep.wrist_frames(bad)


# ----------------------------------------------------------------------------------------------
# rotation scalar

def _planar_hand(theta: float, sideways: bool = False) -> np.ndarray:
    """A hand with x̂ = +x, index MCP at +y, pinky MCP at −y (so the paper's normal is +y).

    Every finger runs straight along +x except the index finger, bent at its PIP by ``theta``,
    in the x–z plane (flexion) or, with ``sideways``, in the x–y plane (abduction).
    """
    p = np.zeros((sk.NUM_JOINTS, 3))
    ys = {"thumb": 0.04, "index": 0.02, "middle": 0.0, "ring": -0.015, "pinky": -0.03}
    for f in sk.FINGER_NAMES:
        c = sk.CHAINS[f]
        p[c[1]] = (0.09, ys[f], 0.0)
        for s in (2, 3, 4):
            p[c[s]] = p[c[s - 1]] + (0.03, 0.0, 0.0)
    bend = np.array([np.cos(theta), np.sin(theta), 0.0] if sideways else [np.cos(theta), 0.0, np.sin(theta)])
    i = sk.CHAINS["index"]
    p[i[3]] = p[i[2]] + 0.03 * bend
    p[i[4]] = p[i[3]] + 0.03 * bend
    return p


@pytest.mark.parametrize("theta", [0.0, 0.3, 1.0, 2.0])
def test_scalar_paper_known_angle(theta):
    hand = _planar_hand(theta)
    j = np.stack([hand, hand])  # (2, 21, 3)
    s = rep.rotation_scalar(j.astype(np.float64), "paper")
    pip = sk.CHAINS["index"][2]
    np.testing.assert_allclose(s[:, pip], theta, atol=1e-12)
    others = np.delete(np.arange(sk.NUM_JOINTS), pip)
    np.testing.assert_allclose(s[:, others], 0.0, atol=1e-12)
    # invariant under a rigid rotation + translation, and under a mirror image
    R = _rodrigues(np.array([0.3, -1.1, 0.7]))
    moved = j @ R.T + np.array([0.2, -0.1, 0.5])
    np.testing.assert_allclose(rep.rotation_scalar(moved, "paper"), s, atol=1e-12)
    mirrored = j * np.array([1.0, -1.0, 1.0])
    np.testing.assert_allclose(rep.rotation_scalar(mirrored, "paper"), s, atol=1e-12)
    # sideways (abduction) bends lie along the pinky→index axis and are projected out
    # (a bend beyond 90° projects onto the reversed bone direction, i.e. π)
    side = _planar_hand(theta, sideways=True)
    np.testing.assert_allclose(rep.rotation_scalar(np.stack([side, side]), "paper")[:, pip],
                               0.0 if np.cos(theta) > 0 else np.pi, atol=1e-12)


def test_scalar_code_known_angle_and_hand_sign():
    theta = 0.7
    hand = _planar_hand(theta)
    pip = sk.CHAINS["index"][2]
    s = rep.rotation_scalar(np.stack([hand, hand]), "code")
    np.testing.assert_allclose(s[sk.LEFT, pip], theta, atol=1e-12)
    np.testing.assert_allclose(s[sk.RIGHT], -s[sk.LEFT], atol=1e-12)  # same pose: right negated
    # an anatomical mirror image flips the local z axis, so after negation both hands agree
    mirrored = hand * np.array([1.0, -1.0, 1.0])
    s2 = rep.rotation_scalar(np.stack([hand, mirrored]), "code")
    np.testing.assert_allclose(s2[sk.RIGHT], s2[sk.LEFT], atol=1e-12)
    # wrist and tips are zero; NaN becomes 0
    assert np.all(s[:, [0, *sk.TIPS]] == 0)
    j = smooth_clip(4, dtype=np.float64)
    j[5, sk.LEFT, 2] = np.nan
    sc = rep.rotation_scalar(j, "code")
    assert np.all(np.isfinite(sc))
    assert sc.shape == (sk.CLIP_LEN, 2, 21)
    assert np.all(np.abs(sc) < 2 * np.pi)


def test_scalar_rejects_unknown_convention():
    with pytest.raises(ValueError, match="convention"):
        rep.rotation_scalar(smooth_clip(0), "degrees")


# ----------------------------------------------------------------------------------------------
# diffusion representation

@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_diffusion_round_trip(dtype):
    j = np.stack([smooth_clip(s, dtype=dtype) for s in (5, 6, 7)])  # (3, T, 2, 21, 3)
    x = rep.to_diffusion(j)
    assert x.shape == (3, sk.CLIP_LEN, 42, 4) and x.dtype == dtype
    c = rep.diffusion_center(j)
    assert c.shape == (3, 3)
    # centring (§1.8): the mean over t of the wrist midpoint is 0 after centring
    mid = 0.5 * (x[:, :, 0, :3].astype(np.float64) + x[:, :, 21, :3])
    np.testing.assert_allclose(mid.mean(axis=1), 0.0, atol=1e-6)
    # layout: rows 0–20 left, channel 3 the scalar
    np.testing.assert_allclose(x[..., :21, 3], rep.rotation_scalar(j)[..., 0, :], atol=1e-6)
    back = rep.diffusion_to_joints(x, c)
    err = np.abs(back.astype(np.float64) - j).max()
    assert err < (1e-6 if dtype == np.float32 else 1e-12), err
    np.testing.assert_allclose(rep.diffusion_to_joints(x), j - c[:, None, None, None, :], atol=1e-6)
    # the code convention changes only the scalar channel
    xc = rep.to_diffusion(j, convention="code")
    np.testing.assert_array_equal(xc[..., :3], x[..., :3])


# ----------------------------------------------------------------------------------------------
# AR representation

def test_ar_layout_slices():
    L = rep.AR_LAYOUT
    sl = [L.root_vel, L.lr_offset, L.rot6d, L.scalar, L.local_pos, L.local_vel]
    assert sl[0].start == 0 and sl[-1].stop == L.dim == 288
    assert all(a.stop == b.start for a, b in zip(sl[:-1], sl[1:]))
    assert [s.stop - s.start for s in sl] == [3, 3, 12, 30, 120, 120]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_ar_round_trip(dtype):
    j = np.stack([smooth_clip(s, dtype=dtype) for s in (8, 9)])  # (2, T, 2, 21, 3)
    f = rep.to_ar(j)
    assert f.shape == (2, sk.CLIP_LEN, 288) and f.dtype == dtype
    back = rep.ar_to_joints(f)  # root0 = origin, as in the released clips
    assert back.shape == j.shape and back.dtype == dtype
    err = np.abs(back.astype(np.float64) - j).max()
    assert err < (1e-5 if dtype == np.float32 else 1e-12), err
    # with an explicit root0 the absolute position is recovered for shifted clips too
    shift = np.array([[0.3, -0.2, 0.9], [-1.0, 0.4, 0.1]], dtype=dtype)
    js = j + shift[:, None, None, None, :]
    back_s = rep.ar_to_joints(rep.to_ar(js), root0_x3=js[:, 0, sk.RIGHT, 0])
    assert np.abs(back_s.astype(np.float64) - js).max() < (1e-5 if dtype == np.float32 else 1e-12)


def test_ar_slices_content():
    j = smooth_clip(10, dtype=np.float64)
    f = rep.to_ar(j)
    L = rep.AR_LAYOUT
    rw, lw = j[:, sk.RIGHT, 0], j[:, sk.LEFT, 0]
    np.testing.assert_allclose(f[:-1, L.root_vel], rw[1:] - rw[:-1], atol=1e-15)
    assert np.all(f[-1, L.root_vel] == 0) and np.all(f[-1, L.local_vel] == 0)
    np.testing.assert_allclose(f[:, L.lr_offset], lw - rw, atol=1e-15)
    R = rep.wrist_frames(j)
    np.testing.assert_allclose(f[:, L.rot6d].reshape(-1, 2, 2, 3), R[:, :, :2, :], atol=1e-15)
    np.testing.assert_allclose(f[:, L.scalar].reshape(-1, 2, 15), rep.rotation_scalar(j)[..., 1:16], atol=1e-15)
    loc = f[:, L.local_pos].reshape(-1, 2, 20, 3)
    expect = np.einsum("thic,thji->thjc", R, j[:, :, 1:] - j[:, :, :1])
    np.testing.assert_allclose(loc, expect, atol=1e-15)
    np.testing.assert_allclose(f[:-1, L.local_vel], f[1:, L.local_pos] - f[:-1, L.local_pos], atol=1e-15)
    f_code = rep.to_ar(j, convention="code")
    np.testing.assert_allclose(f_code[:, L.scalar].reshape(-1, 2, 15),
                               rep.rotation_scalar(j, "code")[..., 1:16], atol=1e-15)


def test_ar_external_rotations_round_trip():
    j = smooth_clip(11, dtype=np.float64)
    rng = np.random.default_rng(0)
    Rext = _rodrigues(rng.normal(size=(sk.CLIP_LEN, 2, 3)))
    f = rep.to_ar(j, rotations_xTx2x3x3=Rext)
    np.testing.assert_allclose(rep.rotation_6d_to_matrix(f[:, rep.AR_LAYOUT.rot6d].reshape(-1, 2, 6)), Rext,
                               atol=1e-12)
    assert np.abs(rep.ar_to_joints(f) - j).max() < 1e-12
    with pytest.raises(ValueError, match="rotations"):
        rep.to_ar(j, rotations_xTx2x3x3=Rext[:5])


def test_rotation_6d_gram_schmidt():
    rng = np.random.default_rng(1)
    R = _rodrigues(rng.normal(size=(50, 3)))
    np.testing.assert_allclose(rep.rotation_6d_to_matrix(rep.matrix_to_rotation_6d(R)), R, atol=1e-12)
    # a perturbed 6D vector still maps to a proper rotation
    M = rep.rotation_6d_to_matrix(rep.matrix_to_rotation_6d(R) + 0.1 * rng.normal(size=(50, 6)))
    np.testing.assert_allclose(M @ np.swapaxes(M, -1, -2), np.broadcast_to(np.eye(3), M.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(M), 1.0, atol=1e-12)


# ----------------------------------------------------------------------------------------------
# evaluator features

def test_evaluator_features():
    j = np.stack([smooth_clip(12), smooth_clip(13)])
    e = rep.to_evaluator(j)
    assert e.shape == (2, sk.CLIP_LEN, 126) and e.dtype == np.float32
    e5 = e.reshape(2, sk.CLIP_LEN, 2, 21, 3)
    assert np.all(e5[:, :, sk.RIGHT, 0] == 0)
    np.testing.assert_allclose(e5[:, :, sk.LEFT, 0], j[:, :, sk.LEFT, 0] - j[:, :, sk.RIGHT, 0], atol=1e-7)
    np.testing.assert_allclose(e[..., 3 * 5:3 * 6], (j[:, :, 0, 5] - j[:, :, 1, 0]), atol=1e-7)
    # float32 in: computed in float32, bit for bit the float64 difference cast back; float64 stays float64
    p64 = j.astype(np.float32).astype(np.float64)
    want = (p64 - p64[..., sk.RIGHT:sk.RIGHT + 1, 0:1, :]).reshape(2, sk.CLIP_LEN, 126).astype(np.float32)
    np.testing.assert_array_equal(rep.to_evaluator(j.astype(np.float32)), want)
    assert rep.to_evaluator(j.astype(np.float64)).dtype == np.float64


def test_evaluator_hand_frames_features():
    j = np.stack([smooth_clip(12), smooth_clip(13)]).astype(np.float64)
    f = rep.to_evaluator_hand_frames(j)
    assert f.shape == (2, sk.CLIP_LEN, rep.EVALUATOR_HAND_FRAMES_DIM) == (2, sk.CLIP_LEN, 307)
    np.testing.assert_array_equal(f[..., :126], rep.to_evaluator(j))  # the reference's 126 come first
    # the local block is exactly §2.1's local positions of joints 1..20
    np.testing.assert_allclose(f[..., 126:246].reshape(2, sk.CLIP_LEN, 2, 20, 3),
                               rep.local_positions(j)[..., 1:, :], atol=1e-12)
    # known distances: thumb tip to index tip (left hand), left thumb tip to right pinky tip
    tips = j[..., list(sk.TIPS), :]
    np.testing.assert_allclose(f[..., 264], np.linalg.norm(tips[..., 0, 1, :] - tips[..., 0, 0, :], axis=-1))
    np.testing.assert_allclose(f[..., 272 + 4], np.linalg.norm(tips[..., 0, 0, :] - tips[..., 1, 4, :], axis=-1))
    # everything after the 126 is invariant to a rigid motion of the whole scene
    R, t = _rodrigues(np.array([0.3, -1.1, 0.7])), np.array([0.4, -0.2, 1.0])
    g = rep.to_evaluator_hand_frames(j @ R.T + t)
    np.testing.assert_allclose(g[..., 126:246], f[..., 126:246], atol=1e-10)
    np.testing.assert_allclose(g[..., 264:], f[..., 264:], atol=1e-10)
    # a collapsed hand (generated motion can do this) gives finite features, not an error
    bad = j.copy()
    bad[0, 5, sk.LEFT] = bad[0, 5, sk.LEFT, :1]
    with pytest.raises(ValueError, match="degenerate"):
        rep.wrist_frames(bad)
    assert np.isfinite(rep.to_evaluator_hand_frames(bad)).all()
    assert rep.to_evaluator_hand_frames(j.astype(np.float32)).dtype == np.float32


# ----------------------------------------------------------------------------------------------
# normalisation statistics

def test_norm_stats_round_trip_and_npz(tmp_path):
    rng = np.random.default_rng(2)
    x = rng.normal(loc=3.0, scale=2.0, size=(40, 7, 288)).astype(np.float32)
    x[..., 5] = 1.25  # constant feature → std 1
    pr = rep.AR_NORM
    st = rep.compute_norm_stats(x, axis=(0, 1), min_std=pr.min_std, eps=pr.eps)
    assert st.mean.shape == (288,) and st.mean.dtype == np.float32 and st.eps == 1e-6
    assert st.std[5] == 1.0 and st.mean[5] == np.float32(1.25)
    x64 = x.astype(np.float64).reshape(-1, 288)
    np.testing.assert_allclose(st.mean, x64.mean(0), rtol=1e-6)
    np.testing.assert_allclose(np.delete(st.std, 5), np.delete(x64.std(0), 5), rtol=1e-5)
    z = st.normalize(x)
    np.testing.assert_allclose(z, (x - st.mean) / (st.std + 1e-6), rtol=1e-6)
    np.testing.assert_allclose(st.denormalize(z), x, atol=1e-5)
    np.savez(tmp_path / "stats.npz", **st.to_npz_dict("ar"))
    with np.load(tmp_path / "stats.npz") as d:
        st2 = rep.NormStats.from_npz_dict(d, "ar")
    np.testing.assert_array_equal(st2.mean, st.mean)
    np.testing.assert_array_equal(st2.std, st.std)
    assert st2.eps == st.eps
    # without the eps key the preset's eps is used
    st3 = rep.NormStats.from_npz_dict({"ar_mean": st.mean, "ar_std": st.std}, "ar")
    assert st3.eps == 1e-6


def test_norm_stats_chunked_stream_equals_in_memory(tmp_path):
    j = np.stack([smooth_clip(s) for s in range(7)])  # (7, T, 2, 21, 3)
    np.save(tmp_path / "motion.npy", j)
    mm = np.load(tmp_path / "motion.npy", mmap_mode="r")
    for kind, fn in (("diffusion", rep.to_diffusion), ("ar", rep.to_ar), ("evaluator", rep.to_evaluator)):
        pr = rep.norm_preset(kind)
        feats = fn(j)
        axes = tuple(range(feats.ndim - len(pr.feature_shape)))
        full = rep.compute_norm_stats(feats, axis=axes, min_std=pr.min_std, eps=pr.eps, chunk_size=10 ** 6)
        streamed = rep.motion_norm_stats(kind, mm, chunk_size=2)  # memory-mapped, 2 clips at a time
        chunked = rep.compute_norm_stats((feats[i:i + 3] for i in range(0, 7, 3)), axis=axes,
                                         min_std=pr.min_std, eps=pr.eps)
        preset = rep.compute_preset_stats(kind, (fn(mm[i:i + 4]) for i in range(0, 7, 4)))
        parts = [rep.preset_moments(kind, fn(mm[i:i + 4])) for i in range(0, 7, 4)]  # the builder's path
        builder = rep.stats_from_moments(kind, *(sum(p[k] for p in parts) for k in range(3)))
        for st in (streamed, chunked, preset, builder):
            assert st.mean.shape == pr.feature_shape and st.eps == pr.eps
            np.testing.assert_allclose(st.mean, full.mean, rtol=1e-6, atol=1e-9)
            np.testing.assert_allclose(st.std, full.std, rtol=1e-6, atol=1e-9)
    ev = rep.motion_norm_stats("evaluator", mm)
    assert np.all(ev.std[:3 * 21] > 0) and np.all(ev.std[63:66] == 1.0)  # right wrist ≡ 0 → std 1


def test_norm_stats_rejects_bad_input():
    with pytest.raises(ValueError, match="axis 0"):
        rep.compute_norm_stats(np.ones((4, 3)), axis=1, min_std=1e-4)
    with pytest.raises(ValueError, match="NaN"):
        rep.compute_norm_stats(np.array([[np.nan, 1.0]]), min_std=1e-4)
    with pytest.raises(ValueError, match="unknown normalisation preset"):
        rep.compute_preset_stats("bogus", np.ones((2, 3)))
