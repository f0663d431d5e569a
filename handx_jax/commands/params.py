"""``handx params <family>``: trainable parameters and analytic forward FLOPs of a configuration.

    handx params diffusion --preset L12-d768 --json
    handx params diffusion --layers 4 --dim 256 --heads 4 --ff 1024 --text-len 32

FLOPs are per sample and per forward pass, 2 per multiply-add, matrix products and attention only.
Every family prints ``params``, ``params_non_embedding``, ``flops_per_sample`` and
``text_flops_per_sample`` (the frozen text encoder, counted apart). Size flags override the preset;
``--set`` takes the same dotted keys as ``handx train``. ``handx params FAMILY --help`` lists a
family's flags.
"""

from __future__ import annotations

import argparse
import json

from handx_jax.commands import fail, parse_family


def family_parser(name: str) -> argparse.ArgumentParser:
    from handx_jax.config import add_config_args
    from handx_jax.families import entry, get_family

    fam = get_family(name)
    p = argparse.ArgumentParser(prog=f"handx params {name}", description=f"{entry(name).help}.\n\n{__doc__}",
                                formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False)
    add_config_args(p, fam.PRESETS, default=next(iter(fam.PRESETS)), example="model.layers=8")
    p.add_argument("--json", action="store_true",
                   help="print {params, params_non_embedding, flops_per_sample, text_flops_per_sample}")
    fam.add_params_args(p)
    return p


def _run(args: argparse.Namespace) -> int:
    fargs, status = parse_family(args, "params", family_parser)
    if fargs is None:
        return status
    from handx_jax.families import get_family

    cmd = f"handx params {args.family}"
    try:
        label, out = get_family(args.family).params_from_args(fargs)
    except ValueError as e:
        return fail(cmd, e)
    if fargs.json:
        print(json.dumps(out))
    else:
        print(f"{label}: {out['params']:,} params ({out['params'] / 1e6:.2f}M; "
              f"{out['params_non_embedding']:,} non-embedding), {out['flops_per_sample'] / 1e9:.3f} GFLOPs/sample "
              f"forward; text encoder {out['text_flops_per_sample'] / 1e9:.3f} GFLOPs/sample")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("params", help="parameter count and analytic FLOPs of a model configuration",
                              add_help=False, allow_abbrev=False, description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("family", nargs="?", metavar="FAMILY", help="model family (see the list below)")
    p.add_argument("-h", "--help", action="store_true", help="show this help (with FAMILY: its options)")
    p.set_defaults(func=_run, parser=p, takes_extra_args=True)
    return p
