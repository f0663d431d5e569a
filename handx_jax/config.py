"""One config system for every entry point: frozen nested dataclasses, named presets, dotted overrides.

A config is a frozen dataclass whose fields are scalars (``bool``, ``int``, ``float``, ``str``),
``Optional`` scalars, tuples/lists of scalars (``tuple[int, ...]``, e.g. FSQ levels) or nested config
dataclasses. Everything that can be set from the command line is set the same way:

    apply_overrides(cfg, ["train.optim.lr=3e-4", "model.levels=8,5,5,5", "data.encoder=none"])

Each value is parsed for the field's declared type (``1e3`` is a valid int, ``2.5`` is not; ``none``
sets an Optional field to None; a tuple takes comma-separated items, optionally in brackets), unknown
keys are an error with a "did you mean" hint, and :func:`validate` runs after all overrides (each nested
group's ``check_values``, e.g. the training loop's ``train.*`` ranges, then the top-level class's
``validate()``), so ``model.dim`` and ``model.heads`` can change together.

``to_dict`` gives the JSON form written to a run's ``config.json``; ``from_dict`` rebuilds the
dataclass from it (ignoring keys the class does not have, e.g. ``params``; tuples come back as
tuples). ``add_config_args`` gives every command the same ``--preset``, ``--set`` and
``--print-config`` flags.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import json
import types
import typing
from typing import Any, Mapping, Sequence

from handx_jax.infra.errors import ConfigError  # noqa: F401  (its home: infra.values raises it too)


_SCALARS = (bool, int, float, str)


def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def _optional_inner(kind):
    """``X`` for ``Optional[X]`` / ``X | None``; None otherwise."""
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(kind) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(kind)) == 2:
            return args[0]
    return None


def _parse_scalar(text: str, kind: Any, key: str):
    if kind is bool:
        low = text.strip().lower()
        if low in ("1", "true", "yes", "on"):
            return True
        if low in ("0", "false", "no", "off"):
            return False
        raise ConfigError(f"--set {key}: expected a boolean (true/false), got {text!r}")
    if kind is int:
        try:
            f = float(text.replace("_", ""))
        except ValueError:
            raise ConfigError(f"--set {key}: expected an integer, got {text!r}") from None
        if f != int(f):
            raise ConfigError(f"--set {key}: expected an integer, got {text!r}")
        return int(f)
    if kind is float:
        try:
            return float(text.replace("_", ""))
        except ValueError:
            raise ConfigError(f"--set {key}: expected a number, got {text!r}") from None
    if kind is str:
        return text
    raise ConfigError(f"--set {key}: values of type {kind} cannot be set from the command line")


def parse_value(text: str, kind: Any, key: str):
    """Parse command-line ``text`` as a value of the declared type ``kind`` (see the module doc)."""
    inner = _optional_inner(kind)
    if inner is not None:
        return None if text.strip().lower() in ("none", "null") else parse_value(text, inner, key)
    origin = typing.get_origin(kind)
    if origin in (tuple, list):
        args = typing.get_args(kind)
        body = text.strip()
        if body[:1] in "([" and body[-1:] in ")]":
            body = body[1:-1]
        items = [s.strip() for s in body.split(",")] if body.strip() else []
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            if len(items) != len(args):
                raise ConfigError(f"--set {key}: expected {len(args)} comma-separated values, got {text!r}")
            return tuple(_parse_scalar(s, a, key) for s, a in zip(items, args))
        item_kind = args[0] if args else str
        vals = [_parse_scalar(s, item_kind, key) for s in items]
        return tuple(vals) if origin is tuple else vals
    return _parse_scalar(text, kind, key)


def _field_names(obj) -> list[str]:
    return [f.name for f in dataclasses.fields(obj)]


def _set_path(obj, path: list[str], text: str, key: str, done: list[str]):
    names = _field_names(obj)
    name = path[0]
    if name not in names:
        close = difflib.get_close_matches(name, names, n=1)
        hint = f" (did you mean {'.'.join(done + [close[0]])!r}?)" if close else ""
        raise ConfigError(f"--set {key}: unknown key {'.'.join(done + [name])!r}{hint}; "
                          f"valid keys here: {', '.join(names)}")
    cur = getattr(obj, name)
    if dataclasses.is_dataclass(cur):
        if len(path) == 1:
            sub = ", ".join(f"{'.'.join(done + [name])}.{n}" for n in _field_names(cur))
            raise ConfigError(f"--set {key}: {'.'.join(done + [name])!r} is a group; set one of its keys: {sub}")
        return dataclasses.replace(obj, **{name: _set_path(cur, path[1:], text, key, done + [name])})
    if len(path) > 1:
        raise ConfigError(f"--set {key}: {'.'.join(done + [name])!r} is a value, not a group")
    return dataclasses.replace(obj, **{name: parse_value(text, _hints(type(obj))[name], key)})


def apply_overrides(cfg, overrides: Sequence[str], *, groups: bool = True):
    """Apply ``key.sub=value`` strings to a (nested) frozen dataclass, type-checked, then :func:`validate`.
    ``groups=False`` leaves out the nested groups' ``check_values`` (the config's own ``validate()`` still
    runs): a trained run's config read back to generate from, whose ``train.*`` values are its history (an
    imported official model records ``train.steps`` 0), not a run to start."""
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected key=value (e.g. train.optim.lr=3e-4)")
        key, text = item.split("=", 1)
        key = key.strip()
        cfg = _set_path(cfg, key.split("."), text.strip(), key, [])
    if groups:
        validate(cfg)
    else:
        check = getattr(cfg, "validate", None)
        if callable(check):
            check()
    return cfg


def validate(cfg, key: str = "") -> None:
    """Check a config before anything runs on it: every nested config's ``check_values(key)`` (a group of
    values checked wherever it is used, named by its dotted key: ``TrainConfig`` as ``train.ckpt_every``,
    ``OptimConfig`` as ``train.optim.lr``), then the config's own ``validate()`` if it has one (the checks
    across groups). ``key``: the dotted key ``cfg`` itself has (``"train"`` for a bare ``TrainConfig``).
    Raises ConfigError naming the key."""
    _check_groups(cfg, key)
    check = getattr(cfg, "validate", None)
    if callable(check):
        check()


def _check_groups(obj, where: str) -> None:
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        return
    own = getattr(obj, "check_values", None)
    if callable(own):
        own(where)
    for f in dataclasses.fields(obj):
        _check_groups(getattr(obj, f.name), f"{where}.{f.name}" if where else f.name)


def to_dict(cfg) -> dict:
    """The JSON form of a config: nested dicts, tuples as lists."""
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def _convert(kind, value, where: str):
    inner = _optional_inner(kind)
    if inner is not None:
        return None if value is None else _convert(inner, value, where)
    if dataclasses.is_dataclass(kind):
        if not isinstance(value, Mapping):
            raise ConfigError(f"config field {where!r}: expected an object, got {value!r}")
        return from_dict(kind, value, where=where)
    origin = typing.get_origin(kind)
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config field {where!r}: expected a list, got {value!r}")
        args = typing.get_args(kind)
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            return tuple(_convert(a, v, where) for a, v in zip(args, value))
        vals = [_convert(args[0], v, where) if args else v for v in value]
        return tuple(vals) if origin is tuple else vals
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if kind in _SCALARS and not isinstance(value, kind):
        raise ConfigError(f"config field {where!r}: expected {kind.__name__}, got {value!r}")
    return value


def from_dict(cls, doc: Mapping, *, where: str = ""):
    """Rebuild a config dataclass from its ``to_dict`` form; keys the class lacks are ignored, keys
    the document lacks take the class defaults."""
    hints = _hints(cls)
    kw = {}
    for f in dataclasses.fields(cls):
        if f.name in doc:
            kw[f.name] = _convert(hints[f.name], doc[f.name], f"{where}.{f.name}" if where else f.name)
    return cls(**kw)


def diff_keys(a: Mapping, b: Mapping, keys: Sequence[str] | None = None) -> list[str]:
    """Top-level keys (all, or ``keys``) whose JSON values differ between two config documents."""
    norm = lambda v: json.loads(json.dumps(v))  # noqa: E731  (tuples vs lists, int vs float keys)
    keys = sorted(set(a) | set(b)) if keys is None else keys
    return [k for k in keys if norm(a.get(k)) != norm(b.get(k))]


def get_preset(presets: Mapping[str, Any], name: str, what: str = "preset"):
    """``presets[name]``, or a ConfigError listing the names (with a "did you mean" hint)."""
    if name in presets:
        return presets[name]
    close = difflib.get_close_matches(name, list(presets), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise ConfigError(f"unknown {what} {name!r}{hint}; choose from {', '.join(presets)}")


def add_config_args(parser: argparse.ArgumentParser, presets: Mapping[str, Any] | Sequence[str] | None,
                    default: str | None = None, *, example: str = "train.steps=2000") -> None:
    """``--preset NAME``, ``--set KEY=VALUE`` (repeatable) and ``--print-config``, for any command."""
    if presets is not None:
        names = list(presets)
        parser.add_argument("--preset", default=default, metavar="NAME",
                            help=f"named size ({', '.join(names)}; default {default})")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help=f"override a config value with a dotted key, e.g. {example} (repeatable)")
    parser.add_argument("--print-config", action="store_true", help="print the resolved config as JSON and exit")


def print_config(cfg) -> None:
    print(json.dumps(to_dict(cfg), indent=2))
