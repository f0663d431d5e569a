"""What a storage library prints while it writes, held back: released if the write succeeds, dropped if it
fails (the failure itself becomes one line)."""

from __future__ import annotations

import contextlib
import io
import logging
import sys
from typing import Iterator


@contextlib.contextmanager
def library_output_held() -> Iterator[None]:
    """Hold what a storage library prints while it writes (orbax's absl ``ERROR`` records with their
    tracebacks, tensorstore's "Event loop is closed" tracebacks from its write threads): released to stderr
    if the block succeeds, dropped if it fails, when the error itself becomes one line (``handx_jax.cli``).
    A full disk under ``orbax`` printed ~110 lines of them before that line (issue 43)."""
    held = io.StringIO()
    loggers = [logging.getLogger(n) for n in ("absl", "asyncio")]
    levels = [lg.level for lg in loggers]
    old = sys.stderr
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    sys.stderr = held
    ok = False
    try:
        yield
        ok = True
    finally:
        # After a failure the library's tasks keep reporting as they are collected (asyncio's "Task exception
        # was never retrieved", at exit): its loggers stay quiet and stderr passes only the project's lines.
        sys.stderr = old if ok else _Quiet(old)
        if ok:
            for lg, lv in zip(loggers, levels):
                lg.setLevel(lv)
            if held.getvalue():
                old.write(held.getvalue())


class _Quiet:
    """stderr after a failed library write: the library's threads may still print tracebacks of callbacks on
    their closed event loop while the error unwinds; only the project's own lines (``handx…``) pass."""

    def __init__(self, stream):
        self._stream, self._line = stream, ""

    def write(self, text: str) -> int:
        self._line += text
        *lines, self._line = self._line.split("\n")
        for ln in lines:
            if ln.startswith("handx"):
                self._stream.write(ln + "\n")
        return len(text)

    def flush(self) -> None:
        self._stream.flush()

    def __getattr__(self, name):
        return getattr(self._stream, name)
