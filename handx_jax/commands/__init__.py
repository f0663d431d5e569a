"""``handx`` subcommand groups that span several packages (eval, train, generate, params)."""

from __future__ import annotations

import sys


def fail(cmd: str, err: object, code: int = 2) -> int:
    """Print ``cmd: error: err`` on stderr and return the exit status (every command's error path)."""
    print(f"{cmd}: error: {err}", file=sys.stderr)
    return code
