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

One concern per module:

    protocol.py   LEVELS and the ``Captioner`` protocol (what every captioner returns)
    words.py      the word tables and phrase helpers (counts, verb forms, finger groups, timing)
    compose.py    ``Fact`` and the composer (salience into the word budget, temporal order)
    hand.py       one hand's facts (finger moves and groups, gestures, pinches, spacing, wrist)
    inter.py      the two hands' facts (touches, palm distance, relative position, coordination)
    template.py   ``TemplateCaptioner``: both hands' facts and their relation into five levels
    llm.py        the LLM prompt, its reply's parser and ``LLMCaptioner``

This package's names below are its public surface: ``from handx_jax.annotation.caption import X``.
"""

from handx_jax.annotation.caption.compose import BUDGET_WORDS, HARD_CAP_WORDS
from handx_jax.annotation.caption.llm import LLMCaptioner, build_prompt, parse_llm_reply
from handx_jax.annotation.caption.protocol import LEVELS, Captioner
from handx_jax.annotation.caption.template import WORDINGS, TemplateCaptioner

__all__ = ["BUDGET_WORDS", "HARD_CAP_WORDS", "LEVELS", "WORDINGS", "Captioner", "LLMCaptioner", "TemplateCaptioner",
           "build_prompt", "parse_llm_reply"]
