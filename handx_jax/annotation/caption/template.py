"""The template captioner: the facts of both hands and of their relation, composed into five levels of
three texts from one seed."""

from __future__ import annotations

import random

from handx_jax.annotation.caption import gist
from handx_jax.annotation.caption.compose import compose
from handx_jax.annotation.caption.hand import _HandFacts
from handx_jax.annotation.caption.inter import _coordination, _InterFacts
from handx_jax.annotation.caption.protocol import LEVELS
from handx_jax.annotation.caption.words import Timing


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

    A record read with the "gist" annotation (it carries ``finger_curl``) gets the gist as level 0
    (``caption.gist``): one decision per finger, in fixed words. Levels 1–4 are composed as always.
    """

    def __init__(self, wording: str = "shared"):
        if wording not in WORDINGS:
            raise ValueError(f"unknown wording {wording!r}; choose one of {', '.join(WORDINGS)}")
        self.wording = wording

    def caption(self, record: dict, *, seed: int) -> list[dict]:
        rng = random.Random(seed)
        tm = Timing(int(record.get("fps", 30)), int(record["frame_count"]))
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
                texts[name] = compose(facts, lv, rng, fallback, order)
            out.append(texts)
        if gist.has_gist(record):  # the gist reading (corpus v3): level 0 says the fingers' gist
            out[0] = gist.level0(record)
        return out
