import numpy as np
import pytest

from handx_jax import skeleton as sk


def test_joint_order_and_chains_match_reference():
    # Reference §1.5: MANO order with tips appended.
    assert sk.JOINT_NAMES[13] == "thumb_cmc" and sk.JOINT_NAMES[16] == "thumb_tip"
    assert sk.CHAINS["ring"] == (0, 10, 11, 12, 19) and sk.CHAINS["pinky"] == (0, 7, 8, 9, 20)
    assert sk.TIPS == (16, 17, 18, 19, 20)
    assert sorted(j for c in sk.CHAINS.values() for j in c[1:]) == list(range(1, 21))
    assert len(sk.BONES) == 20 and all(sk.PARENTS[c] == p for p, c in sk.BONES)
    assert sk.flat_index(sk.RIGHT, 0) == 21
    # OpenPose thumb-first order maps onto HandX's MANO order.
    assert sk.OPENPOSE_TO_HANDX[4] == 16 and sk.OPENPOSE_TO_HANDX[8] == 17


def _random_pose(rng, T=5):
    base = rng.normal(size=(2, 21, 3)) * 0.03
    base[0, :, 0] -= 0.15
    base[1, :, 0] += 0.15
    base[:, list(sk.TIPS), 1] += 0.08  # fingertips point toward +y
    return base[None] + rng.normal(size=(T, 2, 21, 3)) * 0.005


def test_canonical_frame_axes():
    rng = np.random.default_rng(0)
    x = _random_pose(rng)
    # Scramble with a random rotation and translation: canonicalisation must undo it.
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    y = x @ q.T + np.array([1.0, -2.0, 0.5])
    c = sk.canonicalize(y)
    f0 = c[0]
    np.testing.assert_allclose(f0[sk.RIGHT, 0], 0, atol=1e-12)
    d = f0[sk.RIGHT, 0] - f0[sk.LEFT, 0]
    assert d[0] > 0 and abs(d[1]) < 1e-9 and abs(d[2]) < 1e-9  # +x: left wrist → right wrist
    tips = f0[:, list(sk.TIPS)].reshape(-1, 3).mean(0) - 0.5 * (f0[0, 0] + f0[1, 0])
    assert tips[1] > 0 and abs(tips[2]) < 1e-9  # +y toward the fingertips
    # Rigid: distances preserved, and the same result as canonicalising the unscrambled input.
    np.testing.assert_allclose(sk.bone_lengths(c), sk.bone_lengths(x), atol=1e-9)
    np.testing.assert_allclose(c, sk.canonicalize(x), atol=1e-9)
    R = sk.canonical_rotation(y)
    assert np.isclose(np.linalg.det(R), 1.0)  # right-handed


def test_canonicalize_rejects_degenerate_frame():
    x = np.zeros((3, 2, 21, 3))
    with pytest.raises(ValueError, match="wrists coincide"):
        sk.canonicalize(x)
