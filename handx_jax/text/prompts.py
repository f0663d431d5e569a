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

from typing import Sequence

from handx_jax.io import DataError

EMPTY_HELP = "must not be empty (an empty text is refused: no model was trained on one)"


def check_texts(texts: Sequence[str], what: str = "text") -> None:
    """Raise a ``DataError`` naming the first empty or all-whitespace text (``what`` names the argument)."""
    for i, t in enumerate(texts):
        if not isinstance(t, str) or not t.strip():
            where = f"{what} {i + 1} of {len(texts)}" if len(texts) > 1 else what
            raise DataError(f"{where} is empty ({t!r}): describe the motion, e.g. 'the left hand stays still'; "
                            "an empty text is refused everywhere, since no caption a model was trained on is "
                            "empty and guidance's 'no text' is a learned null embedding, not \"\"")
