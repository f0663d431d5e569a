"""The one rule for user-given text (issue 14.8): every prompt or text must say something.

An empty (or all-whitespace) text is refused everywhere a user types one (``handx text encode``,
``handx generate --left/--right/--interaction``), with the same message. Why refuse rather than read ""
as "no text": no caption in any dataset is empty (``dataset.validate_texts`` refuses them), so the
encoding of "" (a lone end-of-sequence token) is a condition no model was trained on; and the "no text"
input of classifier-free guidance is the model's learned null embedding, selected by the guidance
scale, not by an empty string. An empty prompt is therefore almost always a mistake (an unset shell
variable, a missing argument) and generating from it would silently produce meaningless motion. To ask
for little motion, say so ("the left hand stays still").
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

from handx_jax.dataset.format import TEXT_FIELDS
from handx_jax.infra.errors import DataError

EMPTY_HELP = "must not be empty (an empty text is refused: no model was trained on one)"


def check_texts(texts: Sequence[str], what: str = "text") -> None:
    """Raise a ``DataError`` naming the first empty or all-whitespace text (``what`` names the argument)."""
    for i, t in enumerate(texts):
        if not isinstance(t, str) or not t.strip():
            where = f"{what} {i + 1} of {len(texts)}" if len(texts) > 1 else what
            raise DataError(f"{where} is empty ({t!r}): describe the motion, e.g. 'the left hand stays still'; "
                            "an empty text is refused everywhere, since no caption a model was trained on is "
                            "empty and guidance's 'no text' is a learned null embedding, not \"\"")


FIELDS = TEXT_FIELDS  # the dataset's three text fields (data.dataset.TEXT_FIELDS)


def typed_prompts(args) -> list:
    """The prompts given as ``--left``/``--right``/``--interaction`` (none in batch mode)."""
    from handx_jax.generation import Prompt

    return [Prompt(*x) for x in zip(args.left or [], args.right or [], args.interaction or [])]


def check_window(tokenizer, prompts: Sequence, max_len: int, *, joined: Callable[[Any], str] | None = None) -> None:
    """Refuse a typed prompt the run's text encoder would cut (issue 31): a ``DataError`` naming the field
    (``--left``/``--right``/``--interaction``), its length and the window.

    Refused, not truncated with a warning: a cut prompt is another prompt, and the motion would follow
    text the user never sees. Where the family joins the three prompts into one prefix (``joined``: the
    AR family, reference §1.2) the cut falls on whatever comes last, so a long left-hand prompt silently
    removed the right-hand and interaction prompts (a 108k-character prompt gave the same motion whatever
    the other two said); a refusal names the field to shorten. The window is the run's text max_len, the
    length its text cache was built with. Dataset captions (``--data`` batch mode) are not checked:
    the cache cut them at the same window in training (in the tests' 32-clip corpus one clip's most
    detailed captions join to 767 tokens of the tiny fixture tokenizer, against a 128-token window), and
    generation cuts them the same way, so a model is scored on the prefixes it was trained on.
    """
    for i, p in enumerate(prompts):
        which = f" (prompt {i + 1} of {len(prompts)})" if len(prompts) > 1 else ""
        tokens = {f: len(tokenizer.encode_one(getattr(p, f))) for f in FIELDS}  # each with its end token
        if joined is None:
            for f, n in tokens.items():
                if n > max_len:
                    raise DataError(f"--{f}{which} is {n:,} tokens ({len(getattr(p, f)):,} characters), more than the "
                                    f"{max_len} the run's text encoder reads (its text max_len): refused rather than "
                                    f"cut; shorten it")
        else:
            n = len(tokenizer.encode_one(joined(p)))
            if n > max_len:
                f = max(tokens, key=tokens.get)
                raise DataError(f"--{f}{which} is {tokens[f]:,} tokens ({len(getattr(p, f)):,} characters): the three "
                                f"prompts joined are {n:,} tokens, more than the {max_len} the run's text encoder reads "
                                f"(its text max_len); refused rather than cut, since the cut would drop the prompts "
                                f"after it; shorten it")
