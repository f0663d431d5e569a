"""Level 0 of a record read with the "gist" annotation (corpus v3, issue 40): what each hand's fingers do,
in a few fixed words, and whether the hands touch.

Level 0 is "the single most salient thing" a caption says. Chosen by salience among joint-level facts
(``compose``), it flipped under a millimetre of noise: the salience order, the shapes reached and the
grouping of fingers each sit on thresholds that noise crosses (docs/results/validity/level0/). The gist
makes ONE decision per finger, from the record's ``finger_curl`` swings (``events.finger_curl_swing_deg``):
whether the finger curls, straightens, does both (in which order), or does so repeatedly. The fingers that
do the same are named together. The words are fixed (no random choice), so a text changes only when a
decision does; played backwards every swing turns the other way, so the text changes with the order.

The interaction says whether the hands touch: inter-hand fingertip contacts or a palm-to-palm "contact"
state lasting at least ``TOUCH_FRAMES`` frames in all.
"""

from __future__ import annotations

from handx_jax.data.caption.words import FOUR, capitalise, finger_group, join_words

TOUCH_FRAMES = 6
# Swing direction patterns → (singular, plural) verb; three swings or more are a repetition.
_VERBS = {("curl",): ("curls", "curl"), ("straighten",): ("straightens", "straighten"),
          ("curl", "straighten"): ("curls and straightens", "curl and straighten"),
          ("straighten", "curl"): ("straightens and curls", "straighten and curl"),
          "repeat": ("flexes repeatedly", "flex repeatedly")}
_HAND = {("curl",): "the hand closes", ("straighten",): "the hand opens",
         ("curl", "straighten"): "the hand closes and opens again", ("straighten", "curl"): "the hand opens and closes again",
         "repeat": "the hand opens and closes repeatedly"}
STILL = "the fingers hold their shape"


def has_gist(record: dict) -> bool:
    """Whether the record was read with the gist annotation (it carries ``finger_curl``)."""
    return "finger_curl" in record.get("right_hand_events", {})


def hand_gist(hand_events: dict) -> str:
    pats = {}
    for f in FOUR:
        dirs = tuple(e["direction"] for e in hand_events["finger_curl"].get(f) or ())
        if dirs:
            pats[f] = "repeat" if len(dirs) >= 3 else dirs
    if not pats:
        return STILL
    groups: dict = {}
    for f, p in pats.items():
        groups.setdefault(p, []).append(f)
    if len(groups) == 1 and len(pats) == 4:
        return _HAND[next(iter(groups))]
    parts = []
    for p, fs in groups.items():  # dicts keep insertion order: groups by their first finger, index first
        who, plural = finger_group(fs)
        parts.append(f"{who} {_VERBS[p][plural]}")
    return join_words(parts)


def touch_frames(relations: dict) -> int:
    tips = sum(e["end"] - e["start"] for lst in relations.get("finger_tip_contact", {}).values() for e in lst)
    palms = sum(e["end"] - e["start"] for lst in relations.get("palm_palm_distance", {}).values() for e in lst
                if e.get("state") == "contact" or e.get("start_state") == "contact" == e.get("end_state"))
    return tips + palms


def level0(record: dict) -> dict:
    """The gist's three level-0 texts of one record."""
    inter = "the hands touch" if touch_frames(record["two_hand_relationships"]) >= TOUCH_FRAMES else \
        "the hands stay apart"
    return {"left": capitalise(hand_gist(record["left_hand_events"])) + ".",
            "right": capitalise(hand_gist(record["right_hand_events"])) + ".",
            "interaction": capitalise(inter) + "."}
