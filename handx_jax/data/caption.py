"""Captions from structured event records: the ``Captioner`` protocol, a seeded template captioner,
the LLM prompt (paper §4, Fig. D; reference §6.4) and an LLM captioner around a user callable.

Every captioner returns FIVE levels, index 0 the most concise and 4 the most detailed, each a dict
``{"left": str, "right": str, "interaction": str}``. Frame ranges in records are half-open
[start, end) (see ``events.py``); texts quote them as "frames s-e" with e = end − 1 (inclusive, as a
reader expects) or as seconds at the record's fps.

The template captioner works like the paper's annotator is asked to (§4; reference §6.4 rules):
it first digests the record into FACTS about whole fingers and gestures rather than joints — the
joint events of a finger merge into finger moves (same direction, overlapping in time), fingers
doing the same thing form one group ("the middle, ring and pinky fingers curl"), back-and-forth
moves become a repetition ("curl and straighten three times"), the per-finger shapes at key frames
name whole-hand gestures (fist, pointing, claw, …), and contacts, separations, wrist travel and the
relation of the two hands become facts of their own. Each fact has a SALIENCE and renders at any
detail level (0 core → 1 speed → 2 rough timing → 3 shapes and per-move timing → 4 exact timing and
speed per move). A text of level ℓ takes facts in order of salience while they fit its word budget
``BUDGET_WORDS[ℓ]`` (a fact that does not fit at full detail may enter at a lower one), always
keeping contacts and hyperextension; the chosen facts are then told in temporal order, at most two
clauses per sentence. No field exceeds ``HARD_CAP_WORDS`` (≈ 120 T5 tokens).
"""

from __future__ import annotations

import json
import random
from dataclasses import dataclass
from typing import Callable, Protocol

from handx_jax.io import DataError

LEVELS = 5
# Word budget of one text field per level (the mean over a corpus lands a little below, since
# simple motions say less) and the cap no field may exceed (≈ 1.35 T5 tokens per word → 120).
BUDGET_WORDS = (10, 27, 44, 61, 80)
HARD_CAP_WORDS = 90

_FINGERS = ("thumb", "index", "middle", "ring", "pinky")
_FOUR = ("index", "middle", "ring", "pinky")
_FLEX_ORDER = {"hyper extend": -1, "fully extend": 0, "partially bent": 1, "fully bent": 2}
_SPEED_RANK = {"slow": 0, "medium": 1, "fast": 2}
_SPEED_ADV = (("slowly", "gently"), ("steadily", "at a moderate pace"), ("quickly", "rapidly"))
_SPEED_FACTOR = (0.8, 1.0, 1.25)
_NUMBER = {1: "once", 2: "twice", 3: "three times", 4: "four times", 5: "five times"}
_DIR_WORDS = {"left-to-right": "to the right", "right-to-left": "to the left", "back-to-front": "forward",
              "front-to-back": "back", "down-to-up": "up", "up-to-down": "down"}
_SWING = {"left-right": "left and right", "front-back": "forward and back", "down-up": "up and down"}
_REL_PHRASE = {"left": "to the left of", "right": "to the right of", "behind": "behind",
               "in front": "in front of", "below": "below", "above": "above", "aligned": None}
_PALM_DIST_WORDS = {"contact": "touching", "near": "close together", "medium": "a hand's width apart",
                    "far": "far apart"}
_PALM_ORDER = {"contact": 0, "near": 1, "medium": 2, "far": 3}

# Finger shapes (from the joint states of one finger) and their words.
_SHAPE_WORDS = {
    "straight": ("straight", "fully extended"),
    "half": ("half bent", "partly curled"),
    "curled": ("curled", "fully bent"),
    "hooked": ("hooked", "bent at the middle joint"),
    "back": ("bent back", "hyperextended"),
}
_THUMB_SHAPE_WORDS = {
    "straight": ("straight", "extended"),
    "half": ("bent", "partly bent"),
    "curled": ("tucked in", "folded in"),
    "hooked": ("bent", "bent at the tip"),
    "back": ("bent back", "hyperextended"),
}
# Verb phrases (base form) for a move: (direction, shape reached) → options.
_FINGER_VERBS = {
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
_HAND_VERBS = {  # subject "the hand": all four fingers together
    (1, "curled"): ("close into a fist", "clench into a fist", "curl into a fist"),
    (1, "half"): ("close halfway", "curl halfway closed"),
    (1, "hooked"): ("curl into a claw", "form a claw"),
    (-1, "straight"): ("open flat", "open up fully", "open out"),
    (-1, "half"): ("open halfway", "loosen halfway open"),
    (-1, "back"): ("open and bend its fingers back into hyperextension",),
}
_THUMB_VERBS = {
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
_REPEAT_VERBS = {"finger": (("curl and straighten", "flex and extend", "bend and straighten"),
                            ("straighten and curl", "extend and flex", "straighten and bend")),
                 "hand": (("close and open", "clench and release", "close and reopen"),
                          ("open and close", "open and clench again", "open and close again"))}
_GESTURE_WORDS = {"fist": "a fist", "thumbs-up": "a thumbs-up", "pointing": "a pointing pose",
                  "v": "a V sign", "claw": "a claw", "flat": "a flat open hand"}


class Captioner(Protocol):
    def caption(self, record: dict, *, seed: int) -> list[dict]:
        """Five levels (0 = one-line summary … 4 = comprehensive), each {left, right, interaction}."""


# ---------------------------------------------------------------------------------------------
# Shared helpers


def _join(items: list[str]) -> str:
    items = [i for i in items if i]
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


def _pick(rng: random.Random, options):
    """rng.choice without its rejection sampling (several times faster; same determinism)."""
    return options[int(rng.random() * len(options))]


def _cap(s: str) -> str:
    return s[:1].upper() + s[1:] if s else s


def _words(s: str) -> int:
    return s.count(" ") + 1 if s else 0


def _count(n: int) -> str:
    return _NUMBER.get(n, "repeatedly")


def _verb(base: str, plural: bool) -> str:
    """Third-person form of the first word of ``base`` ("curl into" → "curls into"), and of the word
    after an "and"."""
    if plural:
        return base
    head, sep, tail = base.partition(" and ")  # "curl and straighten" → "curls and straightens"
    if sep:
        return f"{_verb(head, False)} and {_verb(tail, False)}"
    w, _, rest = base.partition(" ")
    w = w + ("es" if w.endswith(("s", "sh", "ch", "x")) else "s")
    return f"{w} {rest}".strip()


def _finger_group(fingers) -> tuple[str, bool]:
    """("the index and middle fingers", plural) for a set of digits."""
    fingers = sorted(set(fingers), key=_FINGERS.index)
    if len(fingers) == 5:
        return "all five digits", True
    if fingers == list(_FOUR):
        return "all four fingers", True
    if fingers == ["thumb"]:
        return "the thumb", False
    if len(fingers) == 1:
        return f"the {fingers[0]} finger", False
    if fingers[0] == "thumb" and len(fingers) == 2:
        return f"the thumb and {fingers[1]} finger", True
    return f"the {_join(fingers)} fingers", True


class _Timing:
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


@dataclass
class _Fact:
    """One thing worth saying: salience, time span (t0 None = a state held over the clip) and a
    renderer ``render(detail) -> clause`` for detail 0 … 4."""

    sal: float
    t0: int | None
    t1: int
    render: Callable[[int], str]
    must: bool = False

    def __post_init__(self):
        self._cache: dict[int, str] = {}
        # Per-fact wording (TemplateCaptioner(wording="per_fact")): the shared stream is re-seeded from
        # (caption seed, this fact's key, detail) before each render, so what one fact says never
        # depends on which other facts the record holds.
        self.stream: tuple[random.Random, str] | None = None

    def text(self, d: int) -> str:
        """The clause at detail d, rendered once (a level reuses the wording of lower levels)."""
        t = self._cache.get(d)
        if t is None:
            if self.stream is not None:
                rng, key = self.stream
                rng.seed(f"{key}/{d}")
            t = self._cache[d] = self.render(d)
        return t


def _compose(facts: list[_Fact], level: int, rng: random.Random, fallback: str,
             order: list[int] | None = None) -> str:
    """The level's text: facts by salience into the word budget, then told in temporal order.
    ``order`` is the facts' indices by decreasing salience (computed here when not given)."""
    budget = BUDGET_WORDS[level]
    chosen: dict[int, str] = {}
    used = forced = 0
    if order is None:
        order = sorted(range(len(facts)), key=lambda k: -facts[k].sal)
    for i in order:
        f = facts[i]
        left = budget - used
        forcing = f.must
        if level == 0 and f.must and forced >= 2:
            continue  # level 0 names at most two mandatory facts
        if (left < 4 or _words(f.text(0 if level < 3 else 2)) + 1 > left) and not (forcing or not chosen):
            continue
        txt = None
        # Levels 3–4 only take a fact with its timing (detail ≥ 2); lower levels may shorten it.
        for d in (level, level - 1) if level >= 3 else (level, level - 1, 0) if level == 2 else (level, 0):
            t = f.text(d)
            if _words(t) + 1 <= left:
                txt = t
                break
        if txt is None and (forcing or not chosen):
            txt = f.text(0 if level < 3 else 2)
        if txt is None:
            continue
        chosen[i] = txt
        used += _words(txt) + 1
        forced += f.must
    # The hard cap: drop the least salient optional facts if mandatory ones overflowed.
    while used > HARD_CAP_WORDS and len(chosen) > 1:
        i = min((k for k in chosen if not facts[k].must), key=lambda k: facts[k].sal, default=None)
        if i is None:
            i = min(chosen, key=lambda k: facts[k].sal)
        used -= _words(chosen.pop(i)) + 1
    if not chosen:
        return _cap(fallback) + "."
    sel = sorted(chosen, key=lambda k: (facts[k].t0 is None, facts[k].t0 or 0, -facts[k].sal))
    if level == 0:
        return _cap(_join([chosen[k] for k in sel])) + "."
    sents, k = [], 0
    while k < len(sel):
        a = sel[k]
        if k + 1 < len(sel) and rng.random() < 0.6:
            b = sel[k + 1]
            fa, fb = facts[a], facts[b]
            if fb.t0 is None:
                conn = " and " if fa.t0 is None else _pick(rng, [", while ", "; meanwhile "])
            elif fb.t0 >= fa.t1 - 2:
                conn = _pick(rng, [", then ", ", and then ", ", after which "])
            else:
                conn = _pick(rng, [" while ", " as "])
            sents.append(_cap(chosen[a] + conn + chosen[b]) + ".")
            k += 2
        else:
            sents.append(_cap(chosen[a]) + ".")
            k += 1
    return " ".join(sents)


# ---------------------------------------------------------------------------------------------
# One hand: finger moves, groups, repetitions, gestures, contacts, spacing, wrist


def _shape(finger: str, o: dict) -> str:
    """Shape of one digit from its joint states (orders −1 … 2): straight, half, curled, hooked, back."""
    if o["mcp"] < 0:
        return "back"
    vals = o.values()
    hi = max(vals)
    if hi <= 0:
        return "straight"
    if finger != "thumb" and o["mcp"] <= 0 and o["pip"] >= 2:
        return "hooked"
    mean = sum(vals) / len(o)
    if mean >= 1.5 or (finger == "thumb" and hi >= 2 and mean >= 1):
        return "curled"
    return "half"


def _finger_moves(flexing: dict, finger: str) -> tuple[list[dict], dict, dict]:
    """Whole-finger moves of one digit: its joint transitions merged when they go the same way and
    overlap (or nearly touch) in time. Returns (moves, initial joint orders, final joint orders).

    A move is {start, end, dir (+1 bend / −1 straighten), mag (state steps over all joints),
    speed (rank), from, to (shapes), minor (shape unchanged)}. When the finger has real moves its
    minor ones are dropped, and same-direction moves less than 12 frames apart merge, so a finger
    never "straightens twice in a row".
    """
    joints = ("mcp", "ip") if finger == "thumb" else ("mcp", "pip", "dip")
    init, trans = {}, []
    for j in joints:
        evs = flexing.get(f"{finger}_{j}") or ()
        if not evs:
            init[j] = 0
            continue
        e0 = evs[0]
        init[j] = _FLEX_ORDER[e0["state"] if "state" in e0 else e0["start_state"]]
        for e in evs:
            if "state" in e:
                continue
            a, b = _FLEX_ORDER[e["start_state"]], _FLEX_ORDER[e["end_state"]]
            trans.append((e["start"], e["end"], 1 if b > a else -1, abs(b - a), j, b, _SPEED_RANK[e["speed"]]))
    if not trans:
        return [], init, init
    trans.sort()
    clusters: list[dict] = []
    for s, e, d, mag, j, b, sp in trans:
        target = None
        if clusters and clusters[-1]["dir"] == d and s <= clusters[-1]["end"] + 6:
            target = clusters[-1]
        elif len(clusters) >= 2 and clusters[-2]["dir"] == d and s <= clusters[-2]["end"] + 2:
            target = clusters[-2]
        if target is None:
            clusters.append({"start": s, "end": e, "dir": d, "mag": mag, "speed": sp, "ev": [(e, j, b)]})
        else:
            target["end"] = max(target["end"], e)
            target["mag"] += mag
            target["speed"] = max(target["speed"], sp)
            target["ev"].append((e, j, b))
    cur = dict(init)
    for c in clusters:
        c["from"] = _shape(finger, cur)
        for _, j, b in sorted(c.pop("ev")):
            cur[j] = b
        c["to"] = _shape(finger, cur)
        c["minor"] = c["from"] == c["to"]
    final = cur
    if not all(c["minor"] for c in clusters):
        clusters = [c for c in clusters if not c["minor"]]
    moves: list[dict] = []
    for c in clusters:
        p = moves[-1] if moves else None
        if p is not None and p["dir"] == c["dir"] and c["start"] - p["end"] <= 12:
            p["end"], p["to"] = max(p["end"], c["end"]), c["to"]
            p["mag"] += c["mag"]
            p["speed"] = max(p["speed"], c["speed"])
            p["minor"] = p["from"] == p["to"]
        else:
            moves.append(c)
    return moves, init, final


def _same_pattern(a: list[dict], b: list[dict]) -> bool:
    """Two digits do the same thing: the same moves at about the same time. Single and double moves
    must also reach the same shapes (within 6 frames); a repetition (three moves or more) only needs
    the same rhythm (within 10 frames), its group then spans the union of their shapes."""
    if len(a) != len(b):
        return False
    rep = len(a) >= 3
    tol = 10 if rep else 6
    return all(m["dir"] == n["dir"] and (rep or m["to"] == n["to"]) and abs(m["start"] - n["start"]) <= tol
               and abs(m["end"] - n["end"]) <= tol + 2 for m, n in zip(a, b))


def _gesture(sh: dict) -> str | None:
    four = [sh[f] for f in _FOUR]
    if all(s == "curled" for s in four):
        return "thumbs-up" if sh["thumb"] == "straight" else "fist"
    rest = [sh[f] for f in ("ring", "pinky")]
    if sh["index"] == "straight" and sh["middle"] == "curled" and all(s == "curled" for s in rest):
        return "pointing"
    if sh["index"] == "straight" and sh["middle"] == "straight" and all(s == "curled" for s in rest):
        return "v"
    if all(s == "hooked" for s in four):
        return "claw"
    if all(s == "straight" for s in four) and sh["thumb"] == "straight":
        return "flat"
    return None


class _HandFacts:
    """Facts about one hand's events (finger groups, gestures, held fingers, pinches, spacing, wrist)."""

    def __init__(self, ev: dict, tm: _Timing, rng: random.Random):
        self.tm, self.rng = tm, rng
        flexing = ev.get("finger_flexing", {})
        self.moves, self.init, self.final = {}, {}, {}
        for f in _FINGERS:
            self.moves[f], self.init[f], self.final[f] = _finger_moves(flexing, f)
        self.facts: list[_Fact] = []
        self.main: tuple | None = None   # (salience, moves, subject) of the most salient finger group
        self.segs: list[tuple[int, int, str]] = []  # wrist moves: (start, end, main direction)
        self.groups = self._groups()
        self._finger_facts()
        self._gesture_fact()
        self._static_facts()
        self._contact_facts(ev.get("finger_tip_contact", {}))
        self._spacing_facts(ev.get("finger_spacing", {}))
        self._wrist_facts(ev.get("wrist_trajectory", {}))

    # -- fingers ----------------------------------------------------------------------------------
    def _groups(self) -> list[list[str]]:
        groups: list[list[str]] = []
        for f in _FINGERS:
            if not self.moves[f]:
                continue
            for g in groups:
                if _same_pattern(self.moves[g[0]], self.moves[f]):
                    g.append(f)
                    break
            else:
                groups.append([f])
        return groups

    def _move_phrase(self, m: dict, subject: str, plural: bool) -> str:
        key = (m["dir"], m["to"])
        table = _HAND_VERBS if subject == "hand" and key in _HAND_VERBS else \
            _THUMB_VERBS if subject == "thumb" else _FINGER_VERBS
        return _verb(_pick(self.rng, table[key]), plural)

    def _shape_word(self, shape: str, thumb: bool) -> str:
        return _pick(self.rng, (_THUMB_SHAPE_WORDS if thumb else _SHAPE_WORDS)[shape])

    def _finger_facts(self) -> None:
        for fingers in self.groups:
            ms = [dict(m) for m in self.moves[fingers[0]]]
            for m in ms:
                m["shapes"] = {m["to"]}
            for g in fingers[1:]:  # the group's ranges cover all its fingers
                for m, n in zip(ms, self.moves[g]):
                    m["start"], m["end"] = min(m["start"], n["start"]), max(m["end"], n["end"])
                    m["speed"] = max(m["speed"], n["speed"])
                    m["shapes"].add(n["to"])
            four = set(_FOUR) <= set(fingers)
            thumb_only = fingers == ["thumb"]
            subject = "hand" if four else "thumb" if thumb_only else "finger"
            who, plural = ("the hand", False) if four and all(
                (m["dir"], m["to"]) in _HAND_VERBS for m in ms) else _finger_group(fingers)
            if who != "the hand" and subject == "hand":
                subject = "finger"
            if four and who == "the hand" and "thumb" in fingers:
                who = "the whole hand"
            mag = sum(m["mag"] for m in ms) / max(1, len(ms)) * min(len(ms), 3)
            sal = min(mag, 8.0) * (0.6 + 0.4 * len(fingers)) * _SPEED_FACTOR[max(m["speed"] for m in ms)]
            if all(m["minor"] for m in ms):
                sal *= 0.3
            hyper = any(m["to"] == "back" or m["from"] == "back" for m in ms)
            if self.main is None or sal > self.main[0]:
                self.main = (sal, ms, subject)
            render = self._group_renderer(ms, who, plural, subject, thumb_only)
            self.facts.append(_Fact(sal + (50.0 if hyper else 0.0), ms[0]["start"], ms[-1]["end"], render, hyper))

    def _group_renderer(self, ms, who, plural, subject, thumb):
        tm, rng = self.tm, self.rng
        adv = lambda sp: _pick(rng, _SPEED_ADV[sp])
        s0, s1 = ms[0]["start"], ms[-1]["end"]

        def one(m, d, again=False):
            txt = self._move_phrase(m, subject, plural) + (" again" if again else "")
            if d >= 3 and m["from"] != m["to"] and not again:
                txt += f" from {self._shape_word(m['from'], thumb)}"
            if d >= 1:
                txt += " " + adv(m["speed"])
            if d >= 4:
                txt += " " + tm.exact(m["start"], m["end"], rng)
            elif d == 3:
                txt += " " + tm.rough(m["start"], m["end"])
            return txt

        def render(d: int) -> str:
            if len(ms) >= 3:
                ups = sum(m["dir"] > 0 for m in ms)
                n = max(ups, len(ms) - ups)
                kind = "hand" if subject == "hand" else "finger"
                verb = _verb(_pick(rng, _REPEAT_VERBS[kind][ms[0]["dir"] < 0]), plural)
                txt = f"{who} {verb} {_count(n)}"
                if d >= 3:
                    # Sorted first: shapes of equal flexion order tie, and a set's order follows the
                    # per-process string hash seed, which would make the wording differ between runs.
                    shapes = sorted(set().union(*(m["shapes"] for m in ms)))
                    lo = min(shapes, key=_FLEX_ORDER_SHAPE.get)
                    hi = max(shapes, key=_FLEX_ORDER_SHAPE.get)
                    if lo != hi:
                        txt += f" between {self._shape_word(lo, thumb)} and {self._shape_word(hi, thumb)}"
                if d >= 1:
                    txt += " " + adv(max(m["speed"] for m in ms))
                if d >= 4:
                    txt += " " + tm.exact(s0, s1, rng)
                    if len(ms[-1]["shapes"]) == 1:
                        txt += f", ending {self._shape_word(ms[-1]['to'], thumb)}"
                elif d >= 2:
                    txt += " " + tm.rough(s0, s1)
                return txt
            if len(ms) == 2:
                back = ms[0]["dir"] != ms[1]["dir"] and ms[1]["to"] == ms[0]["from"]
                if d <= 2:
                    txt = f"{who} {one(ms[0], min(d, 1))} and {one(ms[1], min(d, 1), again=back)}"
                    return txt + (" " + tm.rough(s0, s1) if d == 2 else "")
                link = _pick(rng, [", then ", " and then "])
                return f"{who} {one(ms[0], d)}{link}{one(ms[1], d, again=back)}"
            txt = f"{who} {one(ms[0], d)}"
            if d == 2:
                txt += " " + tm.rough(s0, s1)
            return txt

        return render

    def _gesture_fact(self) -> None:
        """Whole-hand shapes (fist, pointing, …) formed at the ends of the finger moves."""
        ends = sorted((m["end"], f, m["to"]) for f in _FINGERS for m in self.moves[f])
        if not ends:
            return
        sh = {f: self.moves[f][0]["from"] if self.moves[f] else _shape(f, self.final[f]) for f in _FINGERS}
        seq: list[tuple[int, str]] = []
        g = _gesture(sh)
        if g:
            seq.append((0, g))
        for k, (t, f, to) in enumerate(ends):
            sh[f] = to
            if k + 1 < len(ends) and ends[k + 1][0] == t:
                continue
            g = _gesture(sh)
            if g and (not seq or seq[-1][1] != g):
                seq.append((t, g))
        if not seq or (len(seq) == 1 and seq[0][0] == 0):
            return
        names = {g for _, g in seq}
        formed = [(t, g) for t, g in seq if t > 0]
        tm, rng = self.tm, self.rng

        def render(d: int) -> str:
            if len(formed) >= 3:
                kinds = sorted({g for _, g in formed}, key=lambda g: [x for _, x in formed].index(g))
                txt = f"the hand changes shape {len(formed)} times, forming {_join([_GESTURE_WORDS[g] for g in kinds])}"
            elif len(formed) == 2:
                txt = (f"the hand forms {_GESTURE_WORDS[formed[0][1]]}, then "
                       f"{_GESTURE_WORDS[formed[1][1]]}")
            else:
                t, g = formed[0]
                if g == "flat":
                    txt = f"the hand {_pick(rng, ['opens out flat', 'flattens out', 'opens fully'])}"
                else:
                    txt = f"the hand {_pick(rng, ['forms', 'makes', 'ends up in'])} {_GESTURE_WORDS[g]}"
                if seq[0][0] == 0 and seq[0][1] != g:
                    txt += f" from {_GESTURE_WORDS[seq[0][1]]}"
            if d >= 4:
                txt += " at " + _join([f"{t / tm.fps:.1f}" for t, _ in formed[:4]]) + " s"
            elif d >= 2:
                txt += " " + tm.rough(formed[0][0] - 5, formed[-1][0])
            return txt

        # A plain fist / flat hand is already said by the group of four fingers.
        plain = names <= {"fist", "flat"} and any(set(_FOUR) <= set(g) for g in self.groups)
        sal = 2.0 if plain else 7.0 + len(formed)
        self.facts.append(_Fact(sal, formed[0][0] - 5, formed[-1][0], render))

    def _static_facts(self) -> None:
        by_shape: dict[str, list[str]] = {}
        for f in _FINGERS:
            if not self.moves[f]:
                by_shape.setdefault(_shape(f, self.final[f]), []).append(f)
        rng = self.rng
        for shape, fingers in by_shape.items():
            who, plural = _finger_group(fingers)
            thumb = fingers == ["thumb"]
            if shape == "back":
                joint = "knuckles" if plural else "knuckle"
                self.facts.append(_Fact(60.0, None, self.tm.T, lambda d, who=who, plural=plural, joint=joint:
                                        f"{who} {'stay' if plural else 'stays'} hyperextended" +
                                        (f", bent backwards at the {joint}" if d >= 1 else ""), True))
                continue
            sal = 0.6 if shape == "straight" else 1.2
            self.facts.append(_Fact(sal, None, self.tm.T, lambda d, who=who, plural=plural, shape=shape, thumb=thumb:
                                    f"{who} {_pick(rng, ['stay', 'remain']) if plural else _pick(rng, ['stays', 'remains'])} "
                                    f"{self._shape_word(shape, thumb)}"))

    # -- pinches, spacing, wrist -----------------------------------------------------------------
    def _contact_facts(self, contacts: dict) -> None:
        tm, rng = self.tm, self.rng
        items = []  # (runs, fingers)
        for key in sorted(contacts, key=lambda k: _FINGERS.index(k.split("_")[0])):
            runs = contacts[key]
            f = key.split("_")[0]
            for it in items:
                r0 = it[0]
                if len(r0) == len(runs) and all(abs(a["start"] - b["start"]) <= 3 for a, b in zip(r0, runs)):
                    it[1].append(f)
                    break
            else:
                items.append((runs, [f]))
        for runs, fingers in items:
            tips = f"{_join(fingers)} fingertip{'s' if len(fingers) > 1 else ''}"
            s0, s1 = runs[0]["start"], runs[-1]["end"]
            whole = len(runs) == 1 and s1 - s0 >= 0.8 * tm.T

            def render(d: int, runs=runs, tips=tips, whole=whole, s0=s0, s1=s1) -> str:
                if whole:
                    return f"the thumb and {tips} stay pinched together"
                if len(runs) >= 2:
                    txt = f"the thumb taps the {tips} {_count(len(runs))}"
                else:
                    txt = _pick(rng, [f"the thumb pinches the {tips}", f"the thumb touches the {tips}",
                                      f"the thumb and {tips} pinch together"])
                if d >= 4:
                    sec = rng.random() < 0.5
                    txt += " " + (_join([tm.exact(r["start"], r["end"], None, sec) for r in runs[:3]]) if len(runs) <= 3
                                  else tm.exact(s0, s1, rng))
                elif d >= 2:
                    txt += " " + tm.rough(s0, s1)
                return txt

            self.facts.append(_Fact(10.0 + len(runs) + len(fingers), s0, s1, render, True))

    def _spacing_facts(self, spacing: dict) -> None:
        eps: list[dict] = []  # episodes: spreading or closing of one or more neighbour pairs together
        for key, evs in spacing.items():
            a, b = key.split(", ")
            for e in evs:
                if "state" in e:
                    continue
                opening = e["end_state"] == "open"
                for ep in eps:
                    if ep["open"] == opening and e["start"] <= ep["end"] + 4 and ep["start"] <= e["end"] + 4:
                        ep["start"], ep["end"] = min(ep["start"], e["start"]), max(ep["end"], e["end"])
                        ep["fingers"] |= {a, b}
                        ep["speed"] = max(ep["speed"], _SPEED_RANK[e["speed"]])
                        break
                else:
                    eps.append({"start": e["start"], "end": e["end"], "open": opening, "fingers": {a, b},
                                "speed": _SPEED_RANK[e["speed"]]})
        if not eps:
            return
        eps.sort(key=lambda ep: ep["start"])
        tm, rng = self.tm, self.rng

        def who(fs):
            return "the fingers" if len(fs) == 4 else f"the {_join(sorted(fs, key=_FINGERS.index))} fingers"

        if len(eps) >= 3:
            fs = set().union(*(ep["fingers"] for ep in eps))
            opens = sum(ep["open"] for ep in eps)
            first = eps[0]["open"]

            def render(d: int) -> str:
                txt = f"{who(fs)} {'spread and close' if first else 'close and spread'} {_count(max(opens, len(eps) - opens))}"
                if d >= 1:
                    txt += " " + _pick(rng, _SPEED_ADV[max(ep["speed"] for ep in eps)])
                if d >= 4:
                    txt += " " + tm.exact(eps[0]["start"], eps[-1]["end"], rng)
                elif d >= 2:
                    txt += " " + tm.rough(eps[0]["start"], eps[-1]["end"])
                return txt

            self.facts.append(_Fact(2.5, eps[0]["start"], eps[-1]["end"], render))
            return
        for ep in eps:
            def render(d: int, ep=ep) -> str:
                verb = _pick(rng, ["spread apart", "fan out"]) if ep["open"] else \
                    _pick(rng, ["close together", "come together", "squeeze together"])
                txt = f"{who(ep['fingers'])} {verb}"
                if d >= 1:
                    txt += " " + _pick(rng, _SPEED_ADV[ep["speed"]])
                if d >= 4:
                    txt += " " + tm.exact(ep["start"], ep["end"], rng)
                elif d >= 3:
                    txt += " " + tm.rough(ep["start"], ep["end"])
                return txt

            self.facts.append(_Fact(1.0 + 0.4 * len(ep["fingers"]), ep["start"], ep["end"], render))

    def _wrist_facts(self, wrist: dict) -> None:
        evs = []
        for axis, lst in wrist.items():
            for e in lst:
                if "direction" in e:
                    evs.append(dict(e, axis=axis))
        tm, rng = self.tm, self.rng
        if not evs:
            self.facts.append(_Fact(0.8, None, tm.T, lambda d: _pick(rng, 
                ["the wrist stays in place", "the hand keeps its position", "the wrist barely moves"])))
            return
        evs.sort(key=lambda e: e["start"])
        # Back-and-forth along one axis: a swing, said once with its count.
        by_axis: dict[str, list[dict]] = {}
        for e in evs:
            by_axis.setdefault(e["axis"], []).append(e)
        swing_axis = None
        for axis, lst in by_axis.items():
            if len(lst) >= 3 and all(a["direction"] != b["direction"] for a, b in zip(lst, lst[1:])):
                if swing_axis is None or len(lst) > len(by_axis[swing_axis]):
                    swing_axis = axis
        if swing_axis is not None:
            lst = by_axis.pop(swing_axis)
            evs = [e for e in evs if e["axis"] != swing_axis]
            cm = round(100 * sum(e["displacement_m"] for e in lst) / len(lst))
            sp = max(_SPEED_RANK[e["speed"]] for e in lst)

            def render(d: int, lst=lst, cm=cm, sp=sp) -> str:
                txt = f"the hand {_pick(rng, ['swings', 'sways', 'moves'])} {_SWING[lst[0]['axis']]} {_count(len(lst))}"
                if d >= 1:
                    txt += " " + _pick(rng, _SPEED_ADV[sp])
                if d >= 3:
                    txt += f" by about {cm} cm"
                if d >= 4:
                    txt += " " + tm.exact(lst[0]["start"], lst[-1]["end"], rng)
                elif d >= 2:
                    txt += " " + tm.rough(lst[0]["start"], lst[-1]["end"])
                return txt

            self.facts.append(_Fact(3.0 + cm / 4, lst[0]["start"], lst[-1]["end"], render))
        segs: list[dict] = []  # moves of different axes that overlap form one diagonal move
        for e in evs:
            for s in segs:
                if e["start"] < s["end"] - 5 and s["start"] < e["end"] - 5 and \
                        all(p["axis"] != e["axis"] for p in s["parts"]):
                    s["start"], s["end"] = min(s["start"], e["start"]), max(s["end"], e["end"])
                    s["parts"].append(e)
                    break
            else:
                segs.append({"start": e["start"], "end": e["end"], "parts": [e]})
        for s in segs:
            parts = sorted(s["parts"], key=lambda p: -p["displacement_m"])
            self.segs.append((s["start"], s["end"], parts[0]["direction"]))
            sp = max(_SPEED_RANK[p["speed"]] for p in parts)
            big = 100 * parts[0]["displacement_m"]

            def render(d: int, s=s, parts=parts, sp=sp) -> str:
                dirs = _join([_DIR_WORDS[p["direction"]] for p in parts])
                txt = f"{_pick(rng, ['the hand moves', 'the wrist travels', 'the hand shifts'])} {dirs}"
                if d >= 1:
                    txt += " " + _pick(rng, _SPEED_ADV[sp])
                if d >= 2:
                    txt += f" by about {round(100 * parts[0]['displacement_m'])} cm"
                if d >= 4:
                    txt += " " + tm.exact(s["start"], s["end"], rng)
                elif d >= 3:
                    txt += " " + tm.rough(s["start"], s["end"])
                return txt

            self.facts.append(_Fact(big / 2.5 * _SPEED_FACTOR[sp], s["start"], s["end"], render))


_FLEX_ORDER_SHAPE = {"back": -1, "straight": 0, "hooked": 1, "half": 1, "curled": 2}


# ---------------------------------------------------------------------------------------------
# Two hands: contacts, finger–palm touches, palm distance, relative position


def _contact_periods(evs: list[dict], T: int) -> list[tuple[int, int]]:
    """Periods [s, e) in the "contact" state of a finger–palm series, from its events (between two
    transitions the series holds the state the first one ended in)."""
    if not evs:
        return []
    if "state" in evs[0]:
        return [(0, T)] if evs[0]["state"] == "contact" else []
    out = []
    start = 0 if evs[0]["start_state"] == "contact" else None
    for e in evs:
        if e["start_state"] == "contact" and start is not None:
            out.append((start, e["start"] + 1))
            start = None
        if e["end_state"] == "contact":
            start = max(e["end"] - 1, 0)
    if start is not None:
        out.append((start, T))
    return [(s, e) for s, e in out if e > s]


def _episodes(items: list[tuple[int, int, str, str]], gap: int = 1) -> list[dict]:
    """Cluster (start, end, a, b) periods that overlap (or nearly touch) into episodes with the sets
    of a- and b-members involved."""
    eps: list[dict] = []
    for s, e, a, b in sorted(items):
        if eps and s <= eps[-1]["end"] + gap:
            ep = eps[-1]
            ep["end"] = max(ep["end"], e)
            ep["a"].add(a)
            ep["b"].add(b)
        else:
            eps.append({"start": s, "end": e, "a": {a}, "b": {b}})
    return eps


def _tips(fingers, side: str | None = None) -> str:
    fs = sorted(fingers, key=_FINGERS.index)
    pre = f"{side} " if side else ""
    if len(fs) == 5:
        return f"all {pre}fingertips"
    return f"the {pre}{_join(fs)} tip{'s' if len(fs) > 1 else ''}"


class _InterFacts:
    def __init__(self, rel: dict, tm: _Timing, rng: random.Random):
        self.tm, self.rng = tm, rng
        self.facts: list[_Fact] = []
        self.touch = False
        self._tip_facts(rel.get("finger_tip_contact", {}))
        self._finger_palm_facts(rel.get("finger_palm_distance", {}))
        self._palm_distance_facts(rel.get("palm_palm_distance", {}).get("left_palm, right_palm", []))
        self._relative_facts(rel.get("palm_palm_relative_position", {}))
        if not self.touch:
            self.facts.append(_Fact(4.0, None, tm.T, lambda d: _pick(rng, 
                ["the hands never touch", "there is no contact between the hands",
                 "the two hands stay out of contact"])))

    def _timed(self, txt: str, d: int, s: int, e: int, sp: int | None = None, rough_from: int = 2) -> str:
        if sp is not None and d >= 1:
            txt += " " + _pick(self.rng, _SPEED_ADV[sp])
        if d >= 4:
            return txt + " " + self.tm.exact(s, e, self.rng)
        if d >= rough_from:
            return txt + " " + self.tm.rough(s, e)
        return txt

    def _tip_facts(self, tip: dict) -> None:
        items = []
        for key, lst in tip.items():
            l, r = key.split(", ")
            for e in lst:
                items.append((e["start"], e["end"], l.split("_")[1], r.split("_")[1]))
        if not items:
            return
        self.touch = True
        eps = _episodes(items)
        by_set: dict[tuple, list[dict]] = {}
        for ep in eps:
            by_set.setdefault((tuple(sorted(ep["a"], key=_FINGERS.index)), tuple(sorted(ep["b"], key=_FINGERS.index))),
                              []).append(ep)
        tm, rng = self.tm, self.rng

        def phrase(lf, rf, n):
            if lf == rf:
                who = "the two thumbs" if lf == ("thumb",) else \
                    f"the two {lf[0]} fingertips" if len(lf) == 1 else f"the {_join(list(lf))} fingertips of both hands"
                if len(lf) == 5:
                    who = "all fingertips of both hands"
                verb = "touch" if n == 1 else f"touch {_count(n)}"
                return f"{who} {_pick(rng, [verb, verb.replace('touch', 'meet')])}"
            lw = _tips(lf, "left")
            verb = "touches" if len(lf) == 1 else "touch"
            return f"{lw} {verb} {_tips(rf, 'right')}" + (f" {_count(n)}" if n > 1 else "")

        if len(by_set) > 3:  # many different touches: one summary with the fingers most involved
            lf = sorted({f for ep in eps for f in ep["a"]}, key=_FINGERS.index)
            rf = sorted({f for ep in eps for f in ep["b"]}, key=_FINGERS.index)

            def render(d: int) -> str:
                txt = f"the fingertips of both hands touch {len(eps)} times"
                if d >= 1:
                    txt += f", the left {_join(lf)} against the right {_join(rf)}"
                return self._timed(txt, d, eps[0]["start"], eps[-1]["end"])

            self.facts.append(_Fact(12.0, eps[0]["start"], eps[-1]["end"], render, True))
            return
        for (lf, rf), group in by_set.items():
            s0, s1 = group[0]["start"], group[-1]["end"]

            def render(d: int, lf=lf, rf=rf, group=group, s0=s0, s1=s1) -> str:
                txt = phrase(lf, rf, len(group))
                if d >= 4 and len(group) <= 3:
                    sec = rng.random() < 0.5
                    return txt + " " + _join([tm.exact(g["start"], g["end"], None, sec) for g in group])
                if len(group) == 1 and group[0]["end"] - group[0]["start"] >= 0.8 * tm.T:
                    return txt + " throughout"
                return self._timed(txt, d, s0, s1)

            self.facts.append(_Fact(11.0 + len(group) + 0.5 * len(lf), s0, s1, render, True))

    def _finger_palm_facts(self, fp: dict) -> None:
        tm, rng = self.tm, self.rng
        contact: dict[str, list] = {"left": [], "right": []}
        near: dict[str, list] = {"left": [], "right": []}
        for key, evs in fp.items():
            tip, palm = key.split(", ")
            side, finger = tip.split("_")[:2]
            for s, e in _contact_periods(evs, tm.T):
                contact[side].append((s, e, finger, palm.split("_")[0]))
            if not contact[side] or contact[side][-1][2] != finger:
                for e in evs:
                    if "state" in e and e["state"] == "near" or e.get("end_state") == "near":
                        near[side].append((e["start"], e["end"], finger, palm.split("_")[0]))
        for side in ("left", "right"):
            other = "right" if side == "left" else "left"
            if contact[side]:
                self.touch = True
                eps = _episodes(contact[side], gap=2)
                fingers = sorted({f for ep in eps for f in ep["a"]}, key=_FINGERS.index)

                def render(d: int, eps=eps, fingers=fingers, side=side, other=other) -> str:
                    n = len(eps)
                    verb = ("press on", "rest on", "touch") if len(fingers) > 1 else ("presses on", "rests on", "touches")
                    txt = f"{_tips(fingers, side)} {_pick(rng, verb)} the {other} palm"
                    if n > 1:
                        txt += f" {_count(n)}"
                    elif eps[0]["end"] - eps[0]["start"] >= 0.8 * tm.T:
                        return txt + " throughout"
                    if d >= 4 and n <= 3:
                        sec = rng.random() < 0.5
                        return txt + " " + _join([tm.exact(ep["start"], ep["end"], None, sec) for ep in eps])
                    return self._timed(txt, d, eps[0]["start"], eps[-1]["end"])

                self.facts.append(_Fact(10.0 + len(eps), eps[0]["start"], eps[-1]["end"], render, True))
            elif near[side]:
                eps = _episodes(near[side], gap=3)
                fingers = sorted({f for ep in eps for f in ep["a"]}, key=_FINGERS.index)

                def render(d: int, eps=eps, fingers=fingers, side=side, other=other) -> str:
                    txt = f"{_tips(fingers, side)} {_pick(rng, ['come close to', 'hover near'])} the {other} palm"
                    return self._timed(txt, d, eps[0]["start"], eps[-1]["end"], rough_from=3)

                self.facts.append(_Fact(2.0, eps[0]["start"], eps[-1]["end"], render))

    def _palm_distance_facts(self, pd: list[dict]) -> None:
        tm, rng = self.tm, self.rng
        if not pd:
            return
        if "state" in pd[0]:
            st = pd[0]["state"]
            if st == "contact":
                self.touch = True
            self.facts.append(_Fact(7.0 if st == "contact" else 1.5, None, tm.T, lambda d: (
                "the palms stay pressed together" if st == "contact" else
                f"the {_pick(rng, ['hands', 'palms'])} stay {_PALM_DIST_WORDS[st]}"), st == "contact"))
            return
        closings = [e for e in pd if _PALM_ORDER[e["end_state"]] < _PALM_ORDER[e["start_state"]]]
        meets = [e for e in closings if e["end_state"] == "contact"]
        if meets:
            self.touch = True
        s0, s1 = pd[0]["start"], pd[-1]["end"]
        sp = max(_SPEED_RANK[e["speed"]] for e in pd)
        if len(meets) >= 2 or len(pd) >= 3:
            n = max(len(meets), len(closings))

            def render(d: int) -> str:
                if len(meets) >= 2:
                    txt = f"the palms {_pick(rng, ['clap together', 'meet', 'come together'])} {_count(len(meets))}"
                else:
                    txt = f"the hands move together and apart {_count(n)}"
                if d >= 3:
                    closest = min(pd, key=lambda e: _PALM_ORDER[e["end_state"]])["end_state"]
                    if not meets:
                        txt += f", getting {_PALM_DIST_WORDS[closest]}"
                return self._timed(txt, d, s0, s1, sp)

            self.facts.append(_Fact(9.0 if meets else 4.0 + n * 0.5, s0, s1, render, bool(meets)))
            return
        for e in pd:
            closer = _PALM_ORDER[e["end_state"]] < _PALM_ORDER[e["start_state"]]

            def render(d: int, e=e, closer=closer) -> str:
                if e["end_state"] == "contact":
                    verb = _pick(rng, ["the palms come together until they touch", "the palms meet"])
                elif e["start_state"] == "contact":
                    verb = _pick(rng, ["the palms separate", "the palms pull apart"])
                elif closer:
                    verb = _pick(rng, ["the hands come together", "the palms approach each other", "the hands close in"])
                else:
                    verb = _pick(rng, ["the hands separate", "the palms move apart", "the hands draw apart"])
                txt = verb
                if d >= 2 and e["end_state"] != "contact":
                    txt += f" until {_PALM_DIST_WORDS[e['end_state']]}"
                return self._timed(txt, d, e["start"], e["end"], _SPEED_RANK[e["speed"]])

            contact = "contact" in (e["end_state"], e["start_state"])
            sal = (8.0 if contact else 3.0 + abs(_PALM_ORDER[e["end_state"]] - _PALM_ORDER[e["start_state"]]) * 0.5) \
                * _SPEED_FACTOR[_SPEED_RANK[e["speed"]]]
            self.facts.append(_Fact(sal, e["start"], e["end"], render, contact))

    def _relative_facts(self, rp: dict) -> None:
        tm, rng = self.tm, self.rng
        const, segs = [], []
        for axis, evs in rp.items():
            if evs and "state" in evs[0]:
                if _REL_PHRASE[evs[0]["state"]]:
                    const.append(_REL_PHRASE[evs[0]["state"]])
                continue
            moves = [e for e in evs if "state" not in e]
            if len(moves) >= 3:
                def render(d: int, moves=moves, axis=axis) -> str:
                    txt = f"the right hand moves {_SWING[axis]} relative to the left {_count(len(moves))}"
                    return self._timed(txt, d, moves[0]["start"], moves[-1]["end"],
                                       max(_SPEED_RANK[e["speed"]] for e in moves), rough_from=3)

                self.facts.append(_Fact(4.0, moves[0]["start"], moves[-1]["end"], render))
                continue
            for e in moves:
                for seg in segs:  # moves along different axes at the same time are one move
                    if e["start"] < seg["end"] - 3 and seg["start"] < e["end"] - 3 and axis not in seg["axes"]:
                        seg["start"], seg["end"] = min(seg["start"], e["start"]), max(seg["end"], e["end"])
                        seg["parts"].append(e)
                        seg["axes"].add(axis)
                        break
                else:
                    segs.append({"start": e["start"], "end": e["end"], "parts": [e], "axes": {axis}})
        for seg in segs:
            sp = max(_SPEED_RANK[e["speed"]] for e in seg["parts"])

            def render(d: int, seg=seg, sp=sp) -> str:
                to = [_REL_PHRASE[e["end_state"]] for e in seg["parts"]]
                frm = [_REL_PHRASE[e["start_state"]] for e in seg["parts"]]
                if all(b is None for b in to):
                    txt = _pick(rng, ["the right hand comes level with the left", "the right hand lines up with the left"])
                else:
                    txt = f"the right hand {_pick(rng, ['moves', 'shifts'])} {_join([b for b in to if b])} the left"
                    if d >= 3 and any(frm):
                        a = _join([x for x in frm if x])
                        txt += f" from {'being ' if a.startswith('to ') else ''}{a} it"
                return self._timed(txt, d, seg["start"], seg["end"], sp, rough_from=2)

            self.facts.append(_Fact((3.0 + 0.5 * len(seg["parts"])) * _SPEED_FACTOR[sp], seg["start"], seg["end"], render))
        if const:
            self.facts.append(_Fact(1.5, None, tm.T, lambda d: (
                f"the right hand {_pick(rng, ['stays', 'remains', 'is held'])} {_join(const)} the left")))


_TOWARD = {("left-to-right", "right-to-left"): "move toward each other",
           ("right-to-left", "left-to-right"): "move apart sideways"}


def _coordination(hl: "_HandFacts", hr: "_HandFacts", tm: _Timing, rng: random.Random) -> list[_Fact]:
    """How the two hands' own movements relate: finger actions in unison or in turn, and wrist
    moves together, toward or away from each other (paper §4: "global coordination patterns")."""
    facts = []
    if hl.main is not None and hr.main is not None:
        a, b = hl.main[1], hr.main[1]
        if len(a) == len(b) and all(m["dir"] == n["dir"] for m, n in zip(a, b)):
            lag = b[0]["start"] - a[0]["start"]
            s0, s1 = min(a[0]["start"], b[0]["start"]), max(a[-1]["end"], b[-1]["end"])
            if abs(lag) <= 6:
                def render(d: int) -> str:
                    txt = _pick(rng, ["both hands move their fingers in unison", "the two hands mirror each other's finger movements",
                                      "the fingers of both hands move in sync"])
                    return txt + (" " + tm.rough(s0, s1) if 2 <= d < 4 else " " + tm.exact(s0, s1, rng) if d >= 4 else "")
            else:
                lead, follow = ("left", "right") if lag > 0 else ("right", "left")

                def render(d: int, lead=lead, follow=follow, lag=abs(lag)) -> str:
                    txt = f"the {follow} hand's fingers repeat the {lead} hand's movement"
                    if d >= 2:
                        txt += f" about {lag / tm.fps:.1f} s later"
                    return txt
            facts.append(_Fact(3.5, s0, s1, render))
    for sl in hl.segs:
        for sr in hr.segs:
            ov = min(sl[1], sr[1]) - max(sl[0], sr[0])
            if ov < 0.5 * min(sl[1] - sl[0], sr[1] - sr[0]):
                continue
            s0, s1 = min(sl[0], sr[0]), max(sl[1], sr[1])
            if sl[2] == sr[2]:
                txt = f"both hands move {_DIR_WORDS[sl[2]]} together"
            elif (sl[2], sr[2]) in _TOWARD:
                txt = f"the hands {_TOWARD[(sl[2], sr[2])]}"
            else:
                continue
            facts.append(_Fact(3.0, s0, s1, lambda d, txt=txt, s0=s0, s1=s1: txt + (
                " " + tm.exact(s0, s1, rng) if d >= 4 else " " + tm.rough(s0, s1) if d >= 2 else "")))
            break
    return facts


WORDINGS = ("shared", "per_fact")


class TemplateCaptioner:
    """Deterministic, seeded template captions: same (record, seed) → same five levels.

    Facts (module docstring) are chosen by salience into each level's word budget
    (``BUDGET_WORDS``): level 0 says the single most salient thing (plus any contact or
    hyperextension), level 1 adds speeds and the next facts, level 2 rough timing and distances,
    level 3 start shapes and per-move timing, and level 4 the exact timing (seconds or frames) and
    speed of every event it mentions.

    ``wording`` says where the random word choices come from. ``"shared"`` (every corpus before
    issue 40): one stream per clip, drawn in rendering order, so one extra event anywhere rewords
    every clause rendered after it. ``"per_fact"``: each fact draws from a stream seeded by (seed,
    text field, the kind of fact, its rank among facts of that kind, detail): not by its exact frames,
    which move with the noise and each text's sentence joins from one
    seeded by (seed, field, level), so a fact is worded the same whatever else the record holds.
    """

    def __init__(self, wording: str = "shared"):
        if wording not in WORDINGS:
            raise ValueError(f"unknown wording {wording!r}; choose one of {', '.join(WORDINGS)}")
        self.wording = wording

    def caption(self, record: dict, *, seed: int) -> list[dict]:
        rng = random.Random(seed)
        tm = _Timing(int(record.get("fps", 30)), int(record["frame_count"]))
        hl = _HandFacts(record["left_hand_events"], tm, rng)
        hr = _HandFacts(record["right_hand_events"], tm, rng)
        left, right = hl.facts, hr.facts
        inter = _InterFacts(record["two_hand_relationships"], tm, rng).facts
        inter = inter + _coordination(hl, hr, tm, rng)
        fields = (("left", left, "the hand holds still"), ("right", right, "the hand holds still"),
                  ("interaction", inter, "the hands move independently"))
        per_fact = self.wording == "per_fact"
        if per_fact:
            for name, facts, _ in fields:
                seen: dict[str, int] = {}
                for f in facts:
                    key = f"{seed}/{name}/{f.render.__qualname__}"
                    seen[key] = seen.get(key, -1) + 1
                    f.stream = (rng, f"{key}/{seen[key]}")
        by_sal = [sorted(range(len(f)), key=lambda k: -f[k].sal) for _, f, _ in fields]
        out = []
        for lv in range(LEVELS):
            texts = {}
            for (name, facts, fallback), order in zip(fields, by_sal):
                if per_fact:
                    rng.seed(f"{seed}/{name}/compose/{lv}")
                texts[name] = _compose(facts, lv, rng, fallback, order)
            out.append(texts)
        return out


# ---------------------------------------------------------------------------------------------
# LLM prompt (paper §4 and Fig. D; structure of reference §6.4, wording our own)

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
