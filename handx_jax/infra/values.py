"""The one check of a numeric setting: a command-line flag (``--clips``, ``--seed``, ``--block``) or a ``--set``
value (issue 54). Whole or finite, within a range, refused before any work and before any folder exists.

:func:`problem` says what is wrong with a value ("must be a whole number >= 1, got 0"), or None; everything
else words it for its caller:

- :func:`whole_flag` / :func:`number_flag`: argparse ``type=`` callables, so a bad flag is refused while the
  command line is parsed (argparse's ``error: argument --clips: must be ...``, exit 2), before any handler runs;
- :func:`check`: a ``ValueError`` subclass (``ConfigError`` (``infra.errors``)) naming a config key, for ``--set``
  values and configs built in Python;
- :func:`check_split_fractions`: the validation and test fractions of a corpus leave every split a share.
"""

from __future__ import annotations

import argparse
import math
from typing import Any, Callable


def _bounds(minimum=None, maximum=None, above=None, below=None) -> str:
    parts = [f">= {minimum:g}" if minimum is not None else None, f"> {above:g}" if above is not None else None,
             f"<= {maximum:g}" if maximum is not None else None, f"< {below:g}" if below is not None else None]
    return " and ".join(p for p in parts if p)


def problem(value: Any, *, whole: bool = False, minimum: float | None = None, maximum: float | None = None,
            above: float | None = None, below: float | None = None) -> str | None:
    """What is wrong with ``value`` as a whole (``whole``) or finite number within the bounds (``minimum``/
    ``maximum`` inclusive, ``above``/``below`` exclusive), or None. NaN and inf are never numbers here; a bool
    is not a count."""
    kind = "a whole number" if whole else "a finite number"
    rng = _bounds(minimum, maximum, above, below)
    want = f"must be {kind}{' ' + rng if rng else ''}, got {value!r}"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return want
    if whole and not isinstance(value, int):
        return want
    if not math.isfinite(value):
        return want
    if (minimum is not None and value < minimum) or (maximum is not None and value > maximum) or \
            (above is not None and value <= above) or (below is not None and value >= below):
        return want
    return None


def check(value: Any, key: str, *, why: str = "", **bounds) -> Any:
    """``value`` if :func:`problem` finds nothing, else a ``ConfigError`` (``infra.errors``) "KEY must be ..." (and
    ``why``, the reason for the bound, in brackets); ``bounds``: :func:`problem`'s keywords."""
    from handx_jax.infra.errors import ConfigError

    wrong = problem(value, **bounds)
    if wrong is not None:
        raise ConfigError(f"{key} {wrong}{f' ({why})' if why else ''}")
    return value


def _flag(parse: Callable[[str], Any], whole: bool, bounds: dict, help_text: str, why: str
          ) -> Callable[[str], Any]:
    def convert(text: str):
        try:
            value = parse(text)
        except ValueError:
            value = text
        wrong = problem(value, whole=whole, **bounds)
        if wrong is not None:
            wrong = wrong.replace(f"got {value!r}", f"got {text!r}")
            raise argparse.ArgumentTypeError(f"{wrong}{f' ({why})' if why else ''}")
        return value

    convert.__name__ = help_text  # argparse names the type in "invalid <name> value" (never reached: see above)
    return convert


def _int(text: str) -> int:
    f = float(text.replace("_", ""))  # "1e3" is a count of 1000, as in --set (config.parse_value)
    if not f.is_integer():
        raise ValueError(text)
    return int(f)


def whole_flag(minimum: int | None = 0, maximum: int | None = None, *, why: str = "") -> Callable[[str], int]:
    """argparse ``type=`` for a whole-number flag in [``minimum``, ``maximum``] (``--seed``: 0; ``--clips``: 1);
    ``why``: the reason for the bound, said with the refusal."""
    return _flag(_int, True, {"minimum": minimum, "maximum": maximum}, "whole number", why)


def number_flag(*, minimum: float | None = None, maximum: float | None = None, above: float | None = None,
                below: float | None = None, why: str = "") -> Callable[[str], float]:
    """argparse ``type=`` for a finite-number flag within the bounds (``--val-fraction``: above 0, below 1)."""
    return _flag(float, False, {"minimum": minimum, "maximum": maximum, "above": above, "below": below}, "number",
                 why)


def check_split_fractions(val: float, test: float, *, names: tuple[str, str] = ("val_fraction", "test_fraction")
                          ) -> None:
    """The validation and test shares of a corpus's sequences (``data.build.sequence_split``): each in (0, 1)
    and together below 1, so that train, val and test each get a share (0.6 and 0.6 left train nothing; NaN
    left val nothing, silently). A ``ConfigError`` (``infra.errors``) naming the setting."""
    from handx_jax.infra.errors import ConfigError

    for v, name in ((val, names[0]), (test, names[1])):
        check(v, name, above=0.0, below=1.0)
    if val + test >= 1:
        raise ConfigError(f"{names[0]} {val:g} + {names[1]} {test:g} = {val + test:g} leaves the train split no "
                          "clips: together they must be < 1")
