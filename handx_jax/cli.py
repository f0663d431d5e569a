"""The ``handx`` command. Each area registers its own subcommand group from its ``cli`` module.

    handx data ...      corpus synthesis, import/export, statistics, rendering   (handx_jax.commands.data);
                        ``handx data tokens``: FSQ motion tokens, for the AR family (handx_jax.commands.tokens)
    handx text ...      SentencePiece model, T5 encoding, embedding cache         (handx_jax.text.cli)
    handx train ...     train a family, the evaluator or a T5 (families registry) (handx_jax.commands.train)
    handx generate ...  sample motion from text, with masked-constraint tasks    (handx_jax.commands.generate)
    handx eval ...      score generated motion, motion prediction                (handx_jax.commands.eval)
    handx params ...    parameter counts and analytic FLOPs                      (handx_jax.commands.params)
    handx sweep ...     launch sweeps locally or on SLURM, resumable             (sweeps.cli)
    handx analyze ...   scaling fits, tables and plots                           (analysis.cli)
    handx standard ...  the packaged standard evaluator and its corpus           (handx_jax.standard.cli)
    handx import ...    the released HandX weights → run / evaluator folders      (handx_jax.interop.cli)
    handx export ...    a diffusion run → the released HandX checkpoint format    (handx_jax.interop.cli)

Every command spells a concept one way (``handx_jax/cliargs.py``: ``--data``, ``--out``, ``--block``,
``--level``, ``--confidence``, ``--steps``, ``--sample-steps``, ``--encoder``); the spellings of the
release before still work and print one line naming the new one (``handx tokenize`` →
``handx data tokens``, ``handx text pretrain`` → ``handx train t5``, …).

Subcommand modules import heavy dependencies (jax, matplotlib) inside their handlers, so ``--help``
stays fast.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import sys
from pathlib import Path

# (group, module providing add_parser(subparsers)); a group whose module is absent is skipped, so a
# partial checkout still runs the groups it has.
GROUPS = (
    ("data", "handx_jax.commands.data"),
    ("text", "handx_jax.text.cli"),
    ("eval", "handx_jax.commands.eval"),
    ("analyze", "analysis.cli"),
    ("train", "handx_jax.commands.train"),
    ("generate", "handx_jax.commands.generate"),
    ("params", "handx_jax.commands.params"),
    ("data tokens", "handx_jax.commands.tokens"),  # `handx data tokens` (and the old `handx tokenize`)
    ("sweep", "sweeps.cli"),
    ("standard", "handx_jax.standard.cli"),
    ("standard validity", "handx_jax.validity.cli"),  # adds `handx standard validity` to the group above
    ("eval recognition", "handx_jax.commands.recognition"),  # adds `handx eval recognition` to the eval group
    ("import/export", "handx_jax.interop.cli"),
)


def build_parser() -> argparse.ArgumentParser:
    from handx_jax.cliargs import Parser

    p = Parser(  # subcommands' parsers are of the same class (argparse's parser_class)
        prog="handx",
        description="handx-jax: text-to-bimanual-hand-motion (HandX) in JAX, built for scaling sweeps.",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for _name, module in GROUPS:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as e:
            if e.name and module.startswith(e.name):
                continue
            raise
        mod.add_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    from handx_jax.infra.diskspace import disk_full_message
    from handx_jax.infra.errors import DataError
    from handx_jax.infra.runlock import RunLocked

    parser = build_parser()
    # Commands whose options depend on a model family (train, generate, params) take the options
    # they do not know themselves as ``args.extra`` and parse them with the family's own parser.
    args, extra = parser.parse_known_args(argv)
    if extra and not getattr(args, "takes_extra_args", False):
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    args.extra = extra
    from handx_jax.infra import hostdevices

    try:  # before any JAX work: the host's cores as CPU devices for sampling (hostdevices, issue 15)
        hostdevices.configure()
    except ValueError as e:
        print(f"handx: error: {e}", file=sys.stderr)
        return 2
    try:
        rc = args.func(args)
        sys.stdout.flush()  # here, not at exit, so that a closed pipe is caught below
    except (DataError, FileExistsError, FileNotFoundError, RunLocked) as e:
        print(f"handx: error: {_unwritable_message(e, args) or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("handx: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `handx analyze fit ... | head`: the reader left; no traceback, as cat and grep do
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so the interpreter's final flush does not raise again
        return 141
    except Exception as e:  # a full disk, whichever library hit it, is one clear line (issues 14.8, 43)
        msg = disk_full_message(e) or _unwritable_message(e, args)
        if msg is None:
            raise
        print(f"handx: error: {msg}", file=sys.stderr)
        return 2
    return int(rc or 0)


# A path the user named that cannot be written: a read-only file system, no permission, a directory
# where a file goes (or a file where a directory goes), a name too long. The one place every command's
# --out failure becomes one line (issue 31); the atomic writers (io.atomic_write_*) leave nothing behind.
_UNWRITABLE = {errno.EROFS, errno.EACCES, errno.EPERM, errno.EISDIR, errno.ENOTDIR, errno.ENAMETOOLONG}
_OUT_ONLY = {errno.ENOENT, errno.EEXIST}  # one line of its own only when it is about --out


def _unwritable_message(e: BaseException, args) -> str | None:
    if not isinstance(e, OSError) or e.errno not in _UNWRITABLE | _OUT_ONLY:
        return None
    out = getattr(args, "out", None)
    names = [f for f in (e.filename, getattr(e, "filename2", None)) if f is not None]
    if out and names:  # name the option the user gave, not an atomic writer's temporary sibling
        o = Path(out).absolute()
        for f in map(lambda n: Path(os.fsdecode(n)).absolute(), names):
            tmp = f.parent == o.parent and f.name.startswith(f".{o.name}.")  # io.atomic_*'s temporary sibling
            if f == o or tmp or o in f.parents or f in o.parents:
                return f"cannot write --out {out}: {e.strerror.lower()} (choose another --out)"
    if e.errno in _OUT_ONLY:
        return None
    where = os.fsdecode(names[-1]) if names else "a file"
    return f"cannot write {where}: {e.strerror.lower()}"


if __name__ == "__main__":
    sys.exit(main())
