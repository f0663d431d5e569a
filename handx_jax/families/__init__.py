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
     loss and batches and call ``handx_jax.train.train(run_dir, TrainSpec(...))`` (which writes
     ``config.json``, ``metrics.jsonl``, ``checkpoints/`` and refuses to resume with a different config);
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

2. Add one line to ``FAMILIES`` below (or, for a family that lives outside the package, e.g. a test's,
   ``register(name, Family(...))``). Nothing else changes: the launcher, the results schema, the
   analysis commands and tables, and the dataset's normalisation statistics read what the entry
   declares.
"""

from __future__ import annotations

import contextlib
import difflib
import importlib
import os
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType


@dataclass(frozen=True)
class Axis:
    """A sweep axis a family adds to the shared ones (layers, dim, heads, ff, data fraction): the results
    column ``name``, the config key a sweep point sets it with (``axes_of`` reads it from the point's
    overrides), its letter in run ids (``run_id``) and display labels (``analysis.schema.config_label``), its
    table header (``analysis.tables``) and the type of its values (a positive number; the results schema's
    column, ``analysis.schema.family_columns``)."""

    name: str
    key: str
    short: str
    header: str
    kind: type = int


@dataclass(frozen=True)
class Family:
    """What the rest of the system knows about a family; nothing outside its module names it.

    ``norm``: how its motion is normalised, ``module:ATTRIBUTE`` of a ``representation.NormPreset``
    (its featuriser, std floor and eps; its name is the ``stats.npz`` prefix; the dataset computes every
    one a family declares).
    ``encoder``: ``handx train NAME`` takes ``--encoder`` (its runs read the frozen text encoder's cache).
    ``needs``: families whose trained run it is trained from, one shared sweep step each, passed as
    ``--NAME STEP_DIR`` (the AR LM: its tokenizer). ``after_train``: commands that finish such a step
    (placeholders ``{out}``, ``{data}``; e.g. writing the token cache). ``results``: its runs are rows
    of a results table (a tokenizer is a step, not a point). ``table``: the ``analysis.tables.LAYOUTS``
    entry a sweep of only this family is shown in (None: the axes that vary). ``flops``: a
    ``module:function`` taking a run's ``config.json`` to its FLOPs per sample in both conventions
    (``flops_per_sample_paper``…, beside the analytic count ``train`` records), or None where the paper
    defines no other convention. ``sweep_sample``: generation settings (``sample.*`` overrides) of a
    sweep's generate stage unless the sweep sets its own (``handx sweep run --set sample.KEY=V``).
    ``axes``: the sweep axes it adds (:class:`Axis`; the AR family's codebook).
    ``tasks``: the generation tasks its runs serve (``handx generate --task``; a run's ``tasks`` is
    this tuple). A family serving ``prediction`` takes ``--observed-frames N`` among its generate
    flags (``handx eval prediction`` passes it); one serving none is a step, not a generator. A family
    serving ``recognition`` (not a generation task: ``handx generate`` refuses it) gives its runs
    ``embed_motions(joints (N, F, 2, 21, 3)) -> (N, D)`` and ``embed_texts(prompts) -> (N, D)``, unit
    vectors whose dot products rank captions for a motion (``handx eval recognition``).
    ``sweep_task``: what a sweep scores its runs on (one of ``tasks``; :func:`sweep_task`): ``text2motion``
    (the split's captions → motion, scored by the evaluator) or ``prediction`` (the split's clips continued
    from their first ``PREDICTION_OBSERVED`` frames: the evaluator scores the completed clips, and
    ``handx eval prediction`` writes ``RUN/eval_prediction.json``, whose predicted frames' MPJPE-RA/-PA and
    APD land in the run's results row).
    """

    module: str  # import path of the family module
    help: str  # one line for `handx train --help`
    norm: str | None = None
    encoder: bool = False
    needs: tuple[str, ...] = ()
    after_train: tuple[tuple[str, ...], ...] = ()
    results: bool = True
    table: str | None = None
    flops: str | None = None
    sweep_sample: tuple[str, ...] = ()
    axes: tuple[Axis, ...] = ()
    tasks: tuple[str, ...] = ("text2motion",)
    sweep_task: str = "text2motion"

    def norm_preset(self):
        """The ``representation.NormPreset`` that ``norm`` names (None without one); its ``name`` is the
        family's ``stats.npz`` prefix."""
        return _resolve(self.norm) if self.norm else None


FAMILIES: dict[str, Family] = {
    "diffusion": Family("handx_jax.families.diffusion", "the treble-residual diffusion model (paper §5.1)",
                        norm="handx_jax.representation.diffusion:DIFFUSION_NORM", encoder=True, flops="handx_jax.families.diffusion.flops:from_config",
                        # DDIM-50: what every diffusion sweep has generated with (DDPM takes all 1,000 steps)
                        sweep_sample=("sample.sampler=ddim", "sample.steps=50"),
                        tasks=("text2motion", "inbetween", "keyframes", "wrist", "reaction", "long", "prediction")),
    "tokenizer": Family("handx_jax.families.tokenizer", "the FSQ motion tokenizer of the AR family (paper §5.2)",
                        norm="handx_jax.representation.ar:AR_NORM", results=False, tasks=(),
                        after_train=(("handx", "data", "tokens", "--tokenizer", "{out}", "--data", "{data}"),)),
    "ar": Family("handx_jax.families.ar", "the text-prefix LM over FSQ motion tokens (paper §5.2)",
                 encoder=True, needs=("tokenizer",), table="table3", tasks=("text2motion", "prediction"),
                 # the FSQ codebook of the tokenizer it is trained from (its runs record it as "codebook")
                 axes=(Axis("codebook", "model.codebook", "K", "Codebook"),)),
    "ghtt-pose": Family("handx_jax.families.ghtt.pose", "G-HTT's pose block P, the step a G-HTT run is trained from",
                        results=False, tasks=()),
    "ghtt": Family("handx_jax.families.ghtt", "G-HTT: the action block A over a trained P (prediction, recognition)",
                   encoder=True, needs=("ghtt-pose",), tasks=("prediction", "recognition"), sweep_task="prediction"),
    "bimart-contact": Family("handx_jax.families.bimart.contact",
                             "BimArt's contact-map generator (§3.2), the step a BimArt run is trained from",
                             results=False, tasks=()),
    "bimart": Family("handx_jax.families.bimart", "BimArt: two hands for an articulated object's trajectory (§3.3-3.4)",
                     needs=("bimart-contact",), tasks=("object2motion",), sweep_task="object2motion"),
}
# A sweep's prediction scoring (``Family.sweep_task == "prediction"``): G-HTT's observation of 16 frames and
# its K = 20 samples (§4.2).
# ``object2motion``: hands for a hand-object corpus split's objects and trajectories, scored by BimArt's metrics
# (``handx eval objects``, RUN/eval_objects.json; no text evaluator).
SWEEP_TASKS = ("text2motion", "prediction", "object2motion")
PREDICTION_OBSERVED = 16
PREDICTION_SAMPLES = 20

# What ``handx train NAME`` trains besides the families: artefacts that are neither generators nor
# results rows (one training verb for everything, issue 42). NAME → the module with
# ``add_train_args(parser)``, ``train_from_args(args) -> exit status`` and ``TRAIN_HELP``.
TRAINABLES: dict[str, str] = {
    "evaluator": "handx_jax.commands.eval",  # the contrastive evaluator (the yardstick)
    "t5": "handx_jax.text.cli",  # T5 span-corruption pretraining (the encoder when none is on disk)
}

# The normalisation statistics a dataset's stats.npz holds besides the families' (``Family.norm``): those
# of the trainables that read the dataset's motion (the evaluator's).
TRAINABLE_NORMS: tuple[str, ...] = ("handx_jax.representation.evaluator:EVALUATOR_NORM",)

# Families registered from outside the package (``register``), as NAME=MODULE pairs: children of this
# process (the sweep launcher's ``handx`` stages) find them here. MODULE holds ``REGISTRY: Family``.
ENV = "HANDX_FAMILIES"


def _from_env(name: str) -> Family | None:
    for item in filter(None, os.environ.get(ENV, "").split(",")):
        n, _, module = item.partition("=")
        if n == name and module:
            return getattr(importlib.import_module(module), "REGISTRY")
    return None


def names() -> list[str]:
    """Every registered family name (the package's, then those registered from outside)."""
    extra = [i.partition("=")[0] for i in filter(None, os.environ.get(ENV, "").split(","))]
    return [*FAMILIES, *(n for n in extra if n not in FAMILIES)]


def entry(name: str) -> Family:
    """The registry entry of ``name``; an unknown name is a ValueError with a hint."""
    fam = FAMILIES.get(name) or _from_env(name)
    if fam is None:
        close = difflib.get_close_matches(name, names(), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"unknown model family {name!r}{hint}; families: {', '.join(names())}")
    return fam


@contextlib.contextmanager
def register(name: str, family: Family):
    """Register ``family`` as ``name`` while the block runs, for this process and its children
    (``HANDX_FAMILIES``); ``family.module`` must define ``REGISTRY = family``."""
    old = os.environ.get(ENV)
    os.environ[ENV] = ",".join(filter(None, [old or "", f"{name}={family.module}"]))
    FAMILIES[name] = family
    try:
        yield family
    finally:
        FAMILIES.pop(name, None)
        if old is None:
            os.environ.pop(ENV, None)
        else:
            os.environ[ENV] = old


def sweep_task(name: str) -> str:
    """The task a sweep scores runs of ``name`` on (``Family.sweep_task``); a ValueError in one line where the
    family cannot be a scored sweep point (it generates nothing, or not the task it declares)."""
    fam = entry(name)
    if not fam.tasks:
        raise ValueError(f"family {name} generates nothing (it is a step another family is trained from): give it "
                         f"to a run as a shared step (sweeps.launcher.family_step), not as a sweep point")
    if fam.sweep_task not in SWEEP_TASKS or fam.sweep_task not in fam.tasks:
        raise ValueError(f"family {name} is scored in sweeps on {fam.sweep_task!r}, which it does not serve (it does "
                         f"{', '.join(fam.tasks)}); sweeps score {', '.join(SWEEP_TASKS)}")
    return fam.sweep_task


def check_task(name: str, task: str) -> None:
    """The one refusal of a task family ``name`` does not serve (``Family.tasks``), asked by every command
    that runs one (``handx generate --task``, ``handx eval prediction``, ``handx eval recognition``) before it
    opens the run: a ValueError in one line saying what the family does instead; a step family (no tasks)
    says what it is for and which family to use."""
    fam = entry(name)
    if task in fam.tasks:
        return
    what = f"--task {task}" if task != "recognition" else "recognition"
    if fam.tasks:
        raise ValueError(f"family {name} does not do {what}; it does {', '.join(fam.tasks)}")
    users = [f for f in names() if name in entry(f).needs]
    use = f"; use the {' or '.join(users)} run trained on it" if users else ""
    raise ValueError(f"family {name} does not do {what}: it is {fam.help}, which generates nothing{use}")


def get_family(name: str) -> ModuleType:
    """The family module registered as ``name``; an unknown name is a ValueError with a hint."""
    return importlib.import_module(entry(name).module)


def _resolve(path: str):
    module, _, attr = path.partition(":")
    return getattr(importlib.import_module(module), attr)


def norm_presets() -> dict:
    """Every normalisation the registry declares, by its ``stats.npz`` prefix: each registered family's
    (``Family.norm``, in registry order), then the trainables' (``TRAINABLE_NORMS``). What a dataset's
    ``stats.npz`` holds: the commands that write one pass these down (``dataset.format.write_dataset(stats=)``)."""
    paths = [entry(f).norm for f in names() if entry(f).norm] + list(TRAINABLE_NORMS)
    out: dict = {}
    for p in dict.fromkeys(paths):
        preset = _resolve(p)
        out.setdefault(preset.name, preset)
    return out


def family_axes() -> dict[str, Axis]:
    """Every registered family's own sweep axes by column name (``Family.axes``)."""
    return {a.name: a for f in names() for a in entry(f).axes}


def flops_columns(config: dict) -> dict:
    """A run's FLOPs per sample in the conventions its family defines beside the analytic one (the
    registry's ``flops``), from its ``config.json``; {} where there are none."""
    fam = FAMILIES.get(config.get("family", "")) or (_from_env(config["family"]) if config.get("family") else None)
    if fam is None or not fam.flops:
        return {}
    module, _, fn = fam.flops.partition(":")
    return getattr(importlib.import_module(module), fn)(config)


def family_of(run_dir: str | Path) -> str:
    """The family a run folder was trained as (``config.json["family"]``)."""
    from handx_jax.infra.errors import DataError

    p = Path(run_dir) / "config.json"
    if not p.exists():
        raise DataError("not a run folder (no config.json)", path=run_dir)
    from handx_jax.infra.readers import read_json

    fam = read_json(p, expect=dict).get("family")
    if not fam:
        raise DataError("config.json names no model family ('family' is missing)", path=p)
    return str(fam)


def run_config(run_dir: str | Path, family: str) -> dict:
    """A run folder's ``config.json``, refused (naming the folder) unless it was trained as ``family``;
    the head of every family's ``load``."""
    found = family_of(run_dir)
    if found != family:
        from handx_jax.infra.errors import DataError

        raise DataError(f"not a {family} run folder (config.json names family {found!r})", path=run_dir)
    from handx_jax.infra.readers import read_json

    return read_json(Path(run_dir) / "config.json", expect=dict)


def generation_config(cfg, overrides, allowed: tuple[str, ...] = ("sample.",)):
    """A loaded run's config with the generation-time ``overrides`` applied and validated; only keys under
    ``allowed`` sections may change (the rest is what the weights were trained with)."""
    from handx_jax.config import apply_overrides

    bad = [o for o in overrides if not o.split("=", 1)[0].strip().startswith(allowed)]
    if bad:
        names = " and ".join(f"{a}*" for a in allowed)
        raise ValueError(f"generation can only override {names} keys, got {bad}")
    cfg = apply_overrides(cfg, overrides, groups=False)  # the run's train.* values are history, not checked
    cfg.validate()
    return cfg


def load_run(run_dir: str | Path, **kw):
    """Open any trained run for generation, dispatching on its ``config.json["family"]``."""
    return get_family(family_of(run_dir)).load(run_dir, **kw)
