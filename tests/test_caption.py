"""Tests for the captioners and the LLM prompt (handx_jax/data/caption.py)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from handx_jax.data import caption as cap
from handx_jax.data import events as ev
from handx_jax.io import DataError
from handmade_hands import clip, mirror, pair, right_hand


def _record(bend_fingers=("index", "middle"), touch=True, move=0.3):
    frames = []
    for t in range(60):
        bend = min(max((t - 10) * 6.0, 0.0), 90.0)
        h = right_hand({(f, lvl): bend for f in bend_fingers for lvl in (1, 2, 3)})
        fr = pair(mirror(right_hand()), h)
        fr[0] += [min(max(t - 30, 0), 20) * move / 30.0, 0.0, 0.0]  # left wrist moves right on frames 30–49
        frames.append(fr)
    x = clip(frames)
    if touch:
        for t in range(40, 50):
            x[0, t, 0, 16] = x[0, t, 1, 17] + [0.004, 0, 0]  # left thumb tip on the right index tip
    return ev.annotate(x, ids=["c0"])[0]


@pytest.fixture(scope="module")
def record():
    return _record()


def test_five_levels_with_three_texts(record):
    out = cap.TemplateCaptioner().caption(record, seed=0)
    assert len(out) == 5
    for lv in out:
        assert set(lv) == {"left", "right", "interaction"}
        assert all(isinstance(v, str) and v.strip() for v in lv.values())
    lengths = [sum(len(v) for v in lv.values()) for lv in out]
    assert lengths[0] < lengths[2] < lengths[4]


def test_determinism_and_seed_variety(record):
    c = cap.TemplateCaptioner()
    assert c.caption(record, seed=3) == c.caption(record, seed=3)
    texts = {json.dumps(c.caption(record, seed=s)) for s in range(12)}
    assert len(texts) >= 6


def test_content_names_fingers_contact_and_wrist(record):
    out = cap.TemplateCaptioner().caption(record, seed=1)
    right4, left4, inter4 = out[4]["right"], out[4]["left"], out[4]["interaction"]
    assert "index and middle fingers" in right4
    assert re.search(r"full bend|fully bent|tight curl|flex(es)? fully", right4)
    assert "to the right" in left4 and re.search(r"quickly|rapidly", left4)
    assert "left thumb tip touches the right index" in inter4
    # Level 4 gives timing (seconds or frames) for every event.
    assert re.search(r"frames? \d+|\d\.\d s", right4) and re.search(r"frames? \d+|\d\.\d s", inter4)
    assert "right index" in out[0]["interaction"] or "touch" in out[0]["interaction"]


def test_no_contact_is_stated(record):
    out = cap.TemplateCaptioner().caption(_record(touch=False, move=0.0), seed=0)
    assert re.search(r"never touch|no contact|out of contact", out[2]["interaction"])


def test_different_motions_give_different_texts(record):
    a = cap.TemplateCaptioner().caption(record, seed=0)
    b = cap.TemplateCaptioner().caption(_record(bend_fingers=("ring", "pinky")), seed=0)
    assert a[0]["right"] != b[0]["right"] and "ring and pinky" in b[4]["right"]


def test_hyperextension_is_always_reported():
    h = right_hand({("index", 1): -35.0})
    x = clip(np.repeat(pair(mirror(right_hand()), h)[None], 60, 0))
    rec = ev.annotate(x)[0]
    out = cap.TemplateCaptioner().caption(rec, seed=0)
    for lv in out:
        assert "hyperextended" in lv["right"] or "bent backwards" in lv["right"], lv["right"]


def test_prompt_embeds_record_and_asks_for_five_levels(record):
    p = cap.build_prompt(record)
    assert json.dumps(record, indent=1, ensure_ascii=False) in p
    assert "exactly 5" in p and "two_hands_relation" in p
    for word in ("left hand", "right hand", "contact", "hyperextended", "order"):
        assert word.lower() in p.lower()


def _fake_reply(n=5, fence=True):
    items = [{"left": f"L{i}", "right": f"R{i}", "two_hands_relation": f"I{i}"} for i in range(n)]
    body = json.dumps(items)
    return f"```json\n{body}\n```" if fence else body


def test_llm_captioner_round_trip(record):
    seen = []

    def complete(prompt: str) -> str:
        seen.append(prompt)
        return _fake_reply()

    out = cap.LLMCaptioner(complete).caption(record, seed=0)
    assert out[4] == {"left": "L4", "right": "R4", "interaction": "I4"} and len(out) == 5
    assert seen and "EVENTS (JSON)" in seen[0]


@pytest.mark.parametrize("reply", ["not json", _fake_reply(4), json.dumps([{"left": "a", "right": "b"}] * 5),
                                   json.dumps({"left": "a"})])
def test_llm_captioner_rejects_bad_reply(record, reply):
    with pytest.raises(DataError, match="clip c0"):
        cap.LLMCaptioner(lambda p: reply).caption(record, seed=0)
