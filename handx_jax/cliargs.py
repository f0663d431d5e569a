"""The command line's vocabulary: one name per concept, and the old spellings kept for one release.

Every ``handx`` command spells a concept one way (issue 42):

    --data        the dataset directory (never --reference, never a positional argument)
    --out         the folder or file a command writes, and the sweep folder it reads
    --block       the R-Precision block size
    --level       a caption level;       --confidence   a confidence level (``handx analyze``)
    --steps       training steps;        --sample-steps a sampler's steps (= --set sample.steps)
    --encoder     the T5 encoder folder

An old spelling stays for one release as a :class:`Deprecated` action: hidden from ``--help``, it
stores into the new flag's destination and prints one line on stderr naming the new spelling.
``tests/test_cli_names.py`` walks every parser and holds the table above.
"""

from __future__ import annotations

import argparse
import sys


def notice(old: str, new: str, prog: str = "handx") -> None:
    """The one line an old spelling prints (stderr, so ``--json`` output stays clean)."""
    print(f"{prog}: note: {old} is deprecated (kept for this release only); use {new}", file=sys.stderr)


class Deprecated(argparse.Action):
    """An old spelling of a renamed flag (or a positional argument that became a flag): stores into
    the new flag's destination and prints :func:`notice`. Hidden from ``--help``."""

    def __init__(self, option_strings, dest, new: str = "", **kw):
        kw["help"] = argparse.SUPPRESS
        if not option_strings:  # a positional: optional, so the flag can be given instead
            kw["nargs"] = "?"
            kw["default"] = None
        super().__init__(option_strings, dest, **kw)
        self.new = new

    def __call__(self, parser, namespace, values, option_string=None):
        if values is None and not self.option_strings:  # the positional was not given
            return
        old = option_string or f"the positional {(self.metavar or self.dest).upper()}"
        notice(old, self.new, parser.prog)
        setattr(namespace, self.dest, values)


def _required_either_way(new_action: argparse.Action) -> None:
    # argparse counts a required flag as given only under its own spelling; Parser checks the dest instead
    if new_action.required:
        new_action.required = False
        new_action.required_either_way = True


def deprecated_flag(p, old: str, new_action: argparse.Action) -> argparse.Action:
    """Accept ``old`` for one release as another spelling of ``new_action`` (same type and dest); a
    required ``new_action`` is then required in the sense that one of the two is given (:class:`Parser`)."""
    _required_either_way(new_action)
    return p.add_argument(old, action=Deprecated, new=new_action.option_strings[0], dest=new_action.dest,
                          type=new_action.type)


def deprecated_positional(p, new_action: argparse.Action, metavar: str) -> argparse.Action:
    """Accept the flag ``new_action`` as a positional argument too, for one release (with a notice);
    the flag is then required only in the sense that one of the two must be given (:class:`Parser`)."""
    _required_either_way(new_action)
    return p.add_argument(new_action.dest, action=Deprecated, new=new_action.option_strings[0],
                          metavar=metavar, type=new_action.type)


def deprecated_command(func, old: str, new: str):
    """A subcommand kept under its old name: prints the notice, then runs the new one."""

    def run(args):
        notice(old, new)
        return func(args)

    run.deprecated = (old, new)
    return run


def subcommands(subparsers, group: str) -> argparse._SubParsersAction:
    """The subcommands of the ``handx GROUP`` parser already added to ``subparsers``, for a module that adds a
    subcommand to another module's group (``handx data tokens``: the data package knows no models)."""
    return next(a for a in subparsers.choices[group]._actions if isinstance(a, argparse._SubParsersAction))


class Parser(argparse.ArgumentParser):
    """argparse, plus required flags that may instead be given by their deprecated spelling: when
    neither was given the error is argparse's own "the following arguments are required"."""

    def parse_known_args(self, args=None, namespace=None):
        ns, extra = super().parse_known_args(args, namespace)
        missing = [a.option_strings[0] for a in self._actions
                   if getattr(a, "required_either_way", False) and getattr(ns, a.dest, None) is None]
        if missing:
            self.error(f"the following arguments are required: {', '.join(missing)}")
        return ns, extra

    def _as_required(self, fmt):
        # usage and help show such a flag as required (no brackets), as argparse would for required=True
        either = [a for a in self._actions if getattr(a, "required_either_way", False)]
        for a in either:
            a.required = True
        try:
            return fmt()
        finally:
            for a in either:
                a.required = False

    def format_usage(self):
        return self._as_required(super().format_usage)

    def error(self, message):
        # One line, exit 2, like every other refusal of the project (issue 54): argparse's own error() prints
        # the whole usage block first, which buries the line that says what is wrong; --help still has it.
        self.exit(2, f"{self.prog}: error: {message}\n")

    def format_help(self):
        return self._as_required(super().format_help)
