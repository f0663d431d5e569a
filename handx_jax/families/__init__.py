"""Model families and the ONE dispatch table, ``FAMILIES``.

``handx train <family>``, ``handx generate --run RUN``, ``handx params <family>`` and the sweep
launcher find a family here by name (a run folder names its family in ``config.json["family"]``);
nothing outside a family's own module asks which family it is. Modules are imported on first use,
so ``handx --help`` does not import JAX.

How to add a family ``foo``:

1. Write ``handx_jax/families/foo.py`` exposing

   - ``FAMILY = "foo"`` (written to ``config.json["family"]`` by ``train``);
   - ``Config``: the frozen run-config dataclass (``handx_jax.config``; a ``validate()`` method is
     run after ``--set`` overrides), ``PRESETS``: named sizes, and
     ``make_config(preset, overrides=(), **paths) -> Config``;
   - ``train(run_dir, cfg, *, stop_at=None, on_log=None, encoder=None) -> dict``: build the model,
     loss and batches and call ``handx_jax.train.train`` (which writes ``config.json``,
     ``metrics.jsonl``, ``checkpoints/`` and refuses to resume with a different config);
   - ``load(run_dir, *, ema=True, encoder=None, overrides=()) -> run``, where ``run`` has ``tasks``,
     ``generate(prompts, opts, *, samples, task, sources, keyframes, fixed_hand)`` → joints
     (P, G, F, 2, 21, 3), ``generate_long(segments, opts, *, samples, source)`` (may raise
     ValueError if unsupported), ``describe(opts) -> str``, ``step``;
   - ``numbers(cfg, **kw) -> {"params", "params_non_embedding", "flops_per_sample",
     "text_flops_per_sample"}``;
   - command-line hooks: ``add_train_args(parser)`` + ``config_from_args(args)`` (the command adds
     ``--preset``, ``--set``, ``--print-config``, ``--out``, ``--quiet``); ``add_params_args(parser)`` +
     ``params_from_args(args) -> (label, numbers)`` (the command adds ``--preset``, ``--set``,
     ``--json``); ``add_generate_args(parser)`` + ``load_for_generate(args, *, ema, encoder, seed,
     batch_size) -> (run, opts)`` (the command adds prompts, tasks, sources, ``--out`` …).

2. Add one line to ``FAMILIES`` below. Nothing else changes.
"""

from __future__ import annotations

import difflib
import importlib
import json
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType


@dataclass(frozen=True)
class Family:
    module: str  # import path of the family module
    help: str  # one line for `handx train --help`


FAMILIES: dict[str, Family] = {
    "diffusion": Family("handx_jax.families.diffusion", "the treble-residual diffusion model (paper §5.1)"),
    "tokenizer": Family("handx_jax.families.tokenizer", "the FSQ motion tokenizer of the AR family (paper §5.2)"),
    "ar": Family("handx_jax.families.ar", "the text-prefix LM over FSQ motion tokens (paper §5.2)"),
}


def get_family(name: str) -> ModuleType:
    """The family module registered as ``name``; an unknown name is a ValueError with a hint."""
    if name not in FAMILIES:
        close = difflib.get_close_matches(name, list(FAMILIES), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"unknown model family {name!r}{hint}; families: {', '.join(FAMILIES)}")
    return importlib.import_module(FAMILIES[name].module)


def family_of(run_dir: str | Path) -> str:
    """The family a run folder was trained as (``config.json["family"]``)."""
    from handx_jax.io import DataError

    p = Path(run_dir) / "config.json"
    if not p.exists():
        raise DataError("not a run folder (no config.json)", path=run_dir)
    try:
        fam = json.loads(p.read_text()).get("family")
    except (json.JSONDecodeError, AttributeError) as e:
        raise DataError(f"config.json is not a JSON object: {e}", path=p) from None
    if not fam:
        raise DataError("config.json names no model family ('family' is missing)", path=p)
    return str(fam)


def run_config(run_dir: str | Path, family: str) -> dict:
    """A run folder's ``config.json``, refused (naming the folder) unless it was trained as ``family``;
    the head of every family's ``load``."""
    found = family_of(run_dir)
    if found != family:
        from handx_jax.io import DataError

        raise DataError(f"not a {family} run folder (config.json names family {found!r})", path=run_dir)
    return json.loads((Path(run_dir) / "config.json").read_text())


def load_run(run_dir: str | Path, **kw):
    """Open any trained run for generation, dispatching on its ``config.json["family"]``."""
    return get_family(family_of(run_dir)).load(run_dir, **kw)
