"""What every captioner returns: ``LEVELS`` texts per clip, index 0 the most concise and 4 the most
detailed, each a dict ``{"left": str, "right": str, "interaction": str}``."""

from __future__ import annotations

from typing import Protocol

LEVELS = 5


class Captioner(Protocol):
    def caption(self, record: dict, *, seed: int) -> list[dict]:
        """Five levels (0 = one-line summary … 4 = comprehensive), each {left, right, interaction}."""
