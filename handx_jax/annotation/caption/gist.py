"""Level 0 of a record read with the "gist" annotation (corpus v3, issue 40): what each hand's fingers do,
in a few fixed words, and which parts of the hands touch.

Level 0 is "the single most salient thing" a caption says. Chosen by salience among joint-level facts
(``compose``), it flipped under a millimetre of noise: the salience order, the shapes reached and the
grouping of fingers each sit on thresholds that noise crosses (docs/results/validity/level0/). The gist
makes ONE decision per finger, from the record's ``finger_curl`` swings (``events.finger_curl_swing_deg``):
whether the finger curls, straightens, does both (in which order), or does so repeatedly, and for a single
curl or straighten, whether it goes into or out of a tight curl (the swing's ``depth``). The fingers that do
the same are named together. The words are fixed (no random choice), so a text changes only when a decision
does; played backwards every swing turns the other way, so the text changes with the order.

The interaction says which parts of the hands touch, if any: the palms (a palm-to-palm "contact" state), else
fingertips (inter-hand fingertip contacts), each counted when it lasts at least ``TOUCH_FRAMES`` frames in all:
palms that come together and stay count from the frame they meet, not only palms pressed the whole clip.
"""

from __future__ import annotations

import numpy as np

from handx_jax.annotation.caption.inter import contact_periods
from handx_jax.annotation.caption.words import FOUR, capitalise, finger_group, join_words

TOUCH_FRAMES = 6
# Swing patterns → (singular, plural) verb. A single swing carries its depth; three swings or more are a
# repetition.
_VERBS = {("curl", "full"): ("curls tightly", "curl tightly"), ("curl", "partial"): ("curls partway", "curl partway"),
          ("straighten", "full"): ("straightens from a tight curl", "straighten from a tight curl"),
          ("straighten", "partial"): ("straightens", "straighten"),
          ("curl", "straighten"): ("curls and straightens", "curl and straighten"),
          ("straighten", "curl"): ("straightens and curls", "straighten and curl"),
          "repeat": ("flexes repeatedly", "flex repeatedly")}
_HAND = {("curl", "full"): "the hand closes into a fist", ("curl", "partial"): "the hand closes halfway",
         ("straighten", "full"): "the hand opens out of a fist", ("straighten", "partial"): "the hand opens",
         ("curl", "straighten"): "the hand closes and opens again",
         ("straighten", "curl"): "the hand opens and closes again", "repeat": "the hand opens and closes repeatedly"}
STILL = "the fingers hold their shape"


def has_gist(record: dict) -> bool:
    """Whether the record was read with the gist annotation (it carries ``finger_curl``)."""
    return "finger_curl" in record.get("right_hand_events", {})


def _pattern(evs) -> tuple | str:
    dirs = tuple(e["direction"] for e in evs)
    return "repeat" if len(dirs) >= 3 else (dirs[0], evs[0]["depth"]) if len(dirs) == 1 else dirs


def hand_gist(hand_events: dict) -> str:
    pats = {f: _pattern(evs) for f in FOUR if (evs := hand_events["finger_curl"].get(f))}
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


def palm_touch_frames(relations: dict, T: int) -> np.ndarray:
    """(T,) bool: the frames of palm-to-palm contact, as :func:`touch_frames` counts them."""
    m = np.zeros(T, bool)
    for lst in relations.get("palm_palm_distance", {}).values():
        for s, e in contact_periods(lst, T):
            m[s:e] = True
    surface = relations.get("surface_contact")
    if surface is not None:
        touching = np.zeros(T, bool)
        for e in surface["left_palm, right_palm"]:
            touching[e["start"]:e["end"]] = True
        m &= touching
    return m


def touch_frames(relations: dict, T: int) -> tuple[int, int]:
    """(palm-to-palm contact frames, inter-hand fingertip contact frames) of a record's relations over its T
    frames. The palm distance is a state series: its contact frames are those held between the transitions
    into and out of "contact" (``inter.contact_periods``); the fingertip contacts are runs. A record read with
    the surface reading counts the palms' contact frames only where the palms' surfaces touch
    (``surface_contact``, corpus v5)."""
    palm_frames = palm_touch_frames(relations, T)
    palms = int(palm_frames.sum())
    tips = sum(e["end"] - e["start"] for lst in relations.get("finger_tip_contact", {}).values() for e in lst)
    return palms, tips


def interaction(relations: dict, T: int) -> str:
    """The palms or the fingertips touch (each for TOUCH_FRAMES frames or more), else the hands stay apart. A
    record read with the surface reading (``surface_contact``, corpus v5) says "the hands touch" where other
    parts touch, or touch for fewer frames: there "the hands stay apart" means no surface contact at all."""
    palms, tips = touch_frames(relations, T)
    if palms >= TOUCH_FRAMES:
        return "the palms touch"
    if tips >= TOUCH_FRAMES:
        return "the fingertips touch"
    surface = relations.get("surface_contact")
    return "the hands touch" if surface and surface["left_hand, right_hand"] else "the hands stay apart"


def level0(record: dict) -> dict:
    """The gist's three level-0 texts of one record."""
    return {"left": capitalise(hand_gist(record["left_hand_events"])) + ".",
            "right": capitalise(hand_gist(record["right_hand_events"])) + ".",
            "interaction": capitalise(interaction(record["two_hand_relationships"], int(record["frame_count"]))) + "."}
