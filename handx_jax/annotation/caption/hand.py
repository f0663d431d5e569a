"""Facts about one hand (module docstring of ``handx_jax.annotation.caption``): whole-finger moves merged from
joint events, fingers doing the same thing grouped, repetitions, whole-hand gestures, held fingers,
thumb pinches and taps, finger spacing and wrist travel.

``_HandFacts`` keeps its leading underscore on purpose: the per-fact wording seeds each fact's stream
with its renderer's ``__qualname__`` (``TemplateCaptioner(wording="per_fact")``), which names this class
and its methods, so renaming either rewords every per-fact corpus (standard corpus v2 among them).
"""

from __future__ import annotations

import random

from handx_jax.annotation.caption.compose import Fact
from handx_jax.annotation.caption.words import (FINGER_VERBS, FINGERS, FLEX_ORDER, FOUR, GESTURE_WORDS, HAND_VERBS,
                                          REPEAT_VERBS, SHAPE_WORDS, SPEED_ADV, SPEED_FACTOR, SPEED_RANK, SWING,
                                          DIR_WORDS, THUMB_SHAPE_WORDS, THUMB_VERBS, Timing, finger_group,
                                          join_words, pick, times, verb_form)

# Flexion order of the finger shapes (a repetition's range runs from the least to the most bent).
_FLEX_ORDER_SHAPE = {"back": -1, "straight": 0, "hooked": 1, "half": 1, "curled": 2}


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


def finger_moves(flexing: dict, finger: str) -> tuple[list[dict], dict, dict]:
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
        init[j] = FLEX_ORDER[e0["state"] if "state" in e0 else e0["start_state"]]
        for e in evs:
            if "state" in e:
                continue
            a, b = FLEX_ORDER[e["start_state"]], FLEX_ORDER[e["end_state"]]
            trans.append((e["start"], e["end"], 1 if b > a else -1, abs(b - a), j, b, SPEED_RANK[e["speed"]]))
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
    four = [sh[f] for f in FOUR]
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

    def __init__(self, ev: dict, tm: Timing, rng: random.Random):
        self.tm, self.rng = tm, rng
        flexing = ev.get("finger_flexing", {})
        self.moves, self.init, self.final = {}, {}, {}
        for f in FINGERS:
            self.moves[f], self.init[f], self.final[f] = finger_moves(flexing, f)
        self.facts: list[Fact] = []
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
        for f in FINGERS:
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
        table = HAND_VERBS if subject == "hand" and key in HAND_VERBS else \
            THUMB_VERBS if subject == "thumb" else FINGER_VERBS
        return verb_form(pick(self.rng, table[key]), plural)

    def _shape_word(self, shape: str, thumb: bool) -> str:
        return pick(self.rng, (THUMB_SHAPE_WORDS if thumb else SHAPE_WORDS)[shape])

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
            four = set(FOUR) <= set(fingers)
            thumb_only = fingers == ["thumb"]
            subject = "hand" if four else "thumb" if thumb_only else "finger"
            who, plural = ("the hand", False) if four and all(
                (m["dir"], m["to"]) in HAND_VERBS for m in ms) else finger_group(fingers)
            if who != "the hand" and subject == "hand":
                subject = "finger"
            if four and who == "the hand" and "thumb" in fingers:
                who = "the whole hand"
            mag = sum(m["mag"] for m in ms) / max(1, len(ms)) * min(len(ms), 3)
            sal = min(mag, 8.0) * (0.6 + 0.4 * len(fingers)) * SPEED_FACTOR[max(m["speed"] for m in ms)]
            if all(m["minor"] for m in ms):
                sal *= 0.3
            hyper = any(m["to"] == "back" or m["from"] == "back" for m in ms)
            if self.main is None or sal > self.main[0]:
                self.main = (sal, ms, subject)
            render = self._group_renderer(ms, who, plural, subject, thumb_only)
            self.facts.append(Fact(sal + (50.0 if hyper else 0.0), ms[0]["start"], ms[-1]["end"], render, hyper))

    def _group_renderer(self, ms, who, plural, subject, thumb):
        tm, rng = self.tm, self.rng
        adv = lambda sp: pick(rng, SPEED_ADV[sp])
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
                verb = verb_form(pick(rng, REPEAT_VERBS[kind][ms[0]["dir"] < 0]), plural)
                txt = f"{who} {verb} {times(n)}"
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
                link = pick(rng, [", then ", " and then "])
                return f"{who} {one(ms[0], d)}{link}{one(ms[1], d, again=back)}"
            txt = f"{who} {one(ms[0], d)}"
            if d == 2:
                txt += " " + tm.rough(s0, s1)
            return txt

        return render

    def _gesture_fact(self) -> None:
        """Whole-hand shapes (fist, pointing, …) formed at the ends of the finger moves."""
        ends = sorted((m["end"], f, m["to"]) for f in FINGERS for m in self.moves[f])
        if not ends:
            return
        sh = {f: self.moves[f][0]["from"] if self.moves[f] else _shape(f, self.final[f]) for f in FINGERS}
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
                txt = f"the hand changes shape {len(formed)} times, forming {join_words([GESTURE_WORDS[g] for g in kinds])}"
            elif len(formed) == 2:
                txt = (f"the hand forms {GESTURE_WORDS[formed[0][1]]}, then "
                       f"{GESTURE_WORDS[formed[1][1]]}")
            else:
                t, g = formed[0]
                if g == "flat":
                    txt = f"the hand {pick(rng, ['opens out flat', 'flattens out', 'opens fully'])}"
                else:
                    txt = f"the hand {pick(rng, ['forms', 'makes', 'ends up in'])} {GESTURE_WORDS[g]}"
                if seq[0][0] == 0 and seq[0][1] != g:
                    txt += f" from {GESTURE_WORDS[seq[0][1]]}"
            if d >= 4:
                txt += " at " + join_words([f"{t / tm.fps:.1f}" for t, _ in formed[:4]]) + " s"
            elif d >= 2:
                txt += " " + tm.rough(formed[0][0] - 5, formed[-1][0])
            return txt

        # A plain fist / flat hand is already said by the group of four fingers.
        plain = names <= {"fist", "flat"} and any(set(FOUR) <= set(g) for g in self.groups)
        sal = 2.0 if plain else 7.0 + len(formed)
        self.facts.append(Fact(sal, formed[0][0] - 5, formed[-1][0], render))

    def _static_facts(self) -> None:
        by_shape: dict[str, list[str]] = {}
        for f in FINGERS:
            if not self.moves[f]:
                by_shape.setdefault(_shape(f, self.final[f]), []).append(f)
        rng = self.rng
        for shape, fingers in by_shape.items():
            who, plural = finger_group(fingers)
            thumb = fingers == ["thumb"]
            if shape == "back":
                joint = "knuckles" if plural else "knuckle"
                self.facts.append(Fact(60.0, None, self.tm.T, lambda d, who=who, plural=plural, joint=joint:
                                        f"{who} {'stay' if plural else 'stays'} hyperextended" +
                                        (f", bent backwards at the {joint}" if d >= 1 else ""), True))
                continue
            sal = 0.6 if shape == "straight" else 1.2
            self.facts.append(Fact(sal, None, self.tm.T, lambda d, who=who, plural=plural, shape=shape, thumb=thumb:
                                    f"{who} {pick(rng, ['stay', 'remain']) if plural else pick(rng, ['stays', 'remains'])} "
                                    f"{self._shape_word(shape, thumb)}"))

    # -- pinches, spacing, wrist -----------------------------------------------------------------
    def _contact_facts(self, contacts: dict) -> None:
        tm, rng = self.tm, self.rng
        items = []  # (runs, fingers)
        for key in sorted(contacts, key=lambda k: FINGERS.index(k.split("_")[0])):
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
            tips = f"{join_words(fingers)} fingertip{'s' if len(fingers) > 1 else ''}"
            s0, s1 = runs[0]["start"], runs[-1]["end"]
            whole = len(runs) == 1 and s1 - s0 >= 0.8 * tm.T

            def render(d: int, runs=runs, tips=tips, whole=whole, s0=s0, s1=s1) -> str:
                if whole:
                    return f"the thumb and {tips} stay pinched together"
                if len(runs) >= 2:
                    txt = f"the thumb taps the {tips} {times(len(runs))}"
                else:
                    txt = pick(rng, [f"the thumb pinches the {tips}", f"the thumb touches the {tips}",
                                      f"the thumb and {tips} pinch together"])
                if d >= 4:
                    sec = rng.random() < 0.5
                    txt += " " + (join_words([tm.exact(r["start"], r["end"], None, sec) for r in runs[:3]]) if len(runs) <= 3
                                  else tm.exact(s0, s1, rng))
                elif d >= 2:
                    txt += " " + tm.rough(s0, s1)
                return txt

            self.facts.append(Fact(10.0 + len(runs) + len(fingers), s0, s1, render, True))

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
                        ep["speed"] = max(ep["speed"], SPEED_RANK[e["speed"]])
                        break
                else:
                    eps.append({"start": e["start"], "end": e["end"], "open": opening, "fingers": {a, b},
                                "speed": SPEED_RANK[e["speed"]]})
        if not eps:
            return
        eps.sort(key=lambda ep: ep["start"])
        tm, rng = self.tm, self.rng

        def who(fs):
            return "the fingers" if len(fs) == 4 else f"the {join_words(sorted(fs, key=FINGERS.index))} fingers"

        if len(eps) >= 3:
            fs = set().union(*(ep["fingers"] for ep in eps))
            opens = sum(ep["open"] for ep in eps)
            first = eps[0]["open"]

            def render(d: int) -> str:
                txt = f"{who(fs)} {'spread and close' if first else 'close and spread'} {times(max(opens, len(eps) - opens))}"
                if d >= 1:
                    txt += " " + pick(rng, SPEED_ADV[max(ep["speed"] for ep in eps)])
                if d >= 4:
                    txt += " " + tm.exact(eps[0]["start"], eps[-1]["end"], rng)
                elif d >= 2:
                    txt += " " + tm.rough(eps[0]["start"], eps[-1]["end"])
                return txt

            self.facts.append(Fact(2.5, eps[0]["start"], eps[-1]["end"], render))
            return
        for ep in eps:
            def render(d: int, ep=ep) -> str:
                verb = pick(rng, ["spread apart", "fan out"]) if ep["open"] else \
                    pick(rng, ["close together", "come together", "squeeze together"])
                txt = f"{who(ep['fingers'])} {verb}"
                if d >= 1:
                    txt += " " + pick(rng, SPEED_ADV[ep["speed"]])
                if d >= 4:
                    txt += " " + tm.exact(ep["start"], ep["end"], rng)
                elif d >= 3:
                    txt += " " + tm.rough(ep["start"], ep["end"])
                return txt

            self.facts.append(Fact(1.0 + 0.4 * len(ep["fingers"]), ep["start"], ep["end"], render))

    def _wrist_facts(self, wrist: dict) -> None:
        evs = []
        for axis, lst in wrist.items():
            for e in lst:
                if "direction" in e:
                    evs.append(dict(e, axis=axis))
        tm, rng = self.tm, self.rng
        if not evs:
            self.facts.append(Fact(0.8, None, tm.T, lambda d: pick(rng, 
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
            sp = max(SPEED_RANK[e["speed"]] for e in lst)

            def render(d: int, lst=lst, cm=cm, sp=sp) -> str:
                txt = f"the hand {pick(rng, ['swings', 'sways', 'moves'])} {SWING[lst[0]['axis']]} {times(len(lst))}"
                if d >= 1:
                    txt += " " + pick(rng, SPEED_ADV[sp])
                if d >= 3:
                    txt += f" by about {cm} cm"
                if d >= 4:
                    txt += " " + tm.exact(lst[0]["start"], lst[-1]["end"], rng)
                elif d >= 2:
                    txt += " " + tm.rough(lst[0]["start"], lst[-1]["end"])
                return txt

            self.facts.append(Fact(3.0 + cm / 4, lst[0]["start"], lst[-1]["end"], render))
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
            sp = max(SPEED_RANK[p["speed"]] for p in parts)
            big = 100 * parts[0]["displacement_m"]

            def render(d: int, s=s, parts=parts, sp=sp) -> str:
                dirs = join_words([DIR_WORDS[p["direction"]] for p in parts])
                txt = f"{pick(rng, ['the hand moves', 'the wrist travels', 'the hand shifts'])} {dirs}"
                if d >= 1:
                    txt += " " + pick(rng, SPEED_ADV[sp])
                if d >= 2:
                    txt += f" by about {round(100 * parts[0]['displacement_m'])} cm"
                if d >= 4:
                    txt += " " + tm.exact(s["start"], s["end"], rng)
                elif d >= 3:
                    txt += " " + tm.rough(s["start"], s["end"])
                return txt

            self.facts.append(Fact(big / 2.5 * SPEED_FACTOR[sp], s["start"], s["end"], render))
