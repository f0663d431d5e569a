"""Tests for the procedural two-hand corpus (handx_jax/synthesis/bimanual.py, hand.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from handx_jax import skeleton as sk
from handx_jax.dataset import clips
from handx_jax.synthesis import bimanual as synth
from handx_jax.synthesis import programs as synth_programs
from handx_jax.synthesis import hand as H

SMALL = synth.SynthConfig(chunk_size=16)
CLEAN = dataclasses.replace(SMALL, noise_deg=0.0, white_noise_deg=0.0, wrist_noise_m=0.0, white_noise_m=0.0, defect_prob=0.0)
L = synth.SynthConfig().segment_len


def _segments(chunk: synth.SynthChunk, cfg: synth.SynthConfig):
    """Yield (sequence, segment, program, joints (L, 2, 21, 3)) for every segment of a chunk."""
    for n, row in enumerate(chunk.programs):
        for s, prog in enumerate(row):
            yield n, s, prog, chunk.joints[n, s * cfg.segment_len:(s + 1) * cfg.segment_len]


@pytest.fixture(scope="module")
def interacting() -> tuple[synth.SynthChunk, synth.SynthConfig]:
    cfg = dataclasses.replace(CLEAN, chunk_size=64, interaction_prob=1.0, idle_prob=0.0)
    return synth.synth_chunk(7, 0, cfg), cfg


def test_vocabularies():
    assert len(synth.ACTIONS) >= 12 and len(synth.INTERACTIONS) >= 8
    assert {"pinch_index", "pinch_middle", "pinch_ring", "pinch_pinky"} <= set(synth.ACTIONS)


def test_shapes_dtype_and_programs():
    c = synth.synth_chunk(0, 0, SMALL)
    T = SMALL.segments_per_sequence * SMALL.segment_len
    assert c.joints.shape == (SMALL.chunk_size, T, 2, sk.NUM_JOINTS, 3) and c.joints.dtype == np.float32
    assert len(c.programs) == SMALL.chunk_size
    for row in c.programs:
        assert len(row) == SMALL.segments_per_sequence
        for p in row:
            assert set(p) == {"left", "right", "interaction", "idle"}
            if p["idle"]:
                assert p["interaction"] is None
            else:
                assert p["left"] in synth.ACTIONS and p["right"] in synth.ACTIONS
                assert p["interaction"] is None or p["interaction"] in synth.INTERACTIONS


def test_deterministic_per_seed_and_chunk():
    a, b = synth.synth_chunk(3, 1, SMALL), synth.synth_chunk(3, 1, SMALL)
    assert np.array_equal(a.joints, b.joints, equal_nan=True) and a.programs == b.programs
    for other in (synth.synth_chunk(4, 1, SMALL), synth.synth_chunk(3, 2, SMALL)):
        assert not np.array_equal(a.joints, other.joints, equal_nan=True)


def test_bone_lengths_constant_and_anatomical():
    c = synth.synth_chunk(1, 0, CLEAN)
    bones = sk.bone_lengths(c.joints)                                   # (N, T, 2, 20)
    assert np.abs(bones - bones[:, :1]).max() < 2e-5                    # rigid bones over time
    assert np.abs(bones[:, :, 0] - bones[:, :, 1]).max() < 2e-5         # one person: equal hands
    index_proximal = bones[:, 0, 0, sk.JOINT_INDEX["index_pip"] - 1]    # bone k ends at joint k+1
    assert index_proximal.min() > 0.035 and index_proximal.max() < 0.055
    sizes = bones[:, 0, 0].sum(-1)
    assert sizes.max() / sizes.min() > 1.1                              # hand size varies


def test_noisy_hands_stay_rigid():
    """Issue 14.4: tracking noise lives in the angles and wrist pose, so with the default noise every
    bone keeps its length within a sequence (MANO-like), the two hands of one person match, and
    the noise is still there (the fingers' angles differ from the noise-free run by degrees)."""
    cfg = dataclasses.replace(SMALL, defect_prob=0.0)
    noisy = synth.synth_chunk(2, 0, cfg).joints
    bones = sk.bone_lengths(noisy).astype(np.float64)                   # (N, T, 2, 20)
    rel_std = bones.std(1) / bones.mean(1)                               # per sequence, hand and bone
    assert rel_std.max() < 0.005
    assert np.abs(bones[:, :, 0] / bones[:, :, 1] - 1).max() < 1e-3     # per-person bone scale kept
    clean = synth.synth_chunk(2, 0, dataclasses.replace(CLEAN, defect_prob=0.0)).joints
    d = clips.interior_angles_deg(noisy) - clips.interior_angles_deg(clean)
    assert 0.5 < np.sqrt(np.mean(d ** 2)) < 5.0
    # Clips cut from the canonicalised sequences (what the corpus stores) are rigid as well.
    for seq in noisy[:4]:
        c, _, _, _ = clips.extract_clips(sk.canonicalize(seq), clips.ClipConfig(tau_hand=0.0, tau_avg=0.0))
        b = sk.bone_lengths(c).astype(np.float64)
        assert len(c) and (b.std(1) / b.mean(1)).max() < 0.005


def _signed_mcp_flexion_deg(joints_x2x21x3: np.ndarray) -> np.ndarray:
    """Signed MCP flexion of index..pinky (+ toward the palm), (..., 2, 4), from joints alone."""
    w, i, p = joints_x2x21x3[..., 0, :], joints_x2x21x3[..., 1, :], joints_x2x21x3[..., 7, :]
    n = np.cross(i - w, p - w)
    n[..., 0, :] *= -1.0                                                # the left hand is mirrored
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    mcp, pip = [1, 4, 10, 7], [2, 5, 11, 8]
    bone = joints_x2x21x3[..., pip, :] - joints_x2x21x3[..., mcp, :]
    bone /= np.linalg.norm(bone, axis=-1, keepdims=True)
    return np.degrees(np.arcsin(np.clip(np.einsum("...fc,...c->...f", bone, n), -1, 1)))


def test_joint_limits_and_hyperextension():
    c = synth.synth_chunk(2, 0, dataclasses.replace(CLEAN, chunk_size=32))
    ang = clips.interior_angles_deg(c.joints)                           # (N, T, 2, 15)
    names = [sk.JOINT_NAMES[j] for _, j, _ in sk.INTERIOR_TRIPLES]
    limit = {"mcp": 91.0, "pip": 106.0, "dip": 71.0, "thumb_ip": 81.0}
    for k, name in enumerate(names):
        kind = name if name == "thumb_ip" else name.split("_")[-1]
        if kind in limit:
            assert ang[..., k].max() <= limit[kind], name
    flex = _signed_mcp_flexion_deg(c.joints)
    assert flex.min() > -45.0                                           # no finger snapped back
    assert (flex < -20.0).any()                                         # but hyperextension occurs


def test_fingertip_contact_arises_and_releases(interacting):
    chunk, cfg = interacting
    found = 0
    for _, _, prog, x in _segments(chunk, cfg):
        if prog["interaction"] != "fingertip_touch":
            continue
        found += 1
        d = np.linalg.norm(x[:, 0, 17] - x[:, 1, 17], axis=-1)
        assert d.min() < 0.02                                           # index tips meet
        assert d.max() > d.min() + 0.01                                 # and the distance changes
    assert found >= 2


def test_palm_and_grip_interactions_touch(interacting):
    chunk, cfg = interacting
    seen, palm_min = set(), []
    for _, _, prog, x in _segments(chunk, cfg):
        kind = prog["interaction"]
        if kind in ("palm_press", "clap"):
            # Palm centroids sit ~2 cm apart when the palm surfaces touch; thumbs and cupped
            # pinkies can hold them a little further apart.
            cen = x[:, :, [0, 1, 4, 10, 7]].mean(2)
            palm_min.append(np.linalg.norm(cen[:, 0] - cen[:, 1], axis=-1).min())
            assert palm_min[-1] < 0.08
        elif kind in ("grip_finger", "grip_wrist", "tap_palm", "steeple", "fist_bump", "interlock"):
            d = np.linalg.norm(x[:, 0, :, None] - x[:, 1, None], axis=-1).min(axis=(1, 2))
            assert d.min() < 0.02, kind
        else:
            continue
        seen.add(kind)
    assert len(seen) >= 5
    assert np.median(palm_min) < 0.04


def test_hands_apart_without_interaction():
    cfg = dataclasses.replace(CLEAN, chunk_size=32, interaction_prob=0.0)
    c = synth.synth_chunk(5, 0, cfg)
    d = np.linalg.norm(c.joints[:, :, 0, :, None] - c.joints[:, :, 1, None], axis=-1).min(axis=(2, 3))
    assert d.min() > 0.05
    wrist = np.linalg.norm(c.joints[:, :, 0, 0] - c.joints[:, :, 1, 0], axis=-1)
    assert wrist.min() > 0.10 and wrist.max() < 0.7


def test_intensity_filter_keeps_motion_and_drops_idle():
    cfg = dataclasses.replace(SMALL, chunk_size=48, defect_prob=0.0, idle_prob=0.2)
    c = synth.synth_chunk(11, 0, cfg)
    windows = c.joints.reshape(-1, cfg.segment_len, 2, sk.NUM_JOINTS, 3)
    idle = np.array([p["idle"] for row in c.programs for p in row])
    keep = clips.keep_mask(clips.hand_intensity(windows))
    assert idle.sum() >= 5 and (~idle).sum() >= 100
    assert keep[~idle].mean() >= 0.9
    assert not keep[idle].any()


def test_clean_sequences_have_no_defective_frames():
    c = synth.synth_chunk(6, 0, dataclasses.replace(SMALL, defect_prob=0.0))
    for seq in c.joints:
        masks = clips.defective_frames(seq)
        assert not any(m.any() for m in masks.values()), {k: int(m.sum()) for k, m in masks.items()}
        _, _, _, rep = clips.extract_clips(seq)
        assert rep.windows == SMALL.segments_per_sequence


def test_defects_are_flagged():
    c = synth.synth_chunk(6, 0, dataclasses.replace(SMALL, defect_prob=1.0))
    kinds = set()
    for seq in c.joints:
        masks = clips.defective_frames(seq)
        bad = [k for k, m in masks.items() if m.any()]
        assert bad
        kinds.update(bad)
    assert {"nonfinite", "jump"} <= kinds


def test_pinch_poses_touch():
    geom = H.hand_geometry(np.ones(1), np.zeros((1, 5, 3)))
    for finger in range(4):
        for flat in (False, True):
            j = H.hand_fk(H.couple_neighbours(np.array(H.pinch_pose(finger, flat)))[None], geom)[0]
            tip = sk.CHAINS[("index", "middle", "ring", "pinky")[finger]][4]
            assert np.linalg.norm(j[16] - j[tip]) < 0.006


def test_closed_form_angles_match_fk():
    rng = np.random.default_rng(0)
    pose = rng.uniform(H.LIMITS_LO_16, H.LIMITS_HI_16, (200, H.NUM_CHANNELS))
    j = H.hand_fk(pose, H.hand_geometry(np.ones(1), np.zeros((1, 5, 3))))
    measured = clips.interior_angles_deg(np.stack([j, j], 1))[:, 0]
    assert np.abs(measured - H.interior_angles_from_pose(pose)).max() < 0.05


def test_intensity_top_up_is_one_coordinated_gesture():
    """The top-up moves the free fingers together (shared profile, small per-finger variation),
    leaves the action's fixed finger alone and vanishes at the segment ends."""
    cfg = synth.SynthConfig(chunk_size=6, segments_per_sequence=1)
    N, L = cfg.chunk_size, cfg.segment_len
    acts = np.array([synth.ACTIONS.index(a) for a in ("ok_sign", "pinch_ring", "fist", "ok_sign", "point", "claw")])
    prog = synth_programs.Programs(idle_NxS=np.zeros((N, 1), bool), inter_NxS=np.full((N, 1), -1),
                           act_NxSx2=np.repeat(acts[:, None, None], 2, 2), pairing_NxS=np.zeros((N, 1), np.int64),
                           offset_NxS=np.zeros((N, 1)), flat_NxS=np.zeros((N, 1), bool))
    pose = np.broadcast_to(H.RELAXED, (N, 1, L, 2, H.NUM_CHANNELS)).copy()          # a still hand
    out = synth._raise_intensity(np.random.default_rng(0), pose, prog, cfg)
    omega = synth._hand_intensity_from_pose(out, cfg.fps)
    assert (omega >= cfg.min_intensity_dps).all()
    delta = (out - pose)[:, 0, :, :, H.MCP]                                           # (N, L, 2, 4)
    assert np.abs(delta[:, [0, -1]]).max() < 1.0                                      # zero at both ends
    for n, a in enumerate(synth.ACTIONS[i] for i in acts):
        free = np.flatnonzero(synth_programs.FREE_FINGERS[a])
        fixed = np.flatnonzero(~synth_programs.FREE_FINGERS[a])
        assert not fixed.size or np.abs(delta[n][..., fixed]).max() == 0.0                # the pinch keeps its contact
        for h in range(2):
            d = delta[n, :, h][:, free]
            amp = np.ptp(d, axis=0)
            assert amp.min() > 0.8 * amp.max()                                        # similar amplitudes
            c = np.corrcoef(d.T)
            assert c[np.triu_indices(len(free), 1)].min() > 0.9                       # one shared rhythm


def test_stored_motion_survives_an_ulp_change_in_sin_cos(monkeypatch):
    """Issue 14.5: numpy builds differ in the last bit of sin/cos (SIMD kernels). FK runs in float64,
    so such a change stays below the float32 the corpus stores; with float32 FK (generator version
    ≤ 2) it moved ~all stored joints by an ulp and flipped ~0.6 % of the captions downstream."""
    class UlpNumpy:
        def __getattr__(self, name):
            return getattr(np, name)

        @staticmethod
        def sin(x):
            return np.nextafter(np.sin(x), np.inf)

        @staticmethod
        def cos(x):
            return np.nextafter(np.cos(x), -np.inf)

    cfg = dataclasses.replace(SMALL, chunk_size=8)
    ref = synth.synth_chunk(4, 0, cfg).joints
    monkeypatch.setattr(H, "np", UlpNumpy())
    H.pinch_pose.cache_clear()
    try:
        moved = synth.synth_chunk(4, 0, cfg).joints
    finally:
        monkeypatch.undo()
        H.pinch_pose.cache_clear()
    differ = np.mean(~((ref == moved) | (np.isnan(ref) & np.isnan(moved))))
    assert differ < 1e-4, f"{differ:.2%} of the stored joint values changed"
