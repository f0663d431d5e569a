"""Corpus v5 (issue 55): the two hands resolved against the hand surface (motion "surface") and their contacts
read from it (annotation "surface"). A small prefix built by the real build is checked on EVERY clip against
issue 55's targets, and the contact stage and the surface reading against cases with known answers. Corpus v4
is untouched (its prefixes still pass tests/test_validity.py and tests/test_synthesis_chain.py)."""

import dataclasses

import numpy as np
import pytest

import handmade_hands as hh
from handx_jax import hand_surface as hs
from handx_jax import skeleton as sk
from handx_jax.annotation import events as E
from handx_jax.dataset.build import BuildConfig, build_corpus, with_motion, with_reading
from handx_jax.annotation.caption import gist
from handx_jax.dataset.format import Dataset
from handx_jax.synthesis import audit, surface


@pytest.fixture(scope="module")
def v5_prefix(tmp_path_factory):
    """The first clips of corpus v5 (seed 0): one generator chunk, built and annotated by the real build."""
    out = tmp_path_factory.mktemp("v5") / "P"
    cfg = with_motion(with_reading(BuildConfig(clips=48, seed=0, workers=1), "surface"), "surface")
    build_corpus(out, cfg, progress=False)
    ds = Dataset.open(out)
    x = np.asarray(ds.motion)
    return x, ds.events, [t["interaction"][0] for t in ds.texts], audit.audit(
        x, ds.events, [t["interaction"][0] for t in ds.texts])


def test_every_clip_of_a_v5_prefix_meets_the_targets(v5_prefix):
    x, events, inter, a = v5_prefix
    n = len(x)
    assert n == 48
    # Enough of both kinds for the per-clip checks to mean something.
    assert a["touch"].sum() >= 8 and a["apart"].sum() >= 8
    assert np.all(a["pen_1cm"] <= 0.01), a["pen_1cm"].max()
    assert np.all(a["depth_mm"] <= 1.0), a["depth_mm"].max()
    assert np.all(a["nontip_mm"] >= 10.0), np.sort(a["nontip_mm"])[:3]
    assert not a["apart_overlap"].any()
    assert not a["touch_without_contact"].any()
    # "Apart" is no surface contact at all; every record says where the surfaces touch.
    for r, t in zip(events, inter):
        sc = r["two_hand_relationships"]["surface_contact"]
        assert (t == audit.APART) == (not sc["left_hand, right_hand"])


def test_the_contact_stage_known_answers():
    # Two flat right hands (the handmade hand, joints at z = 0), one 4 mm above the other: their palm capsules
    # overlap by 2 r_palm − 4 mm. Without a contact program (gap NaN) the stage pushes them to the 2 cm gap;
    # with gap 0 they come to rest touching; a pair 10 cm apart asked for 5 mm is pulled to 5 mm.
    h = hh.right_hand() * np.array([1.0, 1.0, 0.0])
    J0 = np.stack([h, h])[None, None].repeat(3, 1)                                 # (1, 3, 2, 21, 3)
    tr = np.zeros((1, 3, 2, 3))
    tr[0, :2, 1, 2] = 0.004
    tr[0, 2, 1, 2] = 0.10
    gap = np.array([[np.nan, 0.0, 0.005]])
    before = hs.in_batches(hs.interhand_signed_distance, (J0 + tr[..., None, :])[0])
    np.testing.assert_allclose(before[:2], 0.004 - 2 * hs.PALM_RADIUS_M, atol=1e-6)
    # One sequence of 3 frames: the temporal smoothing mixes them, and the solve after it restores each.
    tr2, sd = surface.resolve_translations(J0, tr, gap)
    after = hs.in_batches(hs.interhand_signed_distance, (J0 + tr2[..., None, :])[0])
    np.testing.assert_allclose(after, sd[0], atol=1e-6)
    assert after[0] >= surface.MIN_GAP_M - surface.TOLERANCE_M
    assert after[1] == pytest.approx(0.0, abs=surface.TOLERANCE_M)
    assert after[2] == pytest.approx(0.005, abs=surface.TOLERANCE_M)
    # Both hands move, in opposite directions by equal amounts (the right one up: it started above).
    move = tr2 - tr
    np.testing.assert_allclose(move[0, :, 0], -move[0, :, 1], atol=1e-9)
    assert move[0, 0, 1, 2] > 0


def test_surface_reading_touches_are_surface_contacts():
    # A right hand pointing its index along −x (the other fingers curled 90° at the MCP, so the index tip is
    # the hand's farthest point along −x) and its mirror image across a plane beyond the tip: the index tips
    # face each other `gap` apart, and so do the distal capsules' rounded ends (each ends at its tip), so the
    # surface distance is the gap. 15 mm: under the 2 cm keypoint threshold (gist reads a fingertip touch),
    # but the surfaces are apart (the surface reading: no touch); 3 mm: both readings see the touch.
    h = hh.right_hand(bends={("middle", 1): 90, ("ring", 1): 90, ("pinky", 1): 90})
    r = h @ np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])      # y → −x
    tip = r[sk.JOINT_INDEX["index_tip"]]
    assert tip[0] == pytest.approx(r[:, 0].min())
    frames = []
    for gap in [0.015] * 30 + [0.003] * 30:
        left = r * [-1, 1, 1] + [2 * tip[0] - gap, 0, 0]                         # mirrored across x = tip − gap/2
        frames.append(np.stack([left, r]))
    x = np.asarray(frames, np.float32)[None]
    d_tips = np.linalg.norm(x[0, :, 0, sk.JOINT_INDEX["index_tip"]] - x[0, :, 1, sk.JOINT_INDEX["index_tip"]], axis=-1)
    np.testing.assert_allclose(d_tips, [0.015] * 30 + [0.003] * 30, atol=1e-6)
    g = E.annotate(x, E.ANNOTATIONS["gist"])[0]["two_hand_relationships"]
    s = E.annotate(x, E.ANNOTATIONS["surface"])[0]["two_hand_relationships"]
    key = "left_index_tip, right_index_tip"
    assert [(e["start"], e["end"]) for e in g["finger_tip_contact"][key]] == [(0, 60)]
    sd = hs.in_batches(hs.interhand_signed_distance, x[0])
    np.testing.assert_allclose(sd, [0.015] * 30 + [0.003] * 30, atol=1e-5)
    assert [(e["start"], e["end"]) for e in s["finger_tip_contact"][key]] == [(30, 60)]
    assert [(e["start"], e["end"]) for e in s["surface_contact"]["left_hand, right_hand"]] == [(30, 60)]
    assert gist.interaction(s, 60) == "the fingertips touch"
    # The surface reading is off in every earlier reading (their corpora keep their identity).
    assert all(dataclasses.asdict(c)["surface_contact_m"] == 0.0 for k, c in E.ANNOTATIONS.items() if k != "surface")
