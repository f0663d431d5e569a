"""``handx standard …``: info, corpus, check and package. The commands call the package's public names
(``handx_jax.standard``), as any client does; ``handx standard validity`` is added to this group by
``handx_jax.validity.cli`` (``handx_jax.cli`` registers it after this one)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

from handx_jax import standard
from handx_jax.infra.values import whole_flag


def _info(a: argparse.Namespace) -> int:
    card = standard.read_card()
    if a.json:
        json.dump({k: v for k, v in card.items() if k != "sha256"}, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(standard.card_markdown(card))
        print(f"assets: {standard.assets_folder()}")
    return 0


def _usage_error(e: Exception) -> int:
    print(f"handx: error: {e}", file=sys.stderr)
    return 2


def _corpus(a: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    try:
        recipe = None if a.corpus is None else standard.corpus_recipe(a.corpus)
        out = standard.build_standard_corpus(a.out, a.clips, workers=a.workers, overwrite=a.force, progress=not a.quiet,
                                             recipe=recipe)
    except ValueError as e:  # a --clips outside the recipe: one line, no traceback
        return _usage_error(e)
    print(f"wrote {out} ({time.perf_counter() - t0:.0f} s)")
    return 0


def _check(a: argparse.Namespace) -> int:
    from handx_jax.dataset.format import Dataset

    found = standard.check_reference(Dataset.open(a.data))
    if a.json:
        json.dump(found, sys.stdout)
        sys.stdout.write("\n")
    else:
        kind = "a prefix of the standard corpus" if found["prefix"] else "the standard corpus"
        note = "" if found["same_bytes"] or found["prefix"] else (
            f" (content hash {found['fingerprint']} differs from the packaging machine's "
            f"{found['standard_fingerprint']}: float rounding of another build, within tolerance)")
        print(f"{a.data}: {kind}, {found['clips']} clips, {found['test_clips']} standard test clips; max motion "
              f"deviation {found['max_motion_deviation_m']:.1e} m{note}")
    return 0


def _package(a: argparse.Namespace) -> int:
    training = dict(kv.split("=", 1) for kv in a.note)
    recipe = None if a.corpus is None else standard.corpus_recipe(a.corpus)
    if a.recipe_clips is not None:
        if a.out is None:
            return _usage_error("--recipe-clips packages a dry run: give --out (the package's own assets are "
                                "the standard recipe's)")
        if a.recipe_clips < 1:
            return _usage_error(f"--recipe-clips must be 1 or more, got {a.recipe_clips}")
        recipe = dataclasses.replace(recipe or standard.code_recipe(), clips=int(a.recipe_clips))
    validity = None
    if a.validity:
        from handx_jax.infra.readers import read_json

        validity = read_json(a.validity, expect=dict)
    if a.validity_only:  # the figures of an already packaged evaluator (the suite needs it packaged)
        if validity is None:
            return _usage_error("--validity-only needs --validity FILE")
        standard.add_validity(standard.assets_folder(a.out), validity)
        print(f"wrote the validity figures on {standard.assets_folder(a.out) / standard.CARD_JSON}")
        return 0
    missing = [f"--{k}" for k in ("data", "encoder", "evaluator") if not getattr(a, k)]
    if missing:
        return _usage_error(f"handx standard package needs {', '.join(missing)} (or --validity-only)")
    evaluator = standard.resolve_evaluator(a.evaluator).folder  # a folder that is not a finished evaluator: one line
    out = standard.package(a.data, a.encoder, evaluator, a.out, training=training, replications=a.replications,
                  recipe=recipe, validity=validity, version=a.version)
    print(f"wrote {out}")
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("standard", help="the packaged standard evaluator and its corpus",
                              description=standard.__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="standard_command", metavar="SUBCOMMAND")
    sub.required = True
    i = sub.add_parser("info", help="print the standard evaluator's card (recipe, training, GT rows)")
    i.add_argument("--json", action="store_true")
    i.set_defaults(func=_info)
    c = sub.add_parser("corpus", help="build the standard corpus, or its first --clips M clips (a prefix)")
    c.add_argument("--out", required=True, help="dataset directory to create")
    c.add_argument("--clips", type=whole_flag(1), help="build only the first M clips (default: the whole standard corpus)")
    c.add_argument("--workers", type=whole_flag(0), default=0, help="processes (0 = one per core)")
    c.add_argument("--corpus", choices=standard.CORPUS_VERSIONS,
                   help="a named corpus version instead of the standard one (v4): v5 = v4 with the hands resolved "
                        "against the hand surface and contacts read from it (no evaluator trained on it yet)")
    c.add_argument("--force", action="store_true", help="replace an existing dataset directory")
    c.add_argument("--quiet", action="store_true", help="no progress bar")
    c.set_defaults(func=_corpus)
    k = sub.add_parser("check", help="is a dataset the standard corpus (or a prefix)? if not, say why and exit 2")
    from handx_jax.cliargs import deprecated_positional

    deprecated_positional(k, k.add_argument("--data", required=True, metavar="DIR", help="dataset directory"), "data")
    k.add_argument("--json", action="store_true")
    k.set_defaults(func=_check)
    g = sub.add_parser("package", help="(maintainers) copy a trained encoder + evaluator into the package assets")
    g.add_argument("--data", help="the standard corpus the evaluator was trained on (required but with --validity-only)")
    g.add_argument("--encoder", help="its T5 encoder folder (required but with --validity-only)")
    g.add_argument("--evaluator", help="its evaluator folder (required but with --validity-only)")
    g.add_argument("--out", help="assets folder (default: the package's)")
    g.add_argument("--replications", type=int, default=20)
    g.add_argument("--note", action="append", default=[], metavar="KEY=VALUE",
                   help="a line for the card's training section, e.g. 'corpus build=612 s on 2 cores'")
    g.add_argument("--recipe-clips", type=int, metavar="N",
                   help="(dry runs of the pipeline) package against the first N clips of the recipe instead of the "
                        "whole standard corpus; needs --out")
    g.add_argument("--corpus", choices=standard.CORPUS_VERSIONS,
                   help="the named corpus version the evaluator was trained on, where it is not yet the code's "
                        "standard one (v8 on v5: scripts/build_standard_v8.sh)")
    g.add_argument("--version", type=whole_flag(1), help=f"the version the card says (default {standard.VERSION}, "
                                                          "this code's)")
    g.add_argument("--validity", metavar="FILE", help="a validity.json of this evaluator (handx standard validity): "
                                                      "its figures go on the card")
    g.add_argument("--validity-only", action="store_true",
                   help="only put --validity's figures on the card of the already packaged assets (--out)")
    g.set_defaults(func=_package)
