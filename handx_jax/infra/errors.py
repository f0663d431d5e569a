"""The project's error types for bad input: ``DataError`` names the file and, where known, the clip or field
(``handx_jax.cli`` prints it as one line and exits 2); ``ConfigError`` names the setting or flag (its home is
here, below ``handx_jax.config``, so that ``infra.values`` can raise it)."""

from __future__ import annotations

import os
from typing import Any


class DataError(ValueError):
    """Bad input data. The message names the file and, where known, the clip or field."""

    def __init__(self, message: str, *, path: str | os.PathLike | None = None, clip: Any = None,
                 field: str | None = None):
        where = []
        if path is not None:
            where.append(f"file {os.fspath(path)!s}")
        if clip is not None:
            where.append(f"clip {clip}")
        if field is not None:
            where.append(f"field {field!r}")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)
        self.path, self.clip, self.field = path, clip, field


class ConfigError(ValueError):
    """A bad preset name, override, config file or numeric setting; the message says which key and why."""
