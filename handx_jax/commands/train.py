"""``handx train <family>``: train (or resume) a model family into a run folder.

    handx train diffusion --data DIR --encoder ENC --preset tiny --set train.steps=2000 --out RUN

Re-running the same command on an existing run folder resumes it from its latest checkpoint (the
configuration must match). ``--set`` takes dotted keys of the run config (``model.*``,
``diffusion.*``, ``train.*``, ``train.optim.*``, ``data.*``); unknown keys and ill-typed values are
errors.
"""

from __future__ import annotations

import argparse
import dataclasses
import json

# models.dit.PRESETS (kept literal so --help does not import JAX; tests check they agree).
PRESET_NAMES = ("tiny", "small", "paper-4L", "paper-8L", "paper-12L")


def _diffusion(args: argparse.Namespace) -> int:
    from handx_jax.train import initialize_distributed

    initialize_distributed()  # before any other JAX call; a no-op unless launched multi-process
    from handx_jax.diffusion_family import make_config, train_diffusion

    try:
        cfg = make_config(args.preset, args.data, args.encoder, args.set or [])
    except ValueError as e:
        print(f"handx train diffusion: error: {e}")
        return 2
    if args.print_config:
        print(json.dumps(dataclasses.asdict(cfg), indent=2))
        return 0

    def on_log(row):
        if not args.quiet:
            print(f"step {row['step']:>7d}  loss {row['loss']:.4f}  grad_norm {row['grad_norm']:.3f}  "
                  f"lr {row['lr']:.2e}  {row['samples_per_s']:.0f} samples/s", flush=True)

    out = train_diffusion(args.out, cfg, on_log=on_log)
    print(f"trained {args.out}: step {out['step']}")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("train", help="train a model family (diffusion)",
                              description="Train a model family into a run folder (config.json, metrics.jsonl, "
                                          "checkpoints/); re-running resumes.")
    p.set_defaults(func=lambda a: (p.print_help(), 0)[1])
    sub = p.add_subparsers(dest="family", metavar="FAMILY")
    d = sub.add_parser("diffusion", help="the treble-residual diffusion model (paper §5.1)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    d.add_argument("--data", required=True, help="dataset directory (with a text cache for --encoder)")
    d.add_argument("--encoder", required=True, help="frozen T5 encoder folder")
    d.add_argument("--preset", default="tiny", choices=PRESET_NAMES)
    d.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a config value, e.g. train.steps=2000, train.optim.lr=3e-4, data.fraction=0.2")
    d.add_argument("--out", required=True, help="run folder")
    d.add_argument("--print-config", action="store_true", help="print the resolved config and exit")
    d.add_argument("--quiet", action="store_true")
    d.set_defaults(func=_diffusion)
    return p
