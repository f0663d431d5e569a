"""``handx data tokens``: encode every clip of a dataset with a trained FSQ tokenizer (reference §4.4).

    handx data tokens --tokenizer TOK --data DIR [--force]

Writes ``DIR/token_cache/<fingerprint>/`` (``codes.npy`` (N, 30) int32 in clip order, ``meta.json``
with the tokenizer's provenance and its nominal and real codebook size). The fingerprint hashes the
dataset and the tokenizer's parameters; ``handx train ar --tokenizer TOK`` finds the cache by it. One
tokenizer per (dataset, codebook) serves every LM size.

A dataset's derived cache, so it sits among the ``handx data`` commands (as the text cache sits among
``handx text``'s); it is defined here, not in the dataset room (``handx_jax.dataset``), which knows no
models. ``handx tokenize``, its spelling before issue 42, stays for one release with a one-line notice.
"""

from __future__ import annotations

import argparse

from handx_jax.cliargs import deprecated_command, subcommands
from handx_jax.commands import fail


def _run(args: argparse.Namespace) -> int:
    from handx_jax.families.tokenizer import tokenize

    try:
        tokenize(args.tokenizer, args.data, overwrite=args.force)
    except ValueError as e:
        return fail("handx data tokens", e)
    return 0


def _add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tokenizer", required=True, help="tokenizer run folder (`handx train tokenizer`)")
    p.add_argument("--data", required=True, help="dataset directory")
    p.add_argument("--force", action="store_true", help="rebuild an existing token cache")


def add_parser(subparsers) -> None:
    """Add ``tokens`` to the ``handx data`` group (``handx_jax.cli`` calls this after the group is built),
    and the deprecated top-level ``handx tokenize``."""
    p = subcommands(subparsers, "data").add_parser(
        "tokens", help="encode a dataset's clips with an FSQ tokenizer into a token cache", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_args(p)
    p.set_defaults(func=_run)
    old = subparsers.add_parser("tokenize", help="(deprecated: handx data tokens)",
                                description="Deprecated spelling of `handx data tokens`.")
    _add_args(old)
    old.set_defaults(func=deprecated_command(_run, "handx tokenize", "handx data tokens"))
