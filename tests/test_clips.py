import numpy as np

from handx_jax import skeleton as sk
from handx_jax.dataset import clips


def _straight_hand():
    """A flat hand: wrist at origin, fingers along +y, 4 cm phalanges (per finger chain)."""
    j = np.zeros((21, 3))
    for f, x0 in zip(sk.FINGER_NAMES, (-0.03, -0.015, 0.0, 0.015, 0.03)):
        chain = sk.CHAINS[f]
        for s, joint in enumerate(chain[1:], start=1):
            j[joint] = [x0, 0.04 * s, 0.0]
    return j


def _bend(hand, finger, angle_rad):
    """Rotate everything distal to the finger's proximal joint about the x axis."""
    h = hand.copy()
    chain = sk.CHAINS[finger]
    pivot = h[chain[1]].copy()
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    for joint in chain[2:]:
        h[joint] = (h[joint] - pivot) @ R.T + pivot
    return h


def test_interior_angle_known_value():
    h = _bend(_straight_hand(), "middle", np.deg2rad(40))
    ang = clips.interior_angles_deg(np.stack([h, h]))  # (2, 15)
    tri = list(sk.INTERIOR_TRIPLES)
    assert np.isclose(ang[0, tri.index((0, 4, 5))], 40.0, atol=1e-3)  # middle MCP
    assert np.isclose(ang[0, tri.index((4, 5, 6))], 0.0, atol=1e-3)


def test_intensity_matches_eq_e():
    # Middle MCP sweeps 0 → 60° over 60 frames: ω = 60°/59 frames * 30 fps at that joint, weight 9.
    T = 60
    angles = np.linspace(0, np.deg2rad(60), T)
    seq = np.stack([np.stack([_bend(_straight_hand(), "middle", a)] * 2) for a in angles])  # (T, 2, 21, 3)
    inten = clips.hand_intensity(seq[None])
    expected = (60 / 59 * 30) * 9 / (13 * 5)  # only the index MCP moves; Σλ = 5·(9+3+1)
    np.testing.assert_allclose(inten, [[expected, expected]], rtol=1e-4)


def test_keep_rule():
    i = np.array([[30, 30], [24, 40], [40, 24], [26, 26], [25, 35]], float)
    np.testing.assert_array_equal(clips.keep_mask(i), [True, False, False, False, True])


def test_windows_around_defects():
    valid = np.ones(300, bool)
    valid[70] = False  # run [0,70) → 1 window; run [71,300) → 3 windows
    assert clips.window_starts(valid) == [0, 71, 131, 191]
    assert clips.valid_intervals(valid) == [(0, 70), (71, 300)]
    assert clips.window_starts(np.ones(59, bool)) == []


def test_extract_clips_reports_reasons():
    T = 250
    rng = np.random.default_rng(0)
    angles = np.deg2rad(45 + 40 * np.sin(np.arange(T) / 3.0))  # lively index finger on both hands
    seq = np.stack([np.stack([_bend(_straight_hand(), "middle", a)] * 2) for a in angles])
    seq[:, 1, :, 0] += 0.2
    seq = seq + rng.normal(size=seq.shape) * 1e-4
    seq[100] = np.nan
    seq[200:, 1, 17] += 0.5  # right index tip jumps at frame 200 and stays: a broken bone from there
    c, starts, inten, rep = clips.extract_clips(seq)
    assert rep.defective_frames["nonfinite"] == 1
    assert rep.defective_frames["jump"] + rep.defective_frames["broken_pose"] >= 50
    # Valid runs: [0,100) and [101,199) (frames 199-200 jump, ≥200 broken) → one window each.
    assert list(starts) == [0, 101] and rep.windows == 2 and rep.kept == 2
    assert rep.frames_in_short_runs == (100 - 60) + (98 - 60)
    assert (inten > 25).all()
    assert c.shape[1:] == (60, 2, 21, 3)
