"""``handx train NAME``: train (or resume) a model family, the evaluator or a T5 encoder into a folder.

    handx train diffusion --data DIR --encoder ENC --preset tiny --set train.steps=2000 --out RUN
    handx train evaluator --data DIR --encoder ENC --preset small --out E
    handx train t5 --data DIR --preset tiny --out RUN     (RUN/encoder: the exported frozen encoder)

Re-running the same command on an existing run folder resumes it from its latest checkpoint (the
configuration must match). ``--set`` takes dotted keys of the family's run config (for diffusion
``model.*``, ``diffusion.*``, ``train.*``, ``train.optim.*``, ``data.*``); unknown keys and ill-typed
values are errors. ``handx train FAMILY --help`` lists a family's presets and options; families are
registered in ``handx_jax.families.FAMILIES``.
"""

from __future__ import annotations

import argparse

from handx_jax.commands import fail, parse_family


def family_parser(name: str) -> argparse.ArgumentParser:
    """The full ``handx train NAME`` parser: the shared flags plus the family's own."""
    from handx_jax.config import add_config_args
    from handx_jax.families import entry, get_family

    fam = get_family(name)
    p = argparse.ArgumentParser(prog=f"handx train {name}", description=f"{entry(name).help}.\n\n{__doc__}",
                                formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False)
    add_config_args(p, fam.PRESETS, default=next(iter(fam.PRESETS)))
    p.add_argument("--out", required=True, help="run folder (re-running resumes it)")
    p.add_argument("--quiet", action="store_true", help="do not print the log lines")
    fam.add_train_args(p)
    return p


def _print_row(row: dict) -> None:
    if "loss" in row:
        print(f"step {row['step']:>7d}  loss {row['loss']:.4f}  grad_norm {row['grad_norm']:.3f}  "
              f"lr {row['lr']:.2e}  {row['samples_per_s']:.0f} samples/s", flush=True)
    else:  # an evaluation row
        vals = "  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items() if k != "step")
        print(f"step {row['step']:>7d}  {vals}", flush=True)


def trainable_parser(name: str) -> argparse.ArgumentParser:
    """The ``handx train NAME`` parser of a trainable that is not a family (``families.TRAINABLES``)."""
    import importlib

    from handx_jax.families import TRAINABLES

    mod = importlib.import_module(TRAINABLES[name])
    p = argparse.ArgumentParser(prog=f"handx train {name}", description=f"Train {mod.TRAIN_HELP}. "
                                f"{mod.TRAIN_DESCRIPTION}", allow_abbrev=False)
    mod.add_train_args(p)
    return p


def _run_trainable(args: argparse.Namespace) -> int:
    """``handx train evaluator|t5``: an artefact that is not a model family (``families.TRAINABLES``)."""
    import importlib

    from handx_jax.families import TRAINABLES

    mod = importlib.import_module(TRAINABLES[args.family])
    p = trainable_parser(args.family)
    if args.help:
        p.print_help()
        return 0
    targs = p.parse_args(args.extra)
    refused = _out_inside_data(targs, f"handx train {args.family}")
    return refused if refused is not None else mod.train_from_args(targs)


def _out_inside_data(fargs: argparse.Namespace, cmd: str) -> int | None:
    """A run folder on or inside the dataset it trains on is refused before anything is written (issue 54):
    the run's files would join the dataset's, which `handx data verify` then calls damaged."""
    from handx_jax.infra.errors import DataError
    from handx_jax.infra.outputs import check_out_apart

    if getattr(fargs, "out", None) and getattr(fargs, "data", None):
        try:
            check_out_apart(fargs.out, fargs.data, replaces=False)
        except DataError as e:
            return fail(cmd, e)
    return None


def _run(args: argparse.Namespace) -> int:
    from handx_jax.families import TRAINABLES

    if args.family in TRAINABLES:
        return _run_trainable(args)
    fargs, status = parse_family(args, "train", family_parser, also=TRAINABLES)
    if fargs is None:
        return status
    cmd = f"handx train {args.family}"
    from handx_jax.config import print_config
    from handx_jax.families import get_family
    from handx_jax.train import initialize_distributed

    initialize_distributed()  # before any other JAX call; a no-op unless launched multi-process
    fam = get_family(args.family)
    try:
        cfg = fam.config_from_args(fargs)
    except ValueError as e:
        return fail(cmd, e)
    if fargs.print_config:
        print_config(cfg)
        return 0
    refused = _out_inside_data(fargs, cmd)
    if refused is not None:
        return refused
    import contextlib

    import jax

    from handx_jax.infra.runlock import RunLock, RunLocked

    # One writer per run folder (issue 14.8): taken here, before the family writes anything into it
    # (e.g. norm_stats.npz). Process 0 only: the other processes of a multi-process run are not
    # children of the holder, and only process 0 writes the run files.
    try:
        with RunLock(fargs.out) if jax.process_index() == 0 else contextlib.nullcontext():
            out = fam.train(fargs.out, cfg, on_log=None if fargs.quiet else _print_row)
    except RunLocked as e:
        return fail(cmd, e)
    except ValueError as e:  # config checks the family makes once it sees the data
        return fail(cmd, e)
    except FloatingPointError as e:  # the loop's NaN/inf loss: a diverged run, its earlier checkpoints kept
        return fail(cmd, f"{e}: the run diverged (try a lower train.optim.lr in a new --out; the folder keeps "
                         "its checkpoints from before)")
    print(f"trained {fargs.out}: step {out['step']}")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("train", help="train a model family, the evaluator or a T5 encoder", add_help=False,
                              allow_abbrev=False, description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("family", nargs="?", metavar="NAME", help="model family, evaluator or t5 (see the list below)")
    p.add_argument("-h", "--help", action="store_true", help="show this help (with FAMILY: its options)")
    p.set_defaults(func=_run, parser=p, takes_extra_args=True)
    return p
