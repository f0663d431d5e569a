"""Readers of the project's JSON and JSON-lines files: a missing or corrupt file is a ``DataError`` naming
it."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from handx_jax.infra.errors import DataError


def read_json(path: str | os.PathLike, *, missing: str | None = None) -> Any:
    """Read a JSON file; a missing or corrupt file is a ``DataError`` naming it (``missing`` replaces the
    default message for an absent file, e.g. with the command that makes one)."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(missing or f"missing {path.name}", path=path.parent) from None
    except json.JSONDecodeError as e:
        raise DataError(f"corrupt JSON ({e.msg})", path=path) from None


def read_format_meta(path: str | os.PathLike, fmt: str, version: int, *, missing: str | None = None,
                     upgrade: str = "") -> dict:
    """Read the meta JSON of one of the project's on-disk formats and check its ``format`` and
    ``format_version`` fields; ``upgrade`` is appended to the version error (what to rebuild)."""
    meta = read_json(path, missing=missing)
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise DataError(f"not a {fmt} (format={got!r})", path=path)
    if meta.get("format_version") != version:
        raise DataError(f"{fmt} format_version {meta.get('format_version')} is not supported (this code reads "
                        f"{version}){upgrade}", path=path)
    return meta


def read_jsonl(path: str | os.PathLike, *, strict: bool = True) -> list[Any]:
    """Read a JSON-lines file. With ``strict=False`` a torn final line is ignored."""
    path = Path(path)
    rows = []
    lines = path.read_text(encoding="utf-8").splitlines()
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError as e:
            if not strict and i == len(lines) - 1:
                break
            raise DataError(f"line {i + 1} is not valid JSON ({e.msg})", path=path) from None
    return rows
