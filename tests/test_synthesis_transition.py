"""Corpus v3's parts (issue 40, level-0 stability): the transition motion, the finger-curl swings of the
"gist" annotation and the gist level 0, through the real generator, annotation, captioner and CLI."""

import json

import numpy as np
import pytest

from handx_jax.cli import main as handx
from handx_jax.annotation import events as E
from handx_jax.annotation import descriptors as ft
from handx_jax.dataset.build import BuildConfig, recipe
from handx_jax.annotation.caption import TemplateCaptioner
from handx_jax.annotation.caption import gist
from handx_jax.dataset.format import Dataset
from handx_jax.annotation.segment import swings
from handx_jax.synthesis.bimanual import SynthConfig, synth_chunk
from handx_jax.validity import perturb as P

V3 = SynthConfig(motion="transition", segments_per_sequence=1)


def test_swings_known_answers():
    x = np.array([
        [0, 5, 10, 30, 50, 50, 49, 51, 50, 20, 0, 1, 0],   # up to the peak at frame 7, down to frame 10
        [0, 1, -1, 0.5, 0, 1, 0, 0, 1, 0, 0, 0, 0],        # wobbles below the threshold: no swing
        [50, 40, 30, 20, 10, 0, 0, 0, 0, 0, 0, 0, 0],      # one fall, ending where it bottoms out
        [0, 12, 0, 12, 0, 12, 0, 12, 0, 12, 0, 12, 0],     # a 12-unit oscillation: three swings at 10
    ], float)
    s, st, en, d = swings(x, 20.0)
    assert s.tolist() == [0, 0, 2] and st.tolist() == [0, 7, 0] and en.tolist() == [8, 11, 6]
    assert d.tolist() == [1, -1, -1]
    s, st, en, d = swings(x[3:], 10.0)
    assert d.tolist() == [1, -1] * 6 and st.tolist() == list(range(12)) and en.tolist() == list(range(2, 14))
    # Played backwards, every swing turns the other way and the order reverses.
    s2, st2, en2, d2 = swings(x[:1, ::-1], 20.0)
    assert d2.tolist() == [1, -1] and st2.tolist() == [0, 5] and en2.tolist() == [6, 13]  # ties keep the first low


def test_transition_needs_one_segment_and_a_known_motion():
    with pytest.raises(ValueError, match="segments_per_sequence=1"):
        SynthConfig(motion="transition")
    with pytest.raises(ValueError, match="motion"):
        SynthConfig(motion="wobble", segments_per_sequence=1)


def test_the_recipe_of_older_corpora_is_unchanged():
    # Options added for corpus v3 are recorded only when they change the content (every earlier corpus
    # keeps its identity); a v3 recipe records both.
    old = recipe(BuildConfig(clips=10))["options"]
    assert "motion" not in old["synth"] and "finger_curl_swing_deg" not in old["annotation"]
    from handx_jax.dataset.build import with_reading
    new = recipe(with_reading(BuildConfig(clips=10, synth=V3), "gist"))["options"]
    assert new["synth"]["motion"] == "transition" and new["annotation"]["finger_curl_swing_deg"] == 20.0


def _curl_ranges(joints_NxTx2x21x3):
    """Whole-finger curl range (deg) per (clip, hand, finger) and its net change, on the stable features."""
    flex = ft.compute_features(np.nan_to_num(joints_NxTx2x21x3.astype(np.float64)),
                               E.ANNOTATIONS["stable"].features).flexion_NxTx2x14
    curl = E.finger_curl_deg(flex)                                              # (N, T, 2, 4)
    return np.ptp(curl, axis=1), np.abs(curl[:, -1] - curl[:, 0])


def test_transition_motion_leaves_a_gap_between_acting_and_idle_fingers():
    """Corpus v3's premise: a finger an action closes or opens travels far (and once), a finger it leaves
    barely moves, so a 20° threshold has no fingers sitting on it."""
    chunk = synth_chunk(0, 0, V3)
    rng_, net = _curl_ranges(chunk.joints)
    closing, resting = [], []
    for n, prog in enumerate(chunk.programs):
        if not np.isfinite(chunk.joints[n]).all():
            continue
        seg = prog[0]
        for h, side in enumerate(("left", "right")):
            if seg[side] in ("fist", "open_spread", "grasp", "thumbs_up"):       # all four fingers act
                closing.append((rng_[n, h], net[n, h]))
            elif seg[side] in ("spread_close", "wave", "wrist_roll"):            # no finger curls
                resting.append(rng_[n, h])
    closing_r = np.array([r for r, _ in closing])
    assert len(closing) >= 10 and len(resting) >= 10
    assert closing_r.min() > 35.0 and np.max(resting) < 18.0   # the gist threshold, 20°, sits between
    # Once, not back and forth: the net change is the whole range.
    assert min((nt / r).min() for r, nt in closing) > 0.9
    # The oscillating corpus (v2) has no such gap: its curl ranges fill the band between.
    v2 = synth_chunk(0, 0, SynthConfig()).joints                      # 4 segments of 60 frames per sequence
    r2, _ = _curl_ranges(v2.reshape((-1, 60) + v2.shape[2:]))
    assert np.mean((r2 > 15) & (r2 < 35)) > 0.15
    assert np.mean((rng_ > 15) & (rng_ < 35)) < 0.08


def test_gist_level0_words_one_decision_per_finger():
    def hand(**pats):  # finger=[(direction, depth), ...]
        return {"finger_curl": {f: [{"start": 0, "end": 5, "direction": d, "depth": p} for d, p in pats.get(f, ())]
                                for f in E.CURL_FINGERS}}
    fist = [("curl", "full")]
    assert gist.hand_gist(hand(index=fist, middle=fist, ring=fist, pinky=fist)) == "the hand closes into a fist"
    half = [("curl", "partial")]
    assert gist.hand_gist(hand(index=half, middle=half, ring=half, pinky=half)) == "the hand closes halfway"
    # A depth that differs splits the group: three fingers into a fist, one only partway.
    assert gist.hand_gist(hand(index=half, middle=fist, ring=fist, pinky=fist)) == \
        "the index finger curls partway and the middle, ring and pinky fingers curl tightly"
    assert gist.hand_gist(hand(index=[("straighten", "partial")], middle=fist, ring=fist, pinky=fist)) == \
        "the index finger straightens and the middle, ring and pinky fingers curl tightly"
    out = [("straighten", "full")]
    assert gist.hand_gist(hand(middle=out, ring=out, pinky=out)) == \
        "the middle, ring and pinky fingers straighten from a tight curl"
    assert gist.hand_gist(hand(index=[("curl", "full"), ("straighten", "full"), ("curl", "full")])) == \
        "the index finger flexes repeatedly"
    assert gist.hand_gist(hand()) == gist.STILL
    rel = {"finger_tip_contact": {"left_index_tip, right_index_tip": [{"start": 3, "end": 9, "state": "contact"}]},
           "palm_palm_distance": {"left_palm, right_palm": [{"start": 0, "end": 60, "state": "near"}]}}
    assert gist.touch_frames(rel, 60) == (0, 6) and gist.interaction(rel, 60) == "the fingertips touch"
    rel["finger_tip_contact"]["left_index_tip, right_index_tip"][0]["end"] = 8
    assert gist.interaction(rel, 60) == "the hands stay apart"   # 5 frames: a graze, not a touch
    # The palm distance is a state series: palms that meet at frame 29 and stay touch for the 31 frames left,
    # though no event of the list is a "contact" hold.
    palms = rel["palm_palm_distance"]["left_palm, right_palm"] = [
        {"start": 20, "end": 30, "start_state": "far", "end_state": "contact", "speed": "fast"}]
    assert gist.touch_frames(rel, 60) == (31, 5) and gist.interaction(rel, 60) == "the palms touch"
    # A brief clap (contact from frame 29 until the release starts at 32) is shorter than a touch.
    palms.append({"start": 32, "end": 40, "start_state": "contact", "end_state": "far", "speed": "fast"})
    assert gist.touch_frames(rel, 60) == (4, 5) and gist.interaction(rel, 60) == "the hands stay apart"
    rel["palm_palm_distance"]["left_palm, right_palm"] = [{"start": 0, "end": 60, "state": "contact"}]
    assert gist.interaction(rel, 60) == "the palms touch"


def level0_clean_noisy_reversed(cfg: SynthConfig, clips: int = 40):
    """The first ``clips`` whole clips of chunk (0, 1) and their gist level-0 triples through the real
    annotation and captioner: clean, under 1 mm of white finger noise, and played backwards."""
    chunk = synth_chunk(0, 1, cfg)
    ok = np.isfinite(chunk.joints).reshape(len(chunk.joints), -1).all(1)
    x = chunk.joints[ok][:clips]
    cap = TemplateCaptioner("per_fact")
    l0 = lambda c: [tuple(cap.caption(r, seed=7)[0].values()) for r in E.annotate(c, E.ANNOTATIONS["gist"])]
    return x, l0(x), l0(P.apply("white", x, 0.001, 0)), l0(x[:, ::-1].copy())


def test_gist_reading_is_stable_under_noise_and_turns_with_time():
    """Through the real annotation and captioner: 1 mm of white finger noise leaves the gist level 0 of
    corpus v3 clips unchanged, and playing them backwards changes it (closes ↔ opens)."""
    x, clean, noisy, rev = level0_clean_noisy_reversed(V3)
    cfg = E.ANNOTATIONS["gist"]
    assert all("finger_curl" in r["left_hand_events"] for r in E.annotate(x[:2], cfg))
    assert np.mean([a == b for a, b in zip(clean, noisy)]) >= 0.9
    assert np.mean([a != b for a, b in zip(clean, rev)]) >= 0.6
    swap = {"The hand closes into a fist.": "The hand opens out of a fist.", "The hand closes halfway.": "The hand opens."}
    swap |= {v: k for k, v in swap.items()}
    seen = 0
    for a, b in zip(clean, rev):  # a whole hand that closes opens when played backwards, as far as it closed
        for ta, tb in zip(a[:2], b[:2]):
            if ta in swap:
                seen += 1
                assert tb == swap[ta]
    assert seen >= 10
    # The reference and stable readings carry no finger_curl and keep their composed level 0.
    assert "finger_curl" not in E.annotate(x[:1], E.ANNOTATIONS["stable"])[0]["left_hand_events"]


@pytest.mark.parametrize("motion", ["transition", "chain"])  # corpus v3, and corpus v4 (tests/test_synthesis_chain.py)
def test_corpus_v3_through_the_cli(tmp_path, motion):
    out = tmp_path / motion
    assert handx(["data", "synth", "--clips", "48", "--out", str(out), "--workers", "1", "--quiet",
                  "--motion", motion, "--annotation", "gist"]) == 0
    ds = Dataset.open(out)
    opts = ds.meta["recipe"]["options"]
    assert opts["synth"]["motion"] == motion and opts["synth"]["segments_per_sequence"] == 1
    assert opts["clip"]["tau_hand"] == opts["clip"]["tau_avg"] == 7.0
    # The build's report counts each hand's later moves (corpus v4 only).
    counts = json.loads((out / "report.json").read_text())["program_counts"]
    assert any(k.startswith("right_then:") for k in counts) == (motion == "chain")
    from handx_jax.dataset.build import reading_of
    assert reading_of(ds) == ("gist", "per_fact")
    hands = {t[k][0] for t in ds.texts for k in ("left", "right")}
    words = ("The hand ", "The index", "The middle", "The ring", "The pinky", "The fingers hold")
    assert hands and all(h.startswith(words) for h in hands)
    assert {t["interaction"][0] for t in ds.texts} <= {"The palms touch.", "The fingertips touch.",
                                                      "The hands stay apart."}


def test_transition_clips_that_move_at_all_pass_the_filter():
    """With corpus v3's clip filter (7 °/s) a pinch passes, which the paper's 25 °/s drops, and an idle hand
    still does not (it is what the filter is for)."""
    from handx_jax.dataset import clips as C
    from handx_jax.dataset.build import with_motion
    cfg = with_motion(BuildConfig(clips=10), "transition")
    chunk = synth_chunk(0, 0, cfg.synth)
    ok = np.isfinite(chunk.joints).reshape(len(chunk.joints), -1).all(1)
    inten = C.hand_intensity(np.nan_to_num(chunk.joints))
    act = {"pinch": [], "idle": []}
    for n, prog in enumerate(chunk.programs):
        for h, side in enumerate(("left", "right")):
            name = prog[0][side]
            if ok[n] and (name.startswith("pinch_") or name == "idle"):
                act["pinch" if name != "idle" else "idle"].append(inten[n, h])
    assert len(act["pinch"]) >= 3 and len(act["idle"]) >= 3
    assert min(act["pinch"]) > cfg.clip.tau_hand > max(act["idle"])
    assert max(act["pinch"]) < BuildConfig().clip.tau_hand
