"""The captions' vocabulary: the word tables (finger shapes, verbs per move, speeds, directions, gestures,
spacing and relative position) and the phrase helpers every fact renderer shares (lists, counts,
third-person verbs, finger groups, timing phrases).

The tables are the one place to change how the template captioner words a thing; every option tuple is
drawn from with the captioner's seeded stream (``pick``), so reordering or extending one rewords corpora.
"""

from __future__ import annotations

import random

FINGERS = ("thumb", "index", "middle", "ring", "pinky")
FOUR = ("index", "middle", "ring", "pinky")
FLEX_ORDER = {"hyper extend": -1, "fully extend": 0, "partially bent": 1, "fully bent": 2}
SPEED_RANK = {"slow": 0, "medium": 1, "fast": 2}
SPEED_ADV = (("slowly", "gently"), ("steadily", "at a moderate pace"), ("quickly", "rapidly"))
SPEED_FACTOR = (0.8, 1.0, 1.25)
_NUMBER = {1: "once", 2: "twice", 3: "three times", 4: "four times", 5: "five times"}
DIR_WORDS = {"left-to-right": "to the right", "right-to-left": "to the left", "back-to-front": "forward",
              "front-to-back": "back", "down-to-up": "up", "up-to-down": "down"}
SWING = {"left-right": "left and right", "front-back": "forward and back", "down-up": "up and down"}
REL_PHRASE = {"left": "to the left of", "right": "to the right of", "behind": "behind",
               "in front": "in front of", "below": "below", "above": "above", "aligned": None}
PALM_DIST_WORDS = {"contact": "touching", "near": "close together", "medium": "a hand's width apart",
                    "far": "far apart"}
PALM_ORDER = {"contact": 0, "near": 1, "medium": 2, "far": 3}

# Finger shapes (from the joint states of one finger) and their words.
SHAPE_WORDS = {
    "straight": ("straight", "fully extended"),
    "half": ("half bent", "partly curled"),
    "curled": ("curled", "fully bent"),
    "hooked": ("hooked", "bent at the middle joint"),
    "back": ("bent back", "hyperextended"),
}
THUMB_SHAPE_WORDS = {
    "straight": ("straight", "extended"),
    "half": ("bent", "partly bent"),
    "curled": ("tucked in", "folded in"),
    "hooked": ("bent", "bent at the tip"),
    "back": ("bent back", "hyperextended"),
}
# Verb phrases (base form) for a move: (direction, shape reached) → options.
FINGER_VERBS = {
    (1, "curled"): ("curl fully", "curl up tightly", "flex fully"),
    (1, "half"): ("bend halfway", "curl partway", "flex partly"),
    (1, "hooked"): ("hook into a claw", "curl into a hook"),
    (1, "straight"): ("flex slightly", "bend a little"),
    (1, "back"): ("ease out of hyperextension",),
    (-1, "straight"): ("straighten", "extend fully", "uncurl until straight"),
    (-1, "half"): ("loosen halfway", "straighten partway", "uncurl partway"),
    (-1, "hooked"): ("open into a hook", "straighten at the knuckle into a hook"),
    (-1, "curled"): ("relax slightly", "loosen a little"),
    (-1, "back"): ("bend back into hyperextension", "hyperextend by bending backwards"),
}
HAND_VERBS = {  # subject "the hand": all four fingers together
    (1, "curled"): ("close into a fist", "clench into a fist", "curl into a fist"),
    (1, "half"): ("close halfway", "curl halfway closed"),
    (1, "hooked"): ("curl into a claw", "form a claw"),
    (-1, "straight"): ("open flat", "open up fully", "open out"),
    (-1, "half"): ("open halfway", "loosen halfway open"),
    (-1, "back"): ("open and bend its fingers back into hyperextension",),
}
THUMB_VERBS = {
    (1, "curled"): ("fold across the palm", "tuck in"),
    (1, "half"): ("bend", "flex partway"),
    (1, "hooked"): ("bend at the tip",),
    (1, "straight"): ("flex slightly",),
    (1, "back"): ("ease out of hyperextension",),
    (-1, "straight"): ("straighten", "extend"),
    (-1, "half"): ("loosen", "straighten partway"),
    (-1, "hooked"): ("straighten partway",),
    (-1, "curled"): ("relax slightly",),
    (-1, "back"): ("bend back into hyperextension",),
}
REPEAT_VERBS = {"finger": (("curl and straighten", "flex and extend", "bend and straighten"),
                            ("straighten and curl", "extend and flex", "straighten and bend")),
                 "hand": (("close and open", "clench and release", "close and reopen"),
                          ("open and close", "open and clench again", "open and close again"))}
GESTURE_WORDS = {"fist": "a fist", "thumbs-up": "a thumbs-up", "pointing": "a pointing pose",
                  "v": "a V sign", "claw": "a claw", "flat": "a flat open hand"}


def join_words(items: list[str]) -> str:
    items = [i for i in items if i]
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


def pick(rng: random.Random, options):
    """rng.choice without its rejection sampling (several times faster; same determinism)."""
    return options[int(rng.random() * len(options))]


def capitalise(s: str) -> str:
    return s[:1].upper() + s[1:] if s else s


def word_count(s: str) -> int:
    return s.count(" ") + 1 if s else 0


def times(n: int) -> str:
    return _NUMBER.get(n, "repeatedly")


def verb_form(base: str, plural: bool) -> str:
    """Third-person form of the first word of ``base`` ("curl into" → "curls into"), and of the word
    after an "and"."""
    if plural:
        return base
    head, sep, tail = base.partition(" and ")  # "curl and straighten" → "curls and straightens"
    if sep:
        return f"{verb_form(head, False)} and {verb_form(tail, False)}"
    w, _, rest = base.partition(" ")
    w = w + ("es" if w.endswith(("s", "sh", "ch", "x")) else "s")
    return f"{w} {rest}".strip()


def finger_group(fingers) -> tuple[str, bool]:
    """("the index and middle fingers", plural) for a set of digits."""
    fingers = sorted(set(fingers), key=FINGERS.index)
    if len(fingers) == 5:
        return "all five digits", True
    if fingers == list(FOUR):
        return "all four fingers", True
    if fingers == ["thumb"]:
        return "the thumb", False
    if len(fingers) == 1:
        return f"the {fingers[0]} finger", False
    if fingers[0] == "thumb" and len(fingers) == 2:
        return f"the thumb and {fingers[1]} finger", True
    return f"the {join_words(fingers)} fingers", True


class Timing:
    def __init__(self, fps: int, T: int):
        self.fps, self.T = fps, T

    def exact(self, s: int, e: int, rng: random.Random | None, seconds: bool | None = None) -> str:
        """A half-open [s, e) range as seconds (e is the end instant) or inclusive frames; the
        style is drawn from ``rng`` unless ``seconds`` fixes it."""
        if seconds if seconds is not None else rng.random() < 0.5:
            a, b = f"{s / self.fps:.1f}", f"{e / self.fps:.1f}"
            return f"at {a} s" if a == b else f"from {a} to {b} s"
        return f"at frame {s}" if e - s <= 1 else f"in frames {s}-{e - 1}"

    def rough(self, s: int, e: int) -> str:
        if e - s >= 0.8 * self.T:
            return "throughout"
        mid = (s + e) / 2 / self.T
        return "at the start" if mid < 0.3 else "midway" if mid < 0.65 else "toward the end"
