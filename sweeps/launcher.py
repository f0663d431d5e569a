"""The sweep launcher: every run of a sweep file, locally or on SLURM, resumable, results as a table.

A sweep is a plain Python file with ``runs(preset="tiny", **kw) -> list[RunSpec]`` and, for SLURM,
``RESOURCES = {"tiny": {...}, "paper": {...}}`` (submitit parameters per preset; see
``sweeps/diffusion_depth_data.py``). Each run goes through idempotent stages, each a ``handx``
subprocess so that one run's crash or memory never takes the sweep down:

    steps     shared steps the run needs (e.g. a tokenizer per codebook), in OUT/steps/NAME-HASH/,
              named from a hash of their commands: computed once, found again by every run
    train     handx train FAMILY --preset P --set ... --out RUN       (resumes from RUN/checkpoints)
    generate  handx generate --run RUN --data DATA --split test --limit N --out RUN/generated.npz
    evaluate  handx eval run --evaluator E --generated RUN/generated.npz --data DATA --json --out RUN

A stage is done when its output exists (every output is written atomically), so a killed sweep re-run
with the same command picks up where it stopped; finished runs are not redone. One run's failure is
recorded (RUN/status.json, the table's ``status``/``error``) and the sweep goes on; ``launch`` reports
the failures and the command exits non-zero at the end.

Scores belong to an evaluator. ``eval.json`` records the id of the evaluator that made it
(``handx_jax.evaluation.evaluator_id``: a hash of its weights and config), and a run counts as scored
only if that is the sweep's evaluator. Relaunching a finished sweep with another ``--evaluator`` (a
retrained one, a new version of the packaged standard evaluator) therefore rescores every run without
retraining it, keeps the old scores as ``RUN/eval.<old id>.json``, and regenerates the samples first
only if the new evaluator scores another caption level. Tables carry ``evaluator``/``evaluator_id``,
and ``handx analyze fit`` refuses rows scored by two evaluators.

One writer per run folder: the process bringing a run through its stages holds ``RunLock(RUN)``
(handx_jax/infra/runlock.py), and its children inherit it. A relaunch waits for (adopts) a run whose lock
is held by a live process instead of starting a second trainer beside it; a lock left by a dead
process is recovered. Children are started with PR_SET_PDEATHSIG, so a launcher killed with -9 takes
its training child with it.

SLURM (``executor="slurm"``): one job array per launch, resources and time limit from the sweep's
preset (refused without a time limit: submitit's 5-minute default must not end runs silently). Job ids
go to OUT/slurm_jobs.json; a relaunch adopts (waits for) jobs of an earlier launch that are still
queued or running, or cancels them first with ``existing="cancel"``, instead of duplicating them. The
launcher waits for every job and records each failure (with SLURM's state, e.g. CANCELLED).

Results: after every run, OUT/results.jsonl and OUT/results.csv are rebuilt (atomically) from the run
folders, one row per run of the sweep: axis values, params, FLOPs in both conventions, training
compute, metrics with CIs, wall time, device kind, git commit, status. All runs share a persistent
JAX compilation cache: the user's JAX_COMPILATION_CACHE_DIR if set, else OUT/jax_cache.

The launcher is four modules, one concern each: ``sweeps.spec`` (what a sweep is: ``RunSpec``,
``Step``, ``SweepConfig``, loading a sweep file), ``sweeps.stages`` (a run's stages and their state
on disk: ``run_one``), ``sweeps.results`` (the results table) and ``sweeps.executors`` (local threads
or SLURM: ``launch``, ``rescore``, ``status``). This module gathers their public names, which sweep
files and callers import (``from sweeps.launcher import RunSpec, run_id``).
"""

from __future__ import annotations

from sweeps.spec import (  # noqa: F401
    NAME_RE, REPO, RunSpec, SHARED_AXES, SHORT, Step, SweepConfig, axes_of, check_name, family_step,
    load_resources, load_rprec_block, load_sweep, one_line, run_id)
from sweeps.stages import (  # noqa: F401
    device_kind, ensure_step, evaluator_identity, generate_settings, git_commit, is_complete,
    read_json_or_empty, run_command, run_dir, run_one, scored_block, stage_state, stale_scores, step_dir,
    update_json)
from sweeps.results import collect_quietly, collect_results, load_state, result_row, run_status  # noqa: F401
from sweeps.executors import (  # noqa: F401
    ACTIVE_SLURM, LaunchResult, launch, rescore, sacct_states, squeue_states, status)
