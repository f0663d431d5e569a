"""Captions from structured event records: the ``Captioner`` protocol, a seeded template captioner,
the LLM prompt (paper §4, Fig. D; reference §6.4) and an LLM captioner around a user callable.

Every captioner returns FIVE levels, index 0 the most concise and 4 the most detailed, each a dict
``{"left": str, "right": str, "interaction": str}``. Frame ranges in records are half-open
[start, end) (see ``events.py``); texts quote them as "frames s–e" with e = end − 1 (inclusive, as a
reader expects) or as seconds at the record's fps.
"""

from __future__ import annotations

import json
import random
from typing import Callable, Protocol

from handx_jax.io import DataError

LEVELS = 5
_FINGERS = ("thumb", "index", "middle", "ring", "pinky")
_JOINT_WORDS = {"mcp": "knuckle", "pip": "middle joint", "dip": "tip joint", "ip": "tip joint"}
# Flexion state order (Table A) for deciding bend vs straighten.
_FLEX_ORDER = {"hyper extend": -1, "fully extend": 0, "partially bent": 1, "fully bent": 2}
_FLEX_WORDS = {
    "hyper extend": ("hyperextended", "bent backwards (hyperextended)"),
    "fully extend": ("straight", "fully extended"),
    "partially bent": ("partly bent", "half curled"),
    "fully bent": ("fully bent", "tightly curled"),
}
_NUMBER = {1: "once", 2: "twice", 3: "three times", 4: "four times", 5: "five times", 6: "six times"}
_SPEED_ADV = {"slow": ("slowly", "gently"), "medium": ("steadily", "at a moderate pace"),
              "fast": ("quickly", "rapidly")}
_DIR_WORDS = {"left-to-right": "to the right", "right-to-left": "to the left", "back-to-front": "forward",
              "front-to-back": "backward", "down-to-up": "upward", "up-to-down": "downward"}
_REL_PHRASE = {"left": "to the left of", "right": "to the right of", "behind": "behind",
               "in front": "in front of", "below": "below", "above": "above", "aligned": None}
_PALM_DIST_WORDS = {"contact": "touching", "near": "close together", "medium": "a short distance apart",
                    "far": "far apart"}
_FP_WORDS = {"contact": "touches", "near": "hovers near", "far": "stays away from"}


class Captioner(Protocol):
    def caption(self, record: dict, *, seed: int) -> list[dict]:
        """Five levels (0 = one-line summary … 4 = comprehensive), each {left, right, interaction}."""
        ...


# ---------------------------------------------------------------------------------------------
# Event digestion shared by all levels


def _join(items: list[str]) -> str:
    items = [i for i in items if i]
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


def _finger_group(fingers: list[str]) -> str:
    fingers = sorted(set(fingers), key=_FINGERS.index)
    if len(fingers) == 4 and "thumb" not in fingers:
        return "all four fingers"
    if len(fingers) == 5:
        return "all five digits"
    noun = "finger" if len(fingers) == 1 else "fingers"
    if fingers == ["thumb"]:
        return "the thumb"
    return f"the {_join(fingers)} {noun}"


class _Timing:
    def __init__(self, fps: int, T: int):
        self.fps, self.T = fps, T

    def sec(self, f: int) -> str:
        return f"{f / self.fps:.1f} s"

    def span(self, s: int, e: int, style: int) -> str:
        """A half-open [s, e) range as seconds (e is the end instant) or inclusive frames."""
        if style == 0:
            a, b = self.sec(s), self.sec(e)
            return f"at {a}" if a == b else f"from {a} to {b}"
        return f"at frame {s}" if e - s <= 1 else f"during frames {s}–{e - 1}"

    def rough(self, s: int, e: int) -> str:
        mid = (s + e) / 2 / self.T
        if e - s >= 0.8 * self.T:
            return "throughout the clip"
        return ("at the start" if mid < 0.3 else "in the middle" if mid < 0.65 else "toward the end")


def _finger_moves(flexing: dict) -> tuple[dict, dict]:
    """Per finger: merged transition moves and static joint states.

    Joint transitions of one finger with the same (start_state → end_state) and overlapping frames
    merge into one move listing the joints involved (reference §6.4: describe whole fingers).
    """
    moves: dict[str, list[dict]] = {}
    static: dict[str, dict[str, str]] = {}
    for name, evs in flexing.items():
        finger, joint = name.split("_")
        for e in evs:
            if "state" in e:
                static.setdefault(finger, {})[joint] = e["state"]
                continue
            lst = moves.setdefault(finger, [])
            for m in lst:
                if (m["from"], m["to"]) == (e["start_state"], e["end_state"]) and \
                        e["start"] < m["end"] + 3 and m["start"] < e["end"] + 3:
                    m["start"], m["end"] = min(m["start"], e["start"]), max(m["end"], e["end"])
                    m["joints"].append(joint)
                    if e["speed"] == "fast" or (e["speed"] == "medium" and m["speed"] == "slow"):
                        m["speed"] = e["speed"]
                    break
            else:
                lst.append({"start": e["start"], "end": e["end"], "from": e["start_state"],
                            "to": e["end_state"], "speed": e["speed"], "joints": [joint]})
    for lst in moves.values():
        lst.sort(key=lambda m: m["start"])
    return moves, static


def _verb(base: str, plural: bool) -> str:
    """Third-person form of the first word of ``base`` ("curl into" → "curls into")."""
    if plural:
        return base
    w, _, rest = base.partition(" ")
    w = w + ("es" if w.endswith(("s", "sh", "ch", "x")) else "s")
    return f"{w} {rest}".strip()


def _move_verb(m: dict, rng: random.Random, plural: bool = False) -> str:
    a, b = _FLEX_ORDER[m["from"]], _FLEX_ORDER[m["to"]]
    to_w = rng.choice(_FLEX_WORDS[m["to"]])
    from_w = _FLEX_WORDS[m["from"]][0]
    if b == -1:
        v = rng.choice(["bend backwards into hyperextension", "hyperextend"])
        return _verb(v, plural) + f" from {from_w}"
    if b > a:
        if m["to"] == "fully bent":
            v = rng.choice(["curl into a full bend", "flex fully", "close into a tight curl"])
            return _verb(v, plural) + f" from {from_w}"
        return _verb(rng.choice(["bend", "flex", "curl"]), plural) + f" from {from_w} to {to_w}"
    return _verb(rng.choice(["straighten", "extend", "uncurl"]), plural) + f" from {from_w} to {to_w}"


def _joints_phrase(finger: str, joints: list[str]) -> str:
    full = {"thumb": {"mcp", "ip"}}.get(finger, {"mcp", "pip", "dip"})
    if set(joints) >= full:
        return ""
    return _join([_JOINT_WORDS[j] for j in sorted(set(joints), key=["mcp", "pip", "dip", "ip"].index)])


def _static_state(states: dict[str, str]) -> str:
    vals = list(states.values())
    return max(set(vals), key=lambda v: (vals.count(v), _FLEX_ORDER[v]))


class _Hand:
    """Digest of one hand's events into phrases at several detail levels."""

    def __init__(self, ev: dict, side: str, tm: _Timing, rng: random.Random):
        self.side, self.tm, self.rng = side, tm, rng
        self.moves, self.static = _finger_moves(ev.get("finger_flexing", {}))
        self.spacing = ev.get("finger_spacing", {})
        self.contacts = ev.get("finger_tip_contact", {})
        self.wrist = ev.get("wrist_trajectory", {})

    # -- fingers --------------------------------------------------------------------------
    def _same_moves(self, f: str, g: str, tol: int) -> bool:
        a, b = self.moves[f], self.moves[g]
        return len(a) == len(b) and all(
            (m["from"], m["to"]) == (n["from"], n["to"]) and abs(m["start"] - n["start"]) <= tol
            and abs(m["end"] - n["end"]) <= tol
            and (_joints_phrase(f, m["joints"]) == "") == (_joints_phrase(g, n["joints"]) == "")
            for m, n in zip(a, b))

    def finger_clauses(self, detail: int) -> list[str]:
        """Clauses for moving fingers, grouped when they do the same thing at about the same time
        (within 3 frames at level 4, 8 below), in temporal order."""
        tol = 3 if detail >= 4 else 8
        groups: list[list[str]] = []
        for f in _FINGERS:
            if not self.moves.get(f):
                continue
            for grp in groups:
                if grp[0] != "thumb" and f != "thumb" and self._same_moves(grp[0], f, tol):
                    grp.append(f)
                    break
            else:
                groups.append([f])
        items = []
        for fingers in groups:
            mv = [dict(m) for m in self.moves[fingers[0]]]
            for g in fingers[1:]:  # the group's range covers all its fingers
                for m, n in zip(mv, self.moves[g]):
                    m["start"], m["end"] = min(m["start"], n["start"]), max(m["end"], n["end"])
            items.append((mv[0]["start"], fingers, mv))
        items.sort(key=lambda t: t[0])
        out = []
        for _, fingers, mv in items:
            who = _finger_group(fingers)
            parts = []
            # Repetition: alternating bend/straighten of the same states.
            pairs = [(m["from"], m["to"]) for m in mv]
            if len(mv) >= 3 and all(pairs[i] == pairs[i % 2] for i in range(len(pairs))) and \
                    pairs[0] == (pairs[1][1], pairs[1][0]):
                n = (len(mv) + 1) // 2
                verb = "bends and straightens" if _FLEX_ORDER[pairs[0][1]] > _FLEX_ORDER[pairs[0][0]] \
                    else "straightens and bends"
                txt = f"{who} {verb} {_NUMBER.get(n, f'{n} times')}"
                if detail >= 3:
                    txt += f" between {_FLEX_WORDS[pairs[0][0]][0]} and {_FLEX_WORDS[pairs[0][1]][0]}"
                if detail >= 4:
                    txt += " (" + "; ".join(f"{self.tm.span(m['start'], m['end'], 1)}, {m['speed']}" for m in mv) + ")"
                elif detail >= 2:
                    txt += f" {self.tm.rough(mv[0]['start'], mv[-1]['end'])}"
                out.append(txt)
                continue
            for i, m in enumerate(mv if detail >= 2 else mv[:1]):
                jp = _joints_phrase(fingers[0], m["joints"])
                many = len(fingers) > 1
                lead = "" if i == 0 else self.rng.choice(["then ", "after that ", "next "])
                if jp:
                    njoint = len(set(m["joints"]))
                    subj = (f"{who}'s {jp}" if not many else f"{who}' {jp}s") if i == 0 else \
                        f"{lead}{'their' if many else 'its'} {jp}{'s' if many and njoint == 1 else ''}"
                    plural = many or njoint > 1
                else:
                    subj = who if i == 0 else f"{lead}{'they' if many else 'it'}"
                    plural = many
                txt = f"{subj} {_move_verb(m, self.rng, plural)}"
                if detail >= 1:
                    txt += " " + self.rng.choice(_SPEED_ADV[m["speed"]])
                if detail >= 4:
                    txt += " " + self.tm.span(m["start"], m["end"], self.rng.randrange(2))
                elif detail >= 3:
                    txt += " " + self.tm.rough(m["start"], m["end"])
                parts.append(txt)
            out.append(", ".join(parts) if detail < 2 else "; ".join(parts))
        return out

    def static_clauses(self, detail: int) -> list[str]:
        """Fingers that hold a pose; hyperextended joints are always reported (paper §4 (b))."""
        by_state: dict[str, list[str]] = {}
        hyper = []
        for f in _FINGERS:
            if self.moves.get(f) or f not in self.static:
                continue
            st = _static_state(self.static[f])
            by_state.setdefault(st, []).append(f)
            for j, s in self.static[f].items():
                if s == "hyper extend" and st != "hyper extend":
                    hyper.append(f"the {f} {_JOINT_WORDS[j]}")
        out = []
        for st, fingers in sorted(by_state.items(), key=lambda kv: _FLEX_ORDER[kv[0]]):
            if detail < 2 and st != "hyper extend" and len(out) >= 1:
                continue
            verb = "stays" if len(fingers) == 1 and fingers != ["thumb"] or fingers == ["thumb"] else "stay"
            out.append(f"{_finger_group(fingers)} {verb} {self.rng.choice(_FLEX_WORDS[st])}")
        if hyper:
            out.append(f"{_join(hyper)} {'is' if len(hyper) == 1 else 'are'} hyperextended")
        return out

    def spacing_clauses(self, detail: int) -> list[str]:
        out = []
        const: dict[str, list[str]] = {}
        for key, evs in self.spacing.items():
            a, b = key.split(", ")
            for e in evs:
                if "state" in e:
                    const.setdefault(e["state"], []).append(f"{a}–{b}")
                    continue
                verb = self.rng.choice(["spread apart", "fan out", "separate"]) if e["end_state"] == "open" \
                    else self.rng.choice(["close together", "come together", "squeeze together"])
                txt = f"the {a} and {b} fingers {verb}"
                if detail >= 3:
                    txt += " " + self.rng.choice(_SPEED_ADV[e["speed"]])
                if detail >= 4:
                    txt += " " + self.tm.span(e["start"], e["end"], 1)
                out.append(txt)
        if detail >= 3:
            for st, pairs in const.items():
                word = "open" if st == "open" else "closed"
                gap = "gap stays" if len(pairs) == 1 else "gaps stay"
                out.append(f"the {_join(pairs)} {gap} {word}")
        return out

    def contact_clauses(self, detail: int) -> list[str]:
        out = []
        for key, runs in self.contacts.items():
            f = key.split("_")[0]
            if len(runs) >= 2:
                txt = f"the thumb taps the {f} fingertip {_NUMBER.get(len(runs), f'{len(runs)} times')}"
            else:
                r = runs[0]
                if r["end"] - r["start"] >= 0.8 * self.tm.T:
                    txt = f"the thumb and {f} fingertips stay pinched together"
                else:
                    txt = self.rng.choice([f"the thumb touches the {f} fingertip", f"the thumb pinches the {f} tip",
                                           f"the {f} tip meets the thumb tip"])
            if detail >= 4:
                txt += " (" + "; ".join(self.tm.span(r["start"], r["end"], self.rng.randrange(2)) for r in runs) + ")"
            elif detail >= 2:
                txt += " " + self.tm.rough(runs[0]["start"], runs[-1]["end"])
            out.append(txt)
        return out

    def wrist_segments(self) -> list[dict]:
        """Wrist moves of the three axes merged into segments when their frames overlap."""
        evs = []
        for axis, lst in self.wrist.items():
            for e in lst:
                if "direction" in e:
                    evs.append(dict(e, axis=axis))
        evs.sort(key=lambda e: e["start"])
        segs: list[dict] = []
        for e in evs:
            for s in segs:
                if e["start"] < s["end"] - 5 and s["start"] < e["end"] - 5 and \
                        all(p["axis"] != e["axis"] for p in s["parts"]):
                    s["start"], s["end"] = min(s["start"], e["start"]), max(s["end"], e["end"])
                    s["parts"].append(e)
                    break
            else:
                segs.append({"start": e["start"], "end": e["end"], "parts": [e]})
        return segs

    def wrist_clauses(self, detail: int) -> list[str]:
        segs = self.wrist_segments()
        if not segs:
            return [self.rng.choice(["the wrist stays in place", "the hand keeps its position",
                                     "the wrist barely moves"])] if detail >= 1 else []
        out = []
        segs_used = segs if detail >= 2 else sorted(segs, key=lambda s: -max(p["displacement_m"] for p in s["parts"]))[:1]
        for s in segs_used:
            parts = sorted(s["parts"], key=lambda p: -p["displacement_m"])
            dirs = _join([_DIR_WORDS[p["direction"]] for p in parts])
            speed = max((p["speed"] for p in parts), key=["slow", "medium", "fast"].index)
            verb = self.rng.choice(["the hand moves", "the wrist travels", "the hand shifts", "the wrist moves"])
            txt = f"{verb} {dirs}"
            if detail >= 1:
                txt += " " + self.rng.choice(_SPEED_ADV[speed])
            if detail >= 3:
                cm = _join([f"{round(p['displacement_m'] * 100)} cm {_DIR_WORDS[p['direction']]}" for p in parts])
                txt += f" (about {cm})" if detail >= 4 else ""
                txt += " " + (self.tm.span(s["start"], s["end"], self.rng.randrange(2)) if detail >= 4
                              else self.tm.rough(s["start"], s["end"]))
            out.append(txt)
        return out

    def text(self, level: int) -> str:
        fc, sc = self.finger_clauses(level), self.static_clauses(level)
        wc = self.wrist_clauses(level)
        cc = self.contact_clauses(level) if level >= 1 else []
        spc = self.spacing_clauses(level) if level >= 2 else []
        if level == 0:
            first = fc[:1] or sc[:1]
            hyper = [c for c in sc if "hyperextended" in c and c not in first][:1]
            clauses = first + hyper + (wc[:1] if not fc else [])
            if not clauses:
                clauses = ["the hand holds still"]
            return _cap(_join(clauses)) + "."
        blocks = [fc, cc, spc, sc, wc]
        if self.rng.random() < 0.5 and level < 4:
            blocks = [wc, fc, cc, spc, sc]
        sents = []
        for b in blocks:
            if not b:
                continue
            if level >= 3:
                sents.extend(_cap(c) + "." for c in b)
            else:
                sents.append(_cap(_join(b)) + ".")
        return " ".join(sents)


def _cap(s: str) -> str:
    return s[:1].upper() + s[1:] if s else s


class _Interaction:
    def __init__(self, rel: dict, tm: _Timing, rng: random.Random):
        self.tm, self.rng = tm, rng
        self.tip = rel.get("finger_tip_contact", {})
        self.fp = rel.get("finger_palm_distance", {})
        self.pd = rel.get("palm_palm_distance", {}).get("left_palm, right_palm", [])
        self.rp = rel.get("palm_palm_relative_position", {})

    def contact_clauses(self, detail: int) -> list[str]:
        # Group tip pairs by (start, end) run so simultaneous touches read as one event.
        runs: dict[tuple[int, int], list[tuple[str, str]]] = {}
        for key, lst in self.tip.items():
            l, r = key.split(", ")
            for e in lst:
                runs.setdefault((e["start"], e["end"]), []).append((l.split("_")[1], r.split("_")[1]))
        out = []
        for (s, e), pairs in sorted(runs.items()):
            lf = sorted({p[0] for p in pairs}, key=_FINGERS.index)
            rf = sorted({p[1] for p in pairs}, key=_FINGERS.index)
            txt = (f"the left {_join(lf)} {'tip touches' if len(lf) == 1 else 'tips touch'} "
                   f"the right {_join(rf)} {'tip' if len(rf) == 1 else 'tips'}")
            if detail >= 4:
                txt += " " + self.tm.span(s, e, self.rng.randrange(2))
            elif detail >= 2:
                txt += " " + self.tm.rough(s, e)
            out.append(txt)
        if detail < 3 and len(out) > 2:
            n = len(runs)
            fingers = sorted({p[0] for v in runs.values() for p in v}, key=_FINGERS.index)
            out = [f"the fingertips of both hands touch {n} times, mainly the left {_join(fingers)}"]
        return out

    def finger_palm_clauses(self, detail: int) -> list[str]:
        out = []
        for key, evs in self.fp.items():
            tip, palm = key.split(", ")
            side, finger = tip.split("_")[:2]
            other = palm.split("_")[0]
            for e in evs:
                if "state" in e:
                    if e["state"] == "far":
                        continue
                    txt = f"the {side} {finger} tip {'rests on' if e['state'] == 'contact' else 'stays near'} the {other} palm"
                else:
                    if e["end_state"] == "far" and e["start_state"] == "near" and detail < 3:
                        continue
                    verb = {"contact": "presses onto", "near": "approaches", "far": "pulls away from"}[e["end_state"]]
                    if e["start_state"] == "contact":
                        verb = "lifts off" if e["end_state"] != "far" else "pulls away from"
                    txt = f"the {side} {finger} tip {verb} the {other} palm"
                    if detail >= 3:
                        txt += " " + self.rng.choice(_SPEED_ADV[e["speed"]])
                if detail >= 4:
                    txt += " " + self.tm.span(e["start"], e["end"], self.rng.randrange(2))
                elif detail >= 2:
                    txt += " " + self.tm.rough(e["start"], e["end"])
                out.append(txt)
        if detail < 2:
            out = out[:2]
        return out

    def palm_distance_clauses(self, detail: int) -> list[str]:
        out = []
        for e in self.pd:
            if "state" in e:
                out.append(f"the palms stay {_PALM_DIST_WORDS[e['state']]}")
                continue
            closer = ["contact", "near", "medium", "far"].index(e["end_state"]) < \
                ["contact", "near", "medium", "far"].index(e["start_state"])
            verb = self.rng.choice(["the hands come together", "the palms approach each other", "the hands close in"]) \
                if closer else self.rng.choice(["the hands separate", "the palms move apart", "the hands draw apart"])
            txt = f"{verb} until they are {_PALM_DIST_WORDS[e['end_state']]}"
            if detail >= 1:
                txt += " " + self.rng.choice(_SPEED_ADV[e["speed"]])
            if detail >= 4:
                txt += " " + self.tm.span(e["start"], e["end"], self.rng.randrange(2))
            elif detail >= 2:
                txt += " " + self.tm.rough(e["start"], e["end"])
            out.append(txt)
        return out

    def relative_clauses(self, detail: int) -> list[str]:
        const, moves = [], []
        for axis, evs in self.rp.items():
            for e in evs:
                if "state" in e:
                    if _REL_PHRASE[e["state"]]:
                        const.append(_REL_PHRASE[e["state"]])
                    continue
                a, b = _REL_PHRASE[e["start_state"]], _REL_PHRASE[e["end_state"]]
                if a is not None and a.startswith("to "):
                    a = "being " + a  # "moves from being to the right of …"
                if a is None:
                    txt = f"the right hand moves from level with the left hand to {b} it"
                elif b is None:
                    txt = f"the right hand moves from {a} the left hand into line with it"
                else:
                    txt = f"the right hand moves from {a} the left hand to end up {b} it"
                if detail >= 3:
                    txt += " " + self.rng.choice(_SPEED_ADV[e["speed"]])
                if detail >= 4:
                    txt += " " + self.tm.span(e["start"], e["end"], self.rng.randrange(2))
                elif detail >= 2:
                    txt += " " + self.tm.rough(e["start"], e["end"])
                moves.append((e["start"], txt))
        out = []
        if const:
            out.append(f"the right hand stays {_join(const)} the left hand")
        out.extend(t for _, t in sorted(moves))
        return out

    def text(self, level: int) -> str:
        cc = self.contact_clauses(level)
        fp = self.finger_palm_clauses(level)
        pd = self.palm_distance_clauses(level)
        rp = self.relative_clauses(level)
        if level == 0:
            clauses = (cc[:1] or fp[:1]) + (pd[:1] if not cc else []) + rp[:1]
            return _cap(_join(clauses[:2]) or "the hands move independently") + "."
        if not cc and not any("touch" in c or "rests on" in c or "presses" in c for c in fp):
            cc = [self.rng.choice(["the hands never touch", "there is no contact between the hands",
                                   "the two hands stay out of contact"])]
        blocks = [cc, fp, pd, rp] if self.rng.random() < 0.6 or level >= 4 else [pd, rp, cc, fp]
        sents = []
        for b in blocks:
            if not b:
                continue
            if level >= 3:
                sents.extend(_cap(c) + "." for c in b)
            else:
                sents.append(_cap(_join(b[: 2 + level])) + ".")
        return " ".join(sents)


class TemplateCaptioner:
    """Deterministic, seeded template captions: same (record, seed) → same five levels.

    Level 0 names the most salient finger or wrist action per hand and the main relation; level 1
    adds speed, wrist direction and contacts; level 2 groups all finger moves in order with rough
    timing, spacing and static fingers; level 3 splits clauses per event with rough timing; level 4
    covers every event with its frame range or seconds and its speed.
    """

    def caption(self, record: dict, *, seed: int) -> list[dict]:
        rng = random.Random(seed)
        tm = _Timing(int(record.get("fps", 30)), int(record["frame_count"]))
        hands = [_Hand(record["left_hand_events"], "left", tm, rng), _Hand(record["right_hand_events"], "right", tm, rng)]
        inter = _Interaction(record["two_hand_relationships"], tm, rng)
        out = []
        for lv in range(LEVELS):
            out.append({"left": hands[0].text(lv), "right": hands[1].text(lv), "interaction": inter.text(lv)})
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
