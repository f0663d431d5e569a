"""``handx tokenize``: encode every clip of a dataset with a trained FSQ tokenizer (reference §4.4).

    handx tokenize --tokenizer TOK --data DIR [--force]

Writes ``DIR/token_cache/<fingerprint>/`` (``codes.npy`` (N, 30) int32 in clip order, ``meta.json``
with the tokenizer's provenance and its nominal and real codebook size). The fingerprint hashes the
dataset and the tokenizer's parameters; ``handx train ar --tokenizer TOK`` finds the cache by it. One
tokenizer per (dataset, codebook) serves every LM size.
"""

from __future__ import annotations

import argparse

from handx_jax.commands import fail


def _run(args: argparse.Namespace) -> int:
    from handx_jax.families.tokenizer import tokenize

    try:
        tokenize(args.tokenizer, args.data, overwrite=args.force)
    except ValueError as e:
        return fail("handx tokenize", e)
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("tokenize", help="encode a dataset's clips with an FSQ tokenizer into a token cache",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tokenizer", required=True, help="tokenizer run folder (`handx train tokenizer`)")
    p.add_argument("--data", required=True, help="dataset directory")
    p.add_argument("--force", action="store_true", help="rebuild an existing token cache")
    p.set_defaults(func=_run)
    return p
