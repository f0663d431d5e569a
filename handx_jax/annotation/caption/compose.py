"""The fact composer: a fact is one thing worth saying, with a salience, a time span and a renderer for
detail 0 … 4; a level's text takes facts by salience into its word budget and tells them in temporal
order, at most two clauses per sentence (module docstring of ``handx_jax.annotation.caption``)."""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Callable

from handx_jax.annotation.caption.words import capitalise, join_words, pick, word_count
# Word budget of one text field per level (the mean over a corpus lands a little below, since
# simple motions say less) and the cap no field may exceed (≈ 1.35 T5 tokens per word → 120).
BUDGET_WORDS = (10, 27, 44, 61, 80)
HARD_CAP_WORDS = 90


@dataclass
class Fact:
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


def compose(facts: list[Fact], level: int, rng: random.Random, fallback: str,
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
        if (left < 4 or word_count(f.text(0 if level < 3 else 2)) + 1 > left) and not (forcing or not chosen):
            continue
        txt = None
        # Levels 3–4 only take a fact with its timing (detail ≥ 2); lower levels may shorten it.
        for d in (level, level - 1) if level >= 3 else (level, level - 1, 0) if level == 2 else (level, 0):
            t = f.text(d)
            if word_count(t) + 1 <= left:
                txt = t
                break
        if txt is None and (forcing or not chosen):
            txt = f.text(0 if level < 3 else 2)
        if txt is None:
            continue
        chosen[i] = txt
        used += word_count(txt) + 1
        forced += f.must
    # The hard cap: drop the least salient optional facts if mandatory ones overflowed.
    while used > HARD_CAP_WORDS and len(chosen) > 1:
        i = min((k for k in chosen if not facts[k].must), key=lambda k: facts[k].sal, default=None)
        if i is None:
            i = min(chosen, key=lambda k: facts[k].sal)
        used -= word_count(chosen.pop(i)) + 1
    if not chosen:
        return capitalise(fallback) + "."
    sel = sorted(chosen, key=lambda k: (facts[k].t0 is None, facts[k].t0 or 0, -facts[k].sal))
    if level == 0:
        return capitalise(join_words([chosen[k] for k in sel])) + "."
    sents, k = [], 0
    while k < len(sel):
        a = sel[k]
        if k + 1 < len(sel) and rng.random() < 0.6:
            b = sel[k + 1]
            fa, fb = facts[a], facts[b]
            if fb.t0 is None:
                conn = " and " if fa.t0 is None else pick(rng, [", while ", "; meanwhile "])
            elif fb.t0 >= fa.t1 - 2:
                conn = pick(rng, [", then ", ", and then ", ", after which "])
            else:
                conn = pick(rng, [" while ", " as "])
            sents.append(capitalise(chosen[a] + conn + chosen[b]) + ".")
            k += 2
        else:
            sents.append(capitalise(chosen[a]) + ".")
            k += 1
    return " ".join(sents)
