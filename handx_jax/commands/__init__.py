"""``handx`` subcommand groups that span several packages (data, eval, eval recognition, train, generate, params,
data tokens): the command layer. It asks the family registry and passes down what the rooms below it need
(``dataset``, ``evaluation`` … import neither it nor the registry: tests/test_package_rules.py)."""

from __future__ import annotations

import sys


def fail(cmd: str, err: object, code: int = 2) -> int:
    """Print ``cmd: error: err`` on stderr and return the exit status (every command's error path)."""
    print(f"{cmd}: error: {err}", file=sys.stderr)
    return code


def parse_family(args, verb: str, family_parser, also=()):
    """The shared head of ``handx train|params FAMILY``: list the families, show help, or parse the
    family's own flags. Returns ``(family_args, None)`` to go on, or ``(None, exit_status)``."""
    from handx_jax.families import entry, names

    if args.family is None:
        args.parser.print_help()
        print("\nfamilies:\n" + "\n".join(f"  {k:<12s}{entry(k).help}" for k in names()))
        if also:  # handx train: what it trains besides the families (families.TRAINABLES)
            import importlib

            print("also:\n" + "\n".join(f"  {k:<12s}{importlib.import_module(m).TRAIN_HELP}" for k, m in also.items()))
        return None, 0 if args.help else fail(f"handx {verb}", "give a FAMILY")
    try:
        p = family_parser(args.family)
    except ValueError as e:
        return None, fail(f"handx {verb}", e)
    if args.help:
        p.print_help()
        return None, 0
    return p.parse_args(args.extra), None
