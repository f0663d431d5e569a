"""Corpus v4's motion (issue 40, variety): "chain", three moves in a row (A → B → C → D) instead of corpus v3's one,
through the real generator, annotation, captioner and CLI. Corpus v3 itself is unchanged (its prefix is still
accepted by the archived evaluator v6: tests/test_validity.py)."""

import numpy as np
import pytest

from handx_jax.annotation import events as E
from handx_jax.annotation import descriptors as ft
from handx_jax.synthesis import hand as H
from handx_jax.synthesis import programs as P
from handx_jax.annotation.segment import swings
from handx_jax.synthesis.bimanual import SynthConfig, synth_chunk
from tests.test_synthesis_transition import level0_clean_noisy_reversed

V3 = SynthConfig(motion="transition", segments_per_sequence=1)
V4 = SynthConfig(motion="chain", segments_per_sequence=1)


def _curl(joints_NxTx2x21x3):
    flex = ft.compute_features(np.nan_to_num(joints_NxTx2x21x3.astype(np.float64)),
                               E.ANNOTATIONS["stable"].features).flexion_NxTx2x14
    return E.finger_curl_deg(flex)                                              # (N, T, 2, 4)


def test_chain_needs_one_segment():
    with pytest.raises(ValueError, match="segments_per_sequence=1"):
        SynthConfig(motion="chain")


def test_curl_of_pose_known_answers():
    # The mean of MCP, PIP and DIP (= 2/3 PIP) flexion; hyperextension counts as flexion (interior angle).
    np.testing.assert_allclose(P.curl_of_pose(H.FIST)[:4], (85 + 100 + 200 / 3) / 3)
    np.testing.assert_allclose(P.curl_of_pose(H.FLAT)[:4], 0.0)
    np.testing.assert_allclose(P.curl_of_pose(H.base_pose(-30, 0, 0.0, (0, 0, 0, 0)))[:4], 10.0)
    # ... and it is what the annotation reads from the motion, within coupling and FK geometry.
    chunk = synth_chunk(0, 0, V3)
    ok = np.isfinite(chunk.joints).reshape(len(chunk.joints), -1).all(1)
    fist = [n for n, p in enumerate(chunk.programs) if p[0]["right"] == "fist" and ok[n]]
    assert fist
    end = _curl(chunk.joints[fist])[:, [0, -1], 1]                             # (k, 2 ends, 4)
    assert np.abs(np.abs(end[:, 0] - end[:, 1]) - abs(P.curl_of_pose(H.FIST) - P.curl_of_pose(H.RELAXED))[:4]).max() < 15


def test_next_move_keeps_the_gap_and_a_one_way_finger():
    """From a fist that closed out of a flat hand, every finger has gone one way (curled). A next move that
    opens every finger would read the same played backwards ("closes, then opens"), and one that changes
    nothing is no move: neither is taken. Every finger's curl change stays out of the gist threshold's band."""
    n = 400
    rng = np.random.default_rng(0)
    start = np.tile(H.FLAT, (n, 1))
    held = np.tile(H.FIST, (n, 1)) + rng.normal(0, 3, (n, 16))
    ways = P.finger_ways(start, held)
    assert (ways == 1).all()
    target, which, ways2, mid, dur = P.next_move(rng, ways, held, P.CHAIN_MIDS_S[1], V4)
    assert (which >= 0).all()
    names = {P.CHAIN_TARGETS[i] for i in which}
    assert names.isdisjoint({"flat", "spread", "fist"}) and {"point", "pinch_index"} <= names
    d = np.abs(P.curl_of_pose(H.clip_to_limits(target)) - P.curl_of_pose(held))
    assert (((d < P.CHAIN_STILL_DEG) | (d > P.CHAIN_MOVE_DEG)).all(1) & (d > P.CHAIN_MOVE_DEG).any(1)).all()
    assert ((ways2 == 1) | (ways2 == -1)).any(1).all() and (ways2 == 2).any(1).all()
    lo, hi = P.CHAIN_MIDS_S[1]
    assert ((mid >= lo) & (mid <= hi)).all() and (dur > 0.1).all()
    # A hand that has gone both ways with every finger and holds a pose no target leaves by a clean step
    # has no next move: it holds (-1), and its target is where it is.
    stuck = np.tile(H.base_pose(50, 55, 0.0, (0, 0, 0, 0)), (3, 1))
    t2, w2, _, _, _ = P.next_move(rng, np.full((3, 4), 2), stuck, P.CHAIN_MIDS_S[2], V4)
    assert (w2 == -1).all() and np.array_equal(t2, stuck)
    # The last move ends inside the clip.
    _, _, _, mid3, dur3 = P.next_move(rng, ways, held, P.CHAIN_MIDS_S[2], V4)
    assert (mid3 + dur3 / 2 <= V4.segment_len / V4.fps - P.CHAIN_EDGE_S + 1e-9).all()


def test_chain_moves_several_times_with_swings_clear_of_the_threshold():
    """Corpus v4's premise: hands make up to three moves, and every curl swing of a finger is either large
    (an act) or small (noise): the 20° threshold of the gist has almost no swing near it."""
    ch4, ch3 = synth_chunk(0, 0, V4), synth_chunk(0, 0, V3)
    then = [p[0].get(f"{s}_then") for p in ch4.programs for s in ("left", "right")]
    assert np.mean([t is not None for t in then]) > 0.4
    assert any(t is not None and "," in t for t in then)  # some hands make both later moves
    for ch, name in ((ch4, "v4"), (ch3, "v3")):
        ok = np.isfinite(ch.joints).reshape(len(ch.joints), -1).all(1)
        c = _curl(ch.joints[ok]).transpose(0, 2, 3, 1).reshape(-1, 60)             # (clips·hands·fingers, T)
        s, st, en, d = swings(c, 8.0)
        amp = np.abs(c[s, en - 1] - c[s, st])  # en is one past the swing's last frame
        if name == "v4":
            amp4, per4 = amp, len(s) / ok.sum()
        else:
            per3 = len(s) / ok.sum()
    assert np.mean((amp4 > 16) & (amp4 < 26)) < 0.06
    assert per4 > 1.3 * per3  # more moves: more swings per clip


def test_chain_level0_is_stable_under_noise_and_changes_played_backwards():
    """Through the real annotation and captioner, as for corpus v3; more of level 0 turns played backwards (v3's
    test asks 0.6), and the clips' level 0 varies."""
    _, clean, noisy, rev = level0_clean_noisy_reversed(V4)
    assert np.mean([a == b for a, b in zip(clean, noisy)]) >= 0.9
    assert np.mean([a != b for a, b in zip(clean, rev)]) >= 0.8
    assert len(set(clean)) >= 0.6 * len(clean)
