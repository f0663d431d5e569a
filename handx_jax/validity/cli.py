"""``handx standard validity``: the validity suite (``suite.py``) as one command."""

from __future__ import annotations

import argparse
import sys


def _run(a: argparse.Namespace) -> int:
    from handx_jax.annotation.events import ANNOTATIONS
    from handx_jax.infra.errors import DataError
    from handx_jax.validity import suite
    from handx_jax.validity.perturb import KINDS

    if a.annotation and a.annotation not in ANNOTATIONS:
        print(f"handx: error: --annotation {a.annotation!r}: choose one of {', '.join(ANNOTATIONS)}", file=sys.stderr)
        return 2
    kinds = [k.strip() for k in a.kinds.split(",")] if a.kinds else None
    bad = [k for k in kinds or [] if k not in KINDS]
    if bad:
        print(f"handx: error: --kinds {','.join(bad)}: unknown; choose from {', '.join(KINDS)}", file=sys.stderr)
        return 2
    if a.limit is not None and a.limit < 2:
        print("handx: error: --limit must be at least 2 (another clip's motion needs two clips)", file=sys.stderr)
        return 2
    try:
        rep = suite.run(a.data, a.out, evaluator=None if a.no_evaluator else a.evaluator, tokenizers=a.tokenizer or (),
                        annotation=a.annotation, limit=a.limit, block=a.block, seed=a.seed, kinds=kinds)
    except (DataError, FileNotFoundError, ValueError) as e:
        print(f"handx: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {a.out}/validity.json, validity.md and validity.png ({rep['seconds']:.0f} s)")
    return 0


def add_parser(subparsers) -> None:
    """Add ``validity`` to the ``handx standard`` group (``handx_jax.cli`` calls this after the group is
    built): the suite scores with the standard evaluator, but ``standard`` must not import it back."""
    group = subparsers.choices["standard"]
    sub = next(a for a in group._actions if isinstance(a, argparse._SubParsersAction))
    v = sub.add_parser("validity", help="does the yardstick read what captions say? caption stability and the "
                                        "evaluator under perturbations of the ground truth (docs/validity.md)",
                       description=(__import__("handx_jax.validity.suite", fromlist=["x"]).__doc__ or "").split("\n\n")[0])
    v.add_argument("--data", required=True, help="dataset (its test split is perturbed)")
    v.add_argument("--out", required=True, help="folder for validity.json / .md / .png")
    v.add_argument("--evaluator", default="standard", help="evaluator folder (default: the packaged standard one)")
    v.add_argument("--no-evaluator", action="store_true", help="caption stability only")
    v.add_argument("--tokenizer", action="append", metavar="TOK",
                   help="an FSQ tokenizer run: also score the ground truth through it (repeatable)")
    v.add_argument("--annotation", help="annotation reading to re-annotate with (default: the one the dataset "
                                        "was built with; 'reference' for imported data)")
    v.add_argument("--kinds", help="comma-separated perturbation kinds (default: all: "
                                   "white, lowfreq, offset, shift, reverse, other)")
    v.add_argument("--limit", type=int, help="at most this many test clips (the evaluation's selection)")
    v.add_argument("--block", type=int, default=32, help="R-Precision block (default 32)")
    v.add_argument("--seed", type=int, default=0, help="perturbation seed")
    v.set_defaults(func=_run)
