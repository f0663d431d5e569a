"""``handx standard validity``: the validity suite (``suite.py``) as one command."""

from __future__ import annotations

import argparse
import sys


def _run(a: argparse.Namespace) -> int:
    from handx_jax.annotation.events import ANNOTATIONS
    from handx_jax.infra.errors import DataError
    from handx_jax.validity import suite

    if a.annotation and a.annotation not in ANNOTATIONS:
        print(f"handx: error: --annotation {a.annotation!r}: choose one of {', '.join(ANNOTATIONS)}", file=sys.stderr)
        return 2
    # --kinds "" names no kind (it ran every kind): only an absent --kinds means all of them
    kinds = None if a.kinds is None else [k.strip() for k in a.kinds.split(",") if k.strip()]
    try:
        rep = suite.run(a.data, a.out, evaluator=None if a.no_evaluator else a.evaluator, tokenizers=a.tokenizer or (),
                        annotation=a.annotation, limit=a.limit, block=a.block, seed=a.seed, kinds=kinds)
    except (DataError, FileNotFoundError, ValueError) as e:  # ValueError: config.ConfigError too
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
    v.add_argument("--evaluator", default="standard", help="'standard' (default, the packaged one), a version such as "
                                                           "standard-v6, or an evaluator folder")
    v.add_argument("--no-evaluator", action="store_true", help="caption stability only")
    v.add_argument("--tokenizer", action="append", metavar="TOK",
                   help="an FSQ tokenizer run: also score the ground truth through it (repeatable)")
    v.add_argument("--annotation", help="annotation reading to re-annotate with (default: the one the dataset "
                                        "was built with; 'reference' for imported data)")
    from handx_jax.validity.perturb import KINDS

    v.add_argument("--kinds", help=f"comma-separated perturbation kinds (default: all: {', '.join(KINDS)})")
    from handx_jax.infra.values import whole_flag
    from handx_jax.validity.suite import BLOCK_WHY, MIN_BLOCK

    v.add_argument("--limit", type=whole_flag(2, why="another clip's motion needs two clips"),
                   help="at most this many test clips (the evaluation's selection; 2 or more)")
    v.add_argument("--block", type=whole_flag(MIN_BLOCK, why=BLOCK_WHY), default=32,
                   help=f"R-Precision block (default 32; at least {MIN_BLOCK})")
    v.add_argument("--seed", type=whole_flag(0), default=0, help="perturbation seed (0 or more)")
    v.set_defaults(func=_run)
