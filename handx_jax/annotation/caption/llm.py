"""Captions from a large language model: the prompt (paper §4 and Fig. D; structure of reference §6.4,
wording our own), the parser and validator of its reply, and a captioner around a user's completion
function (no network code lives here)."""

from __future__ import annotations

import json
from typing import Callable

from handx_jax.annotation.caption.protocol import LEVELS
from handx_jax.infra.errors import DataError

_PROMPT_HEAD = """You are annotating a short clip of two human hands moving together. You will not see the
motion itself; instead you receive kinematic events that were measured from it. Write descriptions of
the physical movement only, in plain English, without guessing at objects, intentions or emotions.

INPUT
The JSON below lists events for the LEFT hand, the RIGHT hand and the RELATIONSHIP between them.
All frame ranges are half-open [start, end): an event covers frames start … end−1. The clip has
{T} frames at {fps} frames per second ({dur:.1f} s).
- finger_flexing, keyed by joint (mcp = knuckle, pip = middle joint, dip / ip = tip joint): states are
  "hyper extend" (bent backwards past straight), "fully extend", "partially bent" and "fully bent".
  A transition has start_state, end_state and speed; a constant event has a single state.
- finger_spacing, keyed by a pair of neighbouring fingers: "open" (spread) or "closed" (together).
- finger_tip_contact (inside one hand: thumb tip against another tip; between hands: a left tip
  against a right tip): each entry is a period of contact. Pairs that never touch are omitted.
- wrist_trajectory, per axis (left-right, front-back, down-up): movements with a direction,
  displacement in metres and speed; "still" means no movement along that axis.
- finger_palm_distance: a fingertip of one hand relative to the other hand's palm ("contact",
  "near", "far"). palm_palm_distance: "contact", "near", "medium", "far".
- palm_palm_relative_position, per axis: where the RIGHT palm is relative to the LEFT palm
  (left / aligned / right, behind / aligned / in front, below / aligned / above).
- speed is "slow", "medium" or "fast".

RULES
1. Cover three things every time: what the left hand does, what the right hand does, and how the two
   hands relate to each other (distance, relative position, coordination).
2. Never leave out a contact, a separation after contact, or a hyperextended joint. Contact takes
   precedence over mere closeness.
3. Keep the order of events in time and say when things happen (early, midway, at the end, or in
   seconds / frames). Do not describe simultaneous events as sequential or the reverse.
4. Describe a finger as a whole when its joints move together; name a single joint only when it
   differs (for example a knuckle bent backwards while the tip joints curl). Merge fingers that do
   the same thing ("the index and middle fingers curl"), and summarise repetitions ("taps three
   times") instead of listing them one by one.
5. For the two hands, stress touching, quick approaches or separations, and changes of which hand is
   above, in front or to the side.
6. Use the event information only; do not invent movements that are not in the JSON.

OUTPUT
Return ONLY a JSON list of exactly 5 objects, each with the string keys "left", "right" and
"two_hands_relation". The five objects are five levels of detail of the SAME motion:
  1. one short sentence per key with the single most salient movement;
  2. a concise summary naming the main fingers and the wrist direction;
  3. a balanced description with moderate detail and rough timing;
  4. a detailed description covering most events in order, with speeds;
  5. an exhaustive account of every event with its timing (seconds or frame ranges) and speed.

EVENTS (JSON)
"""


def build_prompt(record: dict) -> str:
    """The LLM prompt for one clip, with the record's JSON embedded at the end."""
    T = int(record["frame_count"])
    fps = int(record.get("fps", 30))
    head = _PROMPT_HEAD.format(T=T, fps=fps, dur=T / fps)
    return head + json.dumps(record, indent=1, ensure_ascii=False) + "\n"


def parse_llm_reply(reply: str, *, clip=None) -> list[dict]:
    """Parse and validate an LLM reply: a JSON list of 5 {left, right, two_hands_relation} objects
    (a leading Markdown code fence is stripped). Returns the captioner's {left, right, interaction}
    levels; raises ``DataError`` naming the clip otherwise."""
    text = reply.strip()
    if text.startswith("```"):
        text = text.split("\n", 1)[1] if "\n" in text else ""
        if text.rstrip().endswith("```"):
            text = text.rstrip()[:-3]
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as e:
        raise DataError(f"LLM reply is not valid JSON ({e.msg} at position {e.pos})", clip=clip) from None
    if not isinstance(obj, list) or len(obj) != LEVELS:
        raise DataError(f"LLM reply must be a JSON list of exactly {LEVELS} objects, got "
                        f"{type(obj).__name__}{f' of length {len(obj)}' if isinstance(obj, list) else ''}", clip=clip)
    out = []
    for i, item in enumerate(obj):
        if not isinstance(item, dict):
            raise DataError(f"LLM reply item {i} is not an object", clip=clip)
        for key in ("left", "right", "two_hands_relation"):
            if not isinstance(item.get(key), str) or not item[key].strip():
                raise DataError(f"LLM reply item {i} lacks a non-empty string {key!r}", clip=clip)
        out.append({"left": item["left"].strip(), "right": item["right"].strip(),
                    "interaction": item["two_hands_relation"].strip()})
    return out


class LLMCaptioner:
    """Captions from a user-supplied completion function ``complete(prompt) -> reply``.

    No network code lives here: plug in any client. The seed is appended to the prompt as a comment
    only when ``seed_in_prompt`` is set (some services cache identical prompts).
    """

    def __init__(self, complete: Callable[[str], str], *, seed_in_prompt: bool = False):
        self.complete = complete
        self.seed_in_prompt = seed_in_prompt

    def caption(self, record: dict, *, seed: int) -> list[dict]:
        prompt = build_prompt(record)
        if self.seed_in_prompt:
            prompt += f"\n(variation seed: {seed})\n"
        reply = self.complete(prompt)
        if not isinstance(reply, str):
            raise DataError(f"completion returned {type(reply).__name__}, expected str", clip=record.get("id", "?"))
        return parse_llm_reply(reply, clip=record.get("id", "?"))
