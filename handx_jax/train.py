"""One training loop for every model family: state, jitted step, data order, checkpoints.

A family hands :func:`train` a :class:`TrainSpec`: ``init(rng) -> params``, ``loss(params, batch, rng,
train) -> (loss, aux)``, a ``get_batch(indices) -> pytree of arrays``, its ``TrainConfig`` and the run
record; everything else lives here, the optimiser in ``handx_jax.optim`` and the run folder's files in
``handx_jax.runlog``:

- The optimiser of ``TrainConfig.optim`` (``optim.py``: AdamW, warm-up and schedule, clipping),
  optional EMA weights, optional bf16 compute (params and optimizer state stay float32).
- Data order is a pure function of (seed, step): epoch e uses permutation(seed, e). The data
  position is therefore the step, and a resumed run sees exactly the batches it would have seen.
- orbax checkpoints every ``ckpt_every`` steps and at the end, holding params, optimizer state, EMA,
  step and rng; a killed run resumes from the latest one and ends with the same parameters.
- The schedule's numbers are a traced argument of the step (``optim.schedule_values``); each log line's
  ``lr`` is the learning rate the logged step's update really applied.
- The run folder gets ``config.json``, ``metrics.jsonl`` (``runlog.RunLogger``) and
  ``checkpoints/``. Re-running on a
  folder resumes it, only with the same configuration (:func:`check_resume`), and ``metrics.jsonl`` is
  trimmed to the restored step (emptied when no checkpoint was written yet: the step-0 evaluation is
  logged again), so a killed run never logs a row twice.
- ``evaluate(params, ema, step) -> dict`` runs every ``eval_every`` steps and at the end; its row
  (``{"step", "eval/...": ...}``) goes to ``metrics.jsonl`` beside the training rows.
- Data parallel across all devices through ``jax.sharding``: the batch is split along a ("data",)
  mesh axis and parameters are replicated. Multi-host: call :func:`initialize_distributed` before
  any other JAX call (the ``handx train`` command does); each process then loads only its slice of
  the global batch, and only process 0 writes the run files.
"""

from __future__ import annotations

import collections
import dataclasses
import itertools
import math
import os
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from handx_jax.config import ConfigError, validate
from handx_jax.infra.checksums import TREE_CHECKSUMS, verify_tree_checksum, write_tree_checksum
from handx_jax.infra.errors import DataError
from handx_jax.infra.param_files import check_finite_params
from handx_jax.infra.readers import read_json
from handx_jax.optim import OptimConfig, effective_warmup, learning_rate, optimizer_for, schedule_values
from handx_jax.runlog import RunLogger


@dataclass(frozen=True)
class TrainConfig:
    steps: int = 1000
    batch_size: int = 64
    seed: int = 42
    log_every: int = 50
    ckpt_every: int = 500
    keep_checkpoints: int = 2
    ema_decay: float = 0.0  # 0 disables EMA
    # Warm-up of the EMA decay, min(ema_decay, (1 + k)/(10 + k)) at update k, so that a short run's EMA
    # is not dominated by the initial weights.
    ema_warmup: bool = False
    bf16: bool = False
    wandb: str = "offline"  # offline | online | disabled
    # Batches assembled ahead of the step that consumes them, in background threads (0 = inline). On an
    # accelerator the host-side batch (memory-map reads, feature maths) otherwise serialises with the
    # step; batches depend only on (seed, step), so prefetching changes no number.
    prefetch: int = 2
    # Steps between calls of the family's evaluation hook (0: only at the end, if a hook is given).
    eval_every: int = 0
    # Examples per gradient computation (0, or batch_size or more: the whole batch). The batch is split
    # into batch_size / microbatch equal parts whose gradients are averaged in one jitted step: the same
    # update up to float rounding, with the step's temporary memory of one part (the AR `small` LM,
    # docs/results/ar_memory). The loss must be a mean over examples; its metrics are averaged too.
    microbatch: int = 0
    optim: OptimConfig = OptimConfig()

    def check_values(self, key: str = "train") -> None:
        """The loop's ranges, checked before any run folder is made (``config.validate``; :func:`train` again
        for a caller that built the config itself): a step count, batch or interval of 0 divides by zero in
        the loop, a negative step count trains nothing, a negative seed cannot order the data."""
        from handx_jax.infra.values import check

        name = lambda n: f"{key}.{n}" if key else n  # noqa: E731
        for n in ("steps", "batch_size", "log_every", "ckpt_every", "keep_checkpoints"):
            check(getattr(self, n), name(n), whole=True, minimum=1)
        for n in ("seed", "prefetch", "eval_every", "microbatch"):
            check(getattr(self, n), name(n), whole=True, minimum=0)
        check(self.ema_decay, name("ema_decay"), minimum=0, below=1, why="0 disables EMA")
        if self.wandb not in ("offline", "online", "disabled"):
            raise ConfigError(f"{name('wandb')} must be offline, online or disabled, got {self.wandb!r}")
        if 0 < self.microbatch < self.batch_size and self.batch_size % self.microbatch:
            raise ConfigError(f"{name('microbatch')} {self.microbatch} must divide {name('batch_size')} "
                              f"{self.batch_size} (0: the whole batch)")


def batch_indices(n: int, batch_size: int, seed: int, step: int) -> np.ndarray:
    """Indices of the batch at ``step``: epoch-wise permutations, remainder dropped."""
    per_epoch = max(n // batch_size, 1)
    epoch, k = divmod(step, per_epoch)
    perm = np.random.default_rng([seed, epoch]).permutation(n)
    if n < batch_size:  # tiny datasets: sample with wrap-around
        return np.resize(perm, batch_size)
    return perm[k * batch_size:(k + 1) * batch_size]


def initialize_distributed() -> bool:
    """Start multi-host JAX when launched that way; a no-op (False) for a single process.

    Explicit launch: ``JAX_COORDINATOR_ADDRESS`` (host:port), ``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID``.
    Cluster launch: SLURM (``SLURM_NTASKS`` > 1) or Open MPI (``OMPI_COMM_WORLD_SIZE`` > 1), whose
    settings ``jax.distributed.initialize`` detects itself. Must run before any other JAX call.
    """
    env = os.environ
    if env.get("JAX_COORDINATOR_ADDRESS"):
        jax.distributed.initialize(coordinator_address=env["JAX_COORDINATOR_ADDRESS"],
                                   num_processes=int(env["JAX_NUM_PROCESSES"]),
                                   process_id=int(env["JAX_PROCESS_ID"]))
        return True
    if int(env.get("SLURM_NTASKS", "1")) > 1 or int(env.get("OMPI_COMM_WORLD_SIZE", "1")) > 1:
        jax.distributed.initialize()
        return True
    return False


def _local_batch(get_batch: Callable[[np.ndarray], Any], idx: np.ndarray) -> Any:
    """This process's rows of the step's batch (host arrays): all of them for a single process."""
    n = jax.process_count()
    if n == 1:
        return get_batch(idx)
    per = len(idx) // n
    return get_batch(idx[jax.process_index() * per:(jax.process_index() + 1) * per])


def _global_batch(local: Any, global_size: int, sharding) -> Any:
    """The step's batch as a global array sharded over ("data",) from each process's rows."""
    if jax.process_count() == 1:
        return jax.device_put(local, sharding)
    return jax.tree_util.tree_map(
        lambda x: jax.make_array_from_process_local_data(sharding, x, (global_size,) + x.shape[1:]), local)


def _local_rows(batch: Any) -> Any:
    """This process's rows of a whole host batch (all of them for a single process)."""
    n = jax.process_count()
    if n == 1:
        return batch
    i = jax.process_index()
    return jax.tree_util.tree_map(lambda x: x[i * (len(x) // n):(i + 1) * (len(x) // n)], batch)


def _host_batches(get_batch: Callable[[np.ndarray], Any] | None, steps: range, num_examples: int, batch_size: int,
                  seed: int, depth: int, get_step_batch: Callable[[int], Any] | None = None):
    """Yield (step, local host batch) in step order, up to ``depth`` batches built ahead in threads.

    ``get_batch`` must be safe to call from several threads (read-only memory maps and numpy are; numpy
    releases the GIL in copies and maths, so the threads really overlap with the device step).
    """
    if get_step_batch is not None:
        make = lambda s: _local_rows(get_step_batch(s))  # noqa: E731
    else:
        make = lambda s: _local_batch(get_batch, batch_indices(num_examples, batch_size, seed, s))  # noqa: E731
    if depth <= 0:
        for s in steps:
            yield s, make(s)
        return
    import collections
    from concurrent.futures import ThreadPoolExecutor

    it = iter(steps)
    with ThreadPoolExecutor(max_workers=depth, thread_name_prefix="batch") as pool:
        pending = collections.deque((s, pool.submit(make, s)) for s in itertools.islice(it, depth))
        try:
            while pending:
                s, fut = pending.popleft()
                nxt = next(it, None)
                if nxt is not None:
                    pending.append((nxt, pool.submit(make, nxt)))
                yield s, fut.result()
        finally:
            for _, fut in pending:
                fut.cancel()


# TrainConfig fields added after runs were written: absent from an older config.json, they read as the default.
_ADDED_TRAIN_FIELDS = {"microbatch": TrainConfig.microbatch}


def check_resume(run_dir: str | os.PathLike, config: dict, keys: Sequence[str] | None = None,
                 upgrade: Callable[[dict], dict] | None = None) -> None:
    """Re-running on an existing run folder resumes it, but only with the same configuration: the
    ``keys`` of ``config`` (all of them by default) must equal those in the folder's config.json, read
    as ``upgrade`` says an older one reads today (``runlog.trainable_renamed``)."""
    from handx_jax.config import diff_keys

    p = Path(run_dir) / "config.json"
    if not p.exists():
        return
    old = read_json(p, expect=dict)  # corrupt or not an object: one line naming it
    if upgrade is not None:
        old = upgrade(old)
    if isinstance(old.get("train"), dict) and isinstance(config.get("train"), dict):
        # a run written before a TrainConfig field existed ran with that field's default
        old = {**old, "train": {**_ADDED_TRAIN_FIELDS, **old["train"]}}
    diff = diff_keys(old, config, list(config) if keys is None else keys)
    if diff:
        raise DataError(f"run folder exists with a different configuration ({', '.join(diff)} differ); "
                        "use a new --out to start another run", path=run_dir)


def _mesh():
    """The data-parallel mesh: every device, except on CPU, where each process trains on one device.
    Several CPU devices in one process are the same cores split up (``hostdevices``, for sampling).
    This loop's data parallelism across two of them ran paper-4L at 14.4 samples/s against 26.4 on one;
    an explicit shard_map step gained 4-10%, but would draw each device's dropout masks from its own
    slice and cannot split a batch-level loss such as the evaluator's contrastive one (issue 15,
    perf_cpu.json host_devices_2026_11_25)."""
    from jax.sharding import Mesh

    devs = jax.devices()
    if devs[0].platform == "cpu":
        first: dict[int, jax.Device] = {}
        for d in devs:
            first.setdefault(d.process_index, d)
        devs = list(first.values())
    return Mesh(np.asarray(devs), ("data",))


def _cast(tree, dtype):
    return jax.tree_util.tree_map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


@dataclass(frozen=True)
class TrainSpec:
    """What :func:`train` trains: the model, its data, its configuration, and the hooks a family adds.

    ``init(rng) -> params``; ``loss(params, batch, rng, train) -> (loss, aux)``. Batches come from
    ``get_batch(indices)`` over ``num_examples`` items in the order of :func:`batch_indices`, or, for a
    family with its own data order, from ``get_step_batch(step)`` (a pure function of the step, so
    resumes stay exact). ``cfg``: the loop's settings; ``config``: the run record written to
    config.json (with ``train``). ``evaluate(params, ema, step)`` (``ema`` is ``{}`` without EMA)
    returns metrics logged as a row of their own at step 0 of a fresh run, every ``cfg.eval_every``
    steps and at the last step; it must not change the training state. ``optimizer`` =
    (transformation, schedule) replaces the one built from ``cfg.optim`` (a family with its own
    recipe, e.g. T5 pretraining). ``flops_per_sample`` (forward FLOPs of the trainable model per
    sample) makes every log line carry the cumulative ``train_flops`` = 3 × forward × samples seen.
    ``resume_keys``: the keys of ``config`` (+ ``train``) a resumed run must share with the folder's
    config.json (default: all); ``upgrade_config``: how an older config.json reads today (renamed keys,
    :func:`check_resume`).
    """

    init: Callable[[jax.Array], Any]
    loss: Callable[[Any, Any, jax.Array, bool], tuple[jax.Array, dict]]
    cfg: TrainConfig
    config: dict
    get_batch: Callable[[np.ndarray], Any] | None = None
    num_examples: int = 0
    get_step_batch: Callable[[int], Any] | None = None
    evaluate: Callable[[Any, Any, int], dict] | None = None
    optimizer: tuple[optax.GradientTransformation, Callable] | None = None
    flops_per_sample: float | None = None
    resume_keys: Sequence[str] | None = None
    upgrade_config: Callable[[dict], dict] | None = None


def train(run_dir: str | os.PathLike, spec: TrainSpec, *, stop_at: int | None = None,
          on_log: Callable[[dict], None] | None = None, save_at_stop: bool = False) -> dict:
    """Train (or resume) a run of ``spec``; returns {"params", "ema", "step"}.

    ``stop_at`` ends the process early (as if killed) after that step's checkpoint logic — used by the
    kill-and-resume tests; ``save_at_stop`` checkpoints at ``stop_at`` (a pre-emptible job's time
    slice) instead of behaving as killed there. ``on_log(row)`` sees every logged row.
    """
    init, loss, cfg, config = spec.init, spec.loss, spec.cfg, spec.config
    get_batch, num_examples, get_step_batch = spec.get_batch, spec.num_examples, spec.get_step_batch
    evaluate, optimizer, flops_per_sample = spec.evaluate, spec.optimizer, spec.flops_per_sample
    import orbax.checkpoint as ocp
    from jax.sharding import NamedSharding, PartitionSpec as P

    run_dir = Path(run_dir).absolute()
    validate(cfg, "train")  # before the run folder exists: a bad value is refused with nothing written
    doc = {**config, "train": dataclasses.asdict(cfg)}
    check_resume(run_dir, doc, spec.resume_keys, spec.upgrade_config)
    # The run-folder lock (handx_jax.infra.runlock.RunLock, issue 14.8) is taken by `handx train` around the
    # whole family run, before the family writes its first file; library callers take it themselves.
    logger = RunLogger(run_dir, doc, cfg.wandb)
    # (optimizer, schedule) as functions of the schedule's numbers, which the step takes as an argument
    # (see schedule_values); a family's own recipe (``optimizer``) has its numbers compiled in.
    if optimizer is not None:
        sched_v = np.zeros((3,), np.float32)
        schedule_of, tx_of = (lambda _v: optimizer[1]), (lambda _v: optimizer[0])
    else:
        sched_v = schedule_values(cfg.optim, cfg.steps)
        if effective_warmup(cfg.optim.warmup_steps, cfg.steps) != cfg.optim.warmup_steps and jax.process_index() == 0:
            print(f"note: warm-up {cfg.optim.warmup_steps} ≥ the run's {cfg.steps} steps; capped at "
                  f"{int(sched_v[1])} (train.effective_warmup)")
        schedule_of = lambda v: partial(learning_rate, values=v, schedule=cfg.optim.schedule)  # noqa: E731
        tx_of = lambda v: optimizer_for(cfg.optim, schedule_of(v))  # noqa: E731
    mesh = _mesh()
    data_sharding = NamedSharding(mesh, P("data"))
    replicated = NamedSharding(mesh, P())
    if cfg.batch_size % mesh.size:
        raise ValueError(f"batch size {cfg.batch_size} is not divisible by {mesh.size} devices")

    rng = jax.random.PRNGKey(cfg.seed)

    def initial_state(key):
        params = init(key)
        return {"params": params, "opt_state": tx_of(sched_v).init(params),
                # A copy: EMA must not alias params, or donating the state donates one buffer twice.
                "ema": jax.tree_util.tree_map(jnp.copy, params) if cfg.ema_decay > 0 else {},
                "step": jnp.zeros((), jnp.int32)}

    mngr = ocp.CheckpointManager(run_dir / "checkpoints", options=ocp.CheckpointManagerOptions(
        max_to_keep=cfg.keep_checkpoints, create=True, enable_async_checkpointing=False))
    start = 0
    if mngr.latest_step() is None:
        # One jitted program for the whole initial state: run eagerly, every initialiser and optimiser-state
        # op is its own dispatch and compile (seconds on CPU for the tiny presets); the values are the same.
        state = jax.device_put(jax.jit(initial_state)(jax.random.fold_in(rng, 0)), replicated)
    else:
        start = int(mngr.latest_step())
        verify_tree_checksum(run_dir / "checkpoints" / str(start))  # flipped bytes are refused, naming the file
        # A resume needs only the state's shapes: tracing them takes a fraction of a second, where compiling
        # the initial state costs 2-5 CPU-s (random initialisers of every leaf) for values the restore
        # overwrites.
        abstract = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=replicated),
                                          jax.eval_shape(initial_state, jax.random.fold_in(rng, 0)))
        state = mngr.restore(start, args=ocp.args.StandardRestore(abstract))
        state = jax.device_put(state, replicated)
        print(f"resumed from step {start}")
    sched_v = jax.device_put(jnp.asarray(sched_v), replicated)
    # Always, also with no checkpoint yet (start 0, when every row goes, the step-0 evaluation too): rows of
    # a killed attempt beyond the restored step would otherwise be logged twice (10, 20, 30, 10, 20, …).
    logger.truncate_after(start)

    compute_dtype = jnp.bfloat16 if cfg.bf16 else jnp.float32

    def lf(p, batch, step_rng):
        l, aux = loss(_cast(p, compute_dtype) if cfg.bf16 else p, batch, step_rng, True)
        return l.astype(jnp.float32), aux

    value_and_grad = jax.value_and_grad(lf, has_aux=True)
    parts = max(cfg.batch_size // cfg.microbatch, 1) if cfg.microbatch else 1

    def averaged_value_and_grad(params, batch, step_rng):
        """value_and_grad of the mean loss over `parts` equal slices of the batch, one slice at a time
        (a scan, so XLA keeps one slice's activations); slice i draws its randomness from fold_in(rng, i)."""
        sliced = jax.tree_util.tree_map(lambda x: x.reshape(parts, x.shape[0] // parts, *x.shape[1:]), batch)

        def add(total, i_part):
            out = value_and_grad(params, i_part[1], jax.random.fold_in(step_rng, i_part[0]))
            return jax.tree_util.tree_map(jnp.add, total, out), None

        first = jax.tree_util.tree_map(lambda x: x[0], sliced)
        zero = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype),
                                      jax.eval_shape(value_and_grad, params, first, step_rng))
        total, _ = jax.lax.scan(add, zero, (jnp.arange(parts), sliced))
        return jax.tree_util.tree_map(lambda t: t / parts, total)

    def step_fn(state, batch, step_rng, sched_v):
        tx, sched = tx_of(sched_v), schedule_of(sched_v)
        (l, aux), grads = (averaged_value_and_grad if parts > 1 else value_and_grad)(state["params"], batch, step_rng)
        grads = _cast(grads, jnp.float32)
        updates, opt_state = tx.update(grads, state["opt_state"], state["params"])
        params = optax.apply_updates(state["params"], updates)
        ema = state["ema"]
        if cfg.ema_decay > 0:
            k = state["step"].astype(jnp.float32)
            d = jnp.minimum(cfg.ema_decay, (1 + k) / (10 + k)) if cfg.ema_warmup else cfg.ema_decay
            ema = jax.tree_util.tree_map(lambda e, p: d * e + (1 - d) * p, ema, params)
        new = {"params": params, "opt_state": opt_state, "ema": ema, "step": state["step"] + 1}
        metrics = {"loss": l, "grad_norm": optax.tree.norm(grads), "lr": sched(state["step"]), **aux}
        return new, metrics

    jstep = jax.jit(step_fn, donate_argnums=(0,))
    # On CPU the "device" is the host's own cores, so dispatching far ahead overlaps nothing useful: it
    # only keeps every queued step's buffers alive (~1 GB of temporaries each for paper-4L at batch 32),
    # and the allocator then cannot hand the same pages back step after step (handx_jax.infra.hostmem). In a
    # 32-step paper-4L run: unbounded, 5.3M page faults and 5.0 GB peak RSS; two in flight, 1.0M and
    # 3.9 GB; one, 0.4M and 2.9 GB. So at most two steps are in flight there: once step N is queued,
    # the loop waits for N - 1. Waiting for each step (one in flight) was as fast for paper-4L but
    # cost the tiny tokenizer, whose steps take ~20 ms, a quarter of its throughput: the Python
    # dispatch no longer overlaps a running step (docs/results/perf_cpu.json, host_malloc_2026_11_24).
    # A step whose temporary buffer is large keeps one in flight (cpu_steps_in_flight): it runs long
    # enough to hide the dispatch, and a second buffer was most of the AR `small` run's peak (issue 30).
    # Accelerators keep JAX's unbounded asynchronous dispatch.
    bounded = jax.devices()[0].platform == "cpu"
    in_flight: list = []  # the losses of the steps queued and not yet waited for
    depth = None
    end = min(cfg.steps, stop_at) if stop_at is not None else cfg.steps

    def run_eval(done: int) -> None:
        ev = evaluate(state["params"], state["ema"], done)
        if ev:
            row = {"step": done, **ev}
            logger.log(row)
            if on_log:
                on_log(row)

    if evaluate is not None and start == 0 and end > 0:
        run_eval(0)  # the untrained model's numbers, the start of every curve
    t_last, n_since = time.perf_counter(), 0
    for step, local in _host_batches(get_batch, range(start, end), num_examples, cfg.batch_size, cfg.seed,
                                     cfg.prefetch, get_step_batch):
        batch = _global_batch(local, cfg.batch_size, data_sharding)
        args = (state, batch, jax.random.fold_in(jax.random.fold_in(rng, 1), step), sched_v)
        if bounded and depth is None:
            depth = cpu_steps_in_flight(jstep, *args)
        state, metrics = jstep(*args)
        if bounded:  # step `step` is queued: wait until fewer than `depth` are (a loss; the states were donated)
            in_flight.append(metrics["loss"])
            while len(in_flight) > depth - 1:
                jax.block_until_ready(in_flight.pop(0))
        n_since += cfg.batch_size
        done = step + 1
        if done % cfg.log_every == 0 or done == cfg.steps:
            m = {k: float(v) for k, v in jax.device_get(metrics).items()}
            if not math.isfinite(m["loss"]):
                raise FloatingPointError(f"loss is {m['loss']} at step {done} (run {run_dir})")
            dt = time.perf_counter() - t_last
            row = {"step": done, **m, "samples_per_s": n_since / max(dt, 1e-9), "samples_seen": done * cfg.batch_size}
            if flops_per_sample:
                row["train_flops"] = 3.0 * float(flops_per_sample) * row["samples_seen"]
            logger.log(row)
            if on_log:
                on_log(row)
            t_last, n_since = time.perf_counter(), 0
        if evaluate is not None and ((cfg.eval_every and done % cfg.eval_every == 0) or done == cfg.steps):
            run_eval(done)
        if done % cfg.ckpt_every == 0 or done == cfg.steps or (save_at_stop and done == end):
            mngr.save(done, args=ocp.args.StandardSave(state))
            if jax.process_index() == 0:  # synchronous save: the step folder is complete here
                write_tree_checksum(run_dir / "checkpoints" / str(done))
    mngr.wait_until_finished()
    mngr.close()
    logger.close()
    return {"params": state["params"], "ema": state["ema"], "step": int(state["step"])}


# A CPU step whose XLA temporary buffer is larger than this keeps one step in flight, not two: it runs
# long enough to hide the Python dispatch, and a second step in flight only adds a second buffer (paper-4L,
# ~1 GB: as fast with one, 2.9 GB peak against 3.9, the comment in train()). The tokenizer's steps, whose
# throughput needs two, have buffers far below it (37 MB tiny, 73 MB small at batch 64; the AR `small`
# LM 713 MB, or 356 MB per microbatch of 32, docs/results/ar_memory).
IN_FLIGHT_TEMP_BYTES = 256 * 2**20


def cpu_steps_in_flight(jstep, *args) -> int:
    """2, or 1 when the compiled step's temporary buffer exceeds IN_FLIGHT_TEMP_BYTES (2 for a step that
    is not a jitted function). Compiling here costs nothing extra: the jitted step reuses this
    executable at its first call."""
    if not hasattr(jstep, "lower"):
        return 2
    ma = jstep.lower(*args).compile().memory_analysis()
    temp = getattr(ma, "temp_size_in_bytes", None)
    return 1 if temp is not None and temp > IN_FLIGHT_TEMP_BYTES else 2


# The last few trees load_params restored, keyed by (checkpoint folder, which weights, SHA256SUMS text).
# An orbax restore costs ~1 CPU-s of per-leaf Python even for a tiny model (metadata, asyncio reads of
# every leaf of params, optimizer state and EMA), and one process often loads the same run again: a notebook
# that samples, renders and scores, `handx eval prediction` after generation, the tests' many `generate`
# calls. Every load still verifies the files against SHA256SUMS first; an identical listing whose files
# verify is the same bytes, hence the same params. Two entries bound the memory a long session keeps alive.
_RESTORED: "collections.OrderedDict[tuple, Any]" = collections.OrderedDict()
_RESTORED_MAX = 2


def load_params(run_dir: str | os.PathLike, *, ema: bool = False, step: int | None = None):
    """Restore params (or EMA params) from a run folder's latest (or given) checkpoint."""
    import orbax.checkpoint as ocp

    mngr = ocp.CheckpointManager(Path(run_dir).absolute() / "checkpoints")
    step = mngr.latest_step() if step is None else step
    if step is None:
        raise FileNotFoundError(f"no checkpoint in {run_dir}/checkpoints")
    folder = (Path(run_dir).absolute() / "checkpoints" / str(step)).resolve()
    listing = folder / TREE_CHECKSUMS
    key = None
    if verify_tree_checksum(folder):
        key = (str(folder), bool(ema), listing.read_text(encoding="utf-8"))
        if key in _RESTORED:
            mngr.close()
            _RESTORED.move_to_end(key)
            return jax.tree_util.tree_map(lambda a: a, _RESTORED[key]), int(step)  # fresh containers, same leaves
    state = mngr.restore(step, args=ocp.args.StandardRestore())
    mngr.close()
    params = state["ema"] if ema and state["ema"] else state["params"]
    check_finite_params(params, path=folder)  # NaN weights are refused here, naming the parameter (issue 43)
    if key is not None:
        _RESTORED[key] = jax.tree_util.tree_map(lambda a: a, params)  # a caller editing its dicts can't reach it
        while len(_RESTORED) > _RESTORED_MAX:
            _RESTORED.popitem(last=False)
    return params, int(step)
