"""Facts about the two hands together: fingertip touches between the hands, fingertips on the other palm,
palm distance (claps, approaches, separations), the right hand's position relative to the left, and the
coordination of the two hands' own moves (in unison, in turn, toward or away from each other).

``_InterFacts`` and ``_coordination`` keep their names on purpose: the per-fact wording seeds each fact's
stream with its renderer's ``__qualname__`` (see ``hand.py``).
"""

from __future__ import annotations

import random

from handx_jax.annotation.caption.compose import Fact
from handx_jax.annotation.caption.hand import _HandFacts
from handx_jax.annotation.caption.words import (DIR_WORDS, FINGERS, PALM_DIST_WORDS, PALM_ORDER, REL_PHRASE, SPEED_ADV,
                                          SPEED_FACTOR, SPEED_RANK, SWING, Timing, join_words, pick, times)


def contact_periods(evs: list[dict], T: int) -> list[tuple[int, int]]:
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
    fs = sorted(fingers, key=FINGERS.index)
    pre = f"{side} " if side else ""
    if len(fs) == 5:
        return f"all {pre}fingertips"
    return f"the {pre}{join_words(fs)} tip{'s' if len(fs) > 1 else ''}"


class _InterFacts:
    def __init__(self, rel: dict, tm: Timing, rng: random.Random):
        self.tm, self.rng = tm, rng
        self.facts: list[Fact] = []
        self.touch = False
        self._tip_facts(rel.get("finger_tip_contact", {}))
        self._finger_palm_facts(rel.get("finger_palm_distance", {}))
        self._palm_distance_facts(rel.get("palm_palm_distance", {}).get("left_palm, right_palm", []))
        self._relative_facts(rel.get("palm_palm_relative_position", {}))
        if not self.touch:
            self.facts.append(Fact(4.0, None, tm.T, lambda d: pick(rng, 
                ["the hands never touch", "there is no contact between the hands",
                 "the two hands stay out of contact"])))

    def _timed(self, txt: str, d: int, s: int, e: int, sp: int | None = None, rough_from: int = 2) -> str:
        if sp is not None and d >= 1:
            txt += " " + pick(self.rng, SPEED_ADV[sp])
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
            by_set.setdefault((tuple(sorted(ep["a"], key=FINGERS.index)), tuple(sorted(ep["b"], key=FINGERS.index))),
                              []).append(ep)
        tm, rng = self.tm, self.rng

        def phrase(lf, rf, n):
            if lf == rf:
                who = "the two thumbs" if lf == ("thumb",) else \
                    f"the two {lf[0]} fingertips" if len(lf) == 1 else f"the {join_words(list(lf))} fingertips of both hands"
                if len(lf) == 5:
                    who = "all fingertips of both hands"
                verb = "touch" if n == 1 else f"touch {times(n)}"
                return f"{who} {pick(rng, [verb, verb.replace('touch', 'meet')])}"
            lw = _tips(lf, "left")
            verb = "touches" if len(lf) == 1 else "touch"
            return f"{lw} {verb} {_tips(rf, 'right')}" + (f" {times(n)}" if n > 1 else "")

        if len(by_set) > 3:  # many different touches: one summary with the fingers most involved
            lf = sorted({f for ep in eps for f in ep["a"]}, key=FINGERS.index)
            rf = sorted({f for ep in eps for f in ep["b"]}, key=FINGERS.index)

            def render(d: int) -> str:
                txt = f"the fingertips of both hands touch {len(eps)} times"
                if d >= 1:
                    txt += f", the left {join_words(lf)} against the right {join_words(rf)}"
                return self._timed(txt, d, eps[0]["start"], eps[-1]["end"])

            self.facts.append(Fact(12.0, eps[0]["start"], eps[-1]["end"], render, True))
            return
        for (lf, rf), group in by_set.items():
            s0, s1 = group[0]["start"], group[-1]["end"]

            def render(d: int, lf=lf, rf=rf, group=group, s0=s0, s1=s1) -> str:
                txt = phrase(lf, rf, len(group))
                if d >= 4 and len(group) <= 3:
                    sec = rng.random() < 0.5
                    return txt + " " + join_words([tm.exact(g["start"], g["end"], None, sec) for g in group])
                if len(group) == 1 and group[0]["end"] - group[0]["start"] >= 0.8 * tm.T:
                    return txt + " throughout"
                return self._timed(txt, d, s0, s1)

            self.facts.append(Fact(11.0 + len(group) + 0.5 * len(lf), s0, s1, render, True))

    def _finger_palm_facts(self, fp: dict) -> None:
        tm, rng = self.tm, self.rng
        contact: dict[str, list] = {"left": [], "right": []}
        near: dict[str, list] = {"left": [], "right": []}
        for key, evs in fp.items():
            tip, palm = key.split(", ")
            side, finger = tip.split("_")[:2]
            for s, e in contact_periods(evs, tm.T):
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
                fingers = sorted({f for ep in eps for f in ep["a"]}, key=FINGERS.index)

                def render(d: int, eps=eps, fingers=fingers, side=side, other=other) -> str:
                    n = len(eps)
                    verb = ("press on", "rest on", "touch") if len(fingers) > 1 else ("presses on", "rests on", "touches")
                    txt = f"{_tips(fingers, side)} {pick(rng, verb)} the {other} palm"
                    if n > 1:
                        txt += f" {times(n)}"
                    elif eps[0]["end"] - eps[0]["start"] >= 0.8 * tm.T:
                        return txt + " throughout"
                    if d >= 4 and n <= 3:
                        sec = rng.random() < 0.5
                        return txt + " " + join_words([tm.exact(ep["start"], ep["end"], None, sec) for ep in eps])
                    return self._timed(txt, d, eps[0]["start"], eps[-1]["end"])

                self.facts.append(Fact(10.0 + len(eps), eps[0]["start"], eps[-1]["end"], render, True))
            elif near[side]:
                eps = _episodes(near[side], gap=3)
                fingers = sorted({f for ep in eps for f in ep["a"]}, key=FINGERS.index)

                def render(d: int, eps=eps, fingers=fingers, side=side, other=other) -> str:
                    txt = f"{_tips(fingers, side)} {pick(rng, ['come close to', 'hover near'])} the {other} palm"
                    return self._timed(txt, d, eps[0]["start"], eps[-1]["end"], rough_from=3)

                self.facts.append(Fact(2.0, eps[0]["start"], eps[-1]["end"], render))

    def _palm_distance_facts(self, pd: list[dict]) -> None:
        tm, rng = self.tm, self.rng
        if not pd:
            return
        if "state" in pd[0]:
            st = pd[0]["state"]
            if st == "contact":
                self.touch = True
            self.facts.append(Fact(7.0 if st == "contact" else 1.5, None, tm.T, lambda d: (
                "the palms stay pressed together" if st == "contact" else
                f"the {pick(rng, ['hands', 'palms'])} stay {PALM_DIST_WORDS[st]}"), st == "contact"))
            return
        closings = [e for e in pd if PALM_ORDER[e["end_state"]] < PALM_ORDER[e["start_state"]]]
        meets = [e for e in closings if e["end_state"] == "contact"]
        if meets:
            self.touch = True
        s0, s1 = pd[0]["start"], pd[-1]["end"]
        sp = max(SPEED_RANK[e["speed"]] for e in pd)
        if len(meets) >= 2 or len(pd) >= 3:
            n = max(len(meets), len(closings))

            def render(d: int) -> str:
                if len(meets) >= 2:
                    txt = f"the palms {pick(rng, ['clap together', 'meet', 'come together'])} {times(len(meets))}"
                else:
                    txt = f"the hands move together and apart {times(n)}"
                if d >= 3:
                    closest = min(pd, key=lambda e: PALM_ORDER[e["end_state"]])["end_state"]
                    if not meets:
                        txt += f", getting {PALM_DIST_WORDS[closest]}"
                return self._timed(txt, d, s0, s1, sp)

            self.facts.append(Fact(9.0 if meets else 4.0 + n * 0.5, s0, s1, render, bool(meets)))
            return
        for e in pd:
            closer = PALM_ORDER[e["end_state"]] < PALM_ORDER[e["start_state"]]

            def render(d: int, e=e, closer=closer) -> str:
                if e["end_state"] == "contact":
                    verb = pick(rng, ["the palms come together until they touch", "the palms meet"])
                elif e["start_state"] == "contact":
                    verb = pick(rng, ["the palms separate", "the palms pull apart"])
                elif closer:
                    verb = pick(rng, ["the hands come together", "the palms approach each other", "the hands close in"])
                else:
                    verb = pick(rng, ["the hands separate", "the palms move apart", "the hands draw apart"])
                txt = verb
                if d >= 2 and e["end_state"] != "contact":
                    txt += f" until {PALM_DIST_WORDS[e['end_state']]}"
                return self._timed(txt, d, e["start"], e["end"], SPEED_RANK[e["speed"]])

            contact = "contact" in (e["end_state"], e["start_state"])
            sal = (8.0 if contact else 3.0 + abs(PALM_ORDER[e["end_state"]] - PALM_ORDER[e["start_state"]]) * 0.5) \
                * SPEED_FACTOR[SPEED_RANK[e["speed"]]]
            self.facts.append(Fact(sal, e["start"], e["end"], render, contact))

    def _relative_facts(self, rp: dict) -> None:
        tm, rng = self.tm, self.rng
        const, segs = [], []
        for axis, evs in rp.items():
            if evs and "state" in evs[0]:
                if REL_PHRASE[evs[0]["state"]]:
                    const.append(REL_PHRASE[evs[0]["state"]])
                continue
            moves = [e for e in evs if "state" not in e]
            if len(moves) >= 3:
                def render(d: int, moves=moves, axis=axis) -> str:
                    txt = f"the right hand moves {SWING[axis]} relative to the left {times(len(moves))}"
                    return self._timed(txt, d, moves[0]["start"], moves[-1]["end"],
                                       max(SPEED_RANK[e["speed"]] for e in moves), rough_from=3)

                self.facts.append(Fact(4.0, moves[0]["start"], moves[-1]["end"], render))
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
            sp = max(SPEED_RANK[e["speed"]] for e in seg["parts"])

            def render(d: int, seg=seg, sp=sp) -> str:
                to = [REL_PHRASE[e["end_state"]] for e in seg["parts"]]
                frm = [REL_PHRASE[e["start_state"]] for e in seg["parts"]]
                if all(b is None for b in to):
                    txt = pick(rng, ["the right hand comes level with the left", "the right hand lines up with the left"])
                else:
                    txt = f"the right hand {pick(rng, ['moves', 'shifts'])} {join_words([b for b in to if b])} the left"
                    if d >= 3 and any(frm):
                        a = join_words([x for x in frm if x])
                        txt += f" from {'being ' if a.startswith('to ') else ''}{a} it"
                return self._timed(txt, d, seg["start"], seg["end"], sp, rough_from=2)

            self.facts.append(Fact((3.0 + 0.5 * len(seg["parts"])) * SPEED_FACTOR[sp], seg["start"], seg["end"], render))
        if const:
            self.facts.append(Fact(1.5, None, tm.T, lambda d: (
                f"the right hand {pick(rng, ['stays', 'remains', 'is held'])} {join_words(const)} the left")))


_TOWARD = {("left-to-right", "right-to-left"): "move toward each other",
           ("right-to-left", "left-to-right"): "move apart sideways"}


def _coordination(hl: "_HandFacts", hr: "_HandFacts", tm: Timing, rng: random.Random) -> list[Fact]:
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
                    txt = pick(rng, ["both hands move their fingers in unison", "the two hands mirror each other's finger movements",
                                      "the fingers of both hands move in sync"])
                    return txt + (" " + tm.rough(s0, s1) if 2 <= d < 4 else " " + tm.exact(s0, s1, rng) if d >= 4 else "")
            else:
                lead, follow = ("left", "right") if lag > 0 else ("right", "left")

                def render(d: int, lead=lead, follow=follow, lag=abs(lag)) -> str:
                    txt = f"the {follow} hand's fingers repeat the {lead} hand's movement"
                    if d >= 2:
                        txt += f" about {lag / tm.fps:.1f} s later"
                    return txt
            facts.append(Fact(3.5, s0, s1, render))
    for sl in hl.segs:
        for sr in hr.segs:
            ov = min(sl[1], sr[1]) - max(sl[0], sr[0])
            if ov < 0.5 * min(sl[1] - sl[0], sr[1] - sr[0]):
                continue
            s0, s1 = min(sl[0], sr[0]), max(sl[1], sr[1])
            if sl[2] == sr[2]:
                txt = f"both hands move {DIR_WORDS[sl[2]]} together"
            elif (sl[2], sr[2]) in _TOWARD:
                txt = f"the hands {_TOWARD[(sl[2], sr[2])]}"
            else:
                continue
            facts.append(Fact(3.0, s0, s1, lambda d, txt=txt, s0=s0, s1=s1: txt + (
                " " + tm.exact(s0, s1, rng) if d >= 4 else " " + tm.rough(s0, s1) if d >= 2 else "")))
            break
    return facts
