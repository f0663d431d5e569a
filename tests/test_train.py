import json
import platform

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from handx_jax.optim import OptimConfig
from handx_jax.train import TrainConfig, TrainSpec, batch_indices, load_params
from handx_jax.train import train as train_spec


def train(run_dir, *, stop_at=None, on_log=None, **spec):
    """The loop on the TrainSpec of these fields (these tests' keyword form)."""
    return train_spec(run_dir, TrainSpec(**spec), stop_at=stop_at, on_log=on_log)


def _problem():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(96, 5)).astype(np.float32)
    w_true = np.arange(5, dtype=np.float32)
    y = X @ w_true + 0.01 * rng.normal(size=96).astype(np.float32)

    def init(key):
        return {"w": jax.random.normal(key, (5, 1)) * 0.1, "b": jnp.zeros((1,))}

    def loss(params, batch, key, train):
        noise = jax.random.normal(key, ()) * 0.0  # the rng is threaded; a real family uses it for dropout
        pred = batch["x"] @ params["w"][:, 0] + params["b"][0] + noise
        return jnp.mean((pred - batch["y"]) ** 2), {"mse": jnp.mean((pred - batch["y"]) ** 2)}

    return init, loss, (lambda idx: {"x": X[idx], "y": y[idx]}), w_true


CFG = TrainConfig(steps=40, batch_size=16, log_every=5, ckpt_every=10, wandb="disabled", ema_decay=0.9,
                  optim=OptimConfig(lr=0.3, weight_decay=0.0, warmup_steps=5))


def test_train_learns_and_writes_run_files(tmp_path):
    init, loss, get_batch, w_true = _problem()
    out = train(tmp_path / "run", init=init, loss=loss, get_batch=get_batch, num_examples=96, cfg=CFG,
                config={"family": "toy"})
    rows = [json.loads(l) for l in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == list(range(5, 41, 5))
    assert rows[-1]["loss"] < 0.05 * rows[0]["loss"]
    assert {"loss", "grad_norm", "lr", "samples_per_s", "mse"} <= rows[0].keys()
    assert rows[0]["lr"] == pytest.approx(0.3 * 4 / 5)  # warm-up: lr at step index 4 of 5
    cfg = json.loads((tmp_path / "run" / "config.json").read_text())
    assert cfg["family"] == "toy" and cfg["train"]["steps"] == 40
    # provenance: the numerical stack that trained it, as each package reports its own version
    import flax
    import jaxlib
    import optax
    import orbax.checkpoint
    assert cfg["versions"] == {"python": platform.python_version(), "jax": jax.__version__, "jaxlib": jaxlib.__version__,
                               "flax": flax.__version__, "optax": optax.__version__,
                               "orbax-checkpoint": orbax.checkpoint.__version__, "numpy": np.__version__}
    np.testing.assert_allclose(out["params"]["w"][:, 0], w_true, atol=0.3)
    p, step = load_params(tmp_path / "run")
    assert step == 40
    np.testing.assert_array_equal(p["w"], out["params"]["w"])
    ema, _ = load_params(tmp_path / "run", ema=True)
    assert not np.array_equal(ema["w"], p["w"])
    # A second load of the same verified checkpoint comes from the process's cache of restored trees: the
    # same values, in containers of its own (editing the first result's dicts changes nothing later).
    p["w"] = None
    again, _ = load_params(tmp_path / "run")
    np.testing.assert_array_equal(again["w"], out["params"]["w"])
    np.testing.assert_array_equal(load_params(tmp_path / "run", ema=True)[0]["w"], ema["w"])


def test_kill_and_resume_is_exact(tmp_path):
    init, loss, get_batch, _ = _problem()
    full = train(tmp_path / "a", init=init, loss=loss, get_batch=get_batch, num_examples=96, cfg=CFG, config={})
    # "Killed" after step 23: the last checkpoint is step 20; metrics logged after it are dropped.
    train(tmp_path / "b", init=init, loss=loss, get_batch=get_batch, num_examples=96, cfg=CFG, config={}, stop_at=23)
    # as if started under another jax: the resume keeps that record and adds its own
    doc = json.loads((tmp_path / "b" / "config.json").read_text())
    now, started = doc["versions"], {**doc["versions"], "jax": "0.0.1"}
    (tmp_path / "b" / "config.json").write_text(json.dumps({**doc, "versions": started}))
    resumed = train(tmp_path / "b", init=init, loss=loss, get_batch=get_batch, num_examples=96, cfg=CFG, config={})
    doc = json.loads((tmp_path / "b" / "config.json").read_text())
    assert doc["versions"] == started and doc["versions_at_resume"] == now
    for k in ("w", "b"):
        np.testing.assert_array_equal(resumed["params"][k], full["params"][k])
        np.testing.assert_array_equal(resumed["ema"][k], full["ema"][k])
    steps = [json.loads(l)["step"] for l in (tmp_path / "b" / "metrics.jsonl").read_text().splitlines()]
    assert steps == list(range(5, 41, 5))


def test_batch_indices_cover_epoch_and_are_deterministic():
    a = np.concatenate([batch_indices(100, 10, 3, s) for s in range(10)])
    assert sorted(a) == list(range(100))
    np.testing.assert_array_equal(batch_indices(100, 10, 3, 13), batch_indices(100, 10, 3, 13))
    assert not np.array_equal(batch_indices(100, 10, 3, 0), batch_indices(100, 10, 3, 10))


def test_nan_loss_stops_with_clear_error(tmp_path):
    init, _, get_batch, _ = _problem()

    def bad_loss(params, batch, key, train):
        return jnp.sum(params["w"]) * jnp.nan, {}

    with pytest.raises(FloatingPointError, match="step 5"):
        train(tmp_path / "r", init=init, loss=bad_loss, get_batch=get_batch, num_examples=96, cfg=CFG, config={})


def test_metrics_are_trimmed_when_killed_before_the_first_checkpoint(tmp_path):
    """Issue 14.8: a kill before the first checkpoint used to leave steps 5, 10, 5, 10, … in metrics.jsonl."""
    init, loss, get_batch, _ = _problem()
    kw = dict(init=init, loss=loss, get_batch=get_batch, num_examples=96, cfg=CFG, config={})
    train(tmp_path / "r", **kw, stop_at=8)  # logs step 5, no checkpoint yet (the first is at 10)
    assert not list((tmp_path / "r" / "checkpoints").glob("[0-9]*"))
    train(tmp_path / "r", **kw)
    steps = [json.loads(l)["step"] for l in (tmp_path / "r" / "metrics.jsonl").read_text().splitlines()]
    assert steps == list(range(5, 41, 5))


def test_evaluation_hook_and_resume_check(tmp_path):
    import dataclasses

    from handx_jax.infra.errors import DataError

    init, loss, get_batch, w_true = _problem()
    seen = []

    def evaluate(params, ema, step):
        seen.append(step)
        return {"eval/w_err": float(np.abs(np.asarray(params["w"][:, 0]) - w_true).max()), "eval/has_ema": bool(ema)}

    cfg = dataclasses.replace(CFG, eval_every=20)
    kw = dict(init=init, loss=loss, get_batch=get_batch, num_examples=96, config={"family": "toy"})
    out = train(tmp_path / "r", **kw, cfg=cfg, evaluate=evaluate)
    assert seen == [0, 20, 40]  # the untrained model, every eval_every steps, the end
    rows = [json.loads(l) for l in (tmp_path / "r" / "metrics.jsonl").read_text().splitlines()]
    ev = [r for r in rows if "eval/w_err" in r]
    assert [r["step"] for r in ev] == [0, 20, 40] and ev[-1]["eval/has_ema"] is True
    assert ev[-1]["eval/w_err"] == pytest.approx(float(np.abs(np.asarray(out["params"]["w"][:, 0]) - w_true).max()))
    # The same folder with another config is refused before anything is written.
    before = (tmp_path / "r" / "config.json").read_text()
    with pytest.raises(DataError, match=r"different configuration \(train differ\)"):
        train(tmp_path / "r", **kw, cfg=dataclasses.replace(cfg, batch_size=8))
    with pytest.raises(DataError, match=r"different configuration \(family differ\)"):
        train(tmp_path / "r", **{**kw, "config": {"family": "other"}}, cfg=cfg)
    assert (tmp_path / "r" / "config.json").read_text() == before


def test_checkpoints_carry_checksums_and_flipped_bytes_are_refused(tmp_path):
    """Each checkpoint step folder gets a SHA256SUMS listing (issue 14.8: 64 flipped bytes loaded
    silently); a changed file is a DataError naming it, on resume and on load."""
    from handx_jax.infra.errors import DataError
    from handx_jax.train import load_params

    init, loss, get_batch, _ = _problem()
    train(tmp_path / "r", init=init, loss=loss, get_batch=get_batch, num_examples=96, cfg=CFG, config={})
    step_dir = tmp_path / "r" / "checkpoints" / str(CFG.steps)
    assert (step_dir / "SHA256SUMS").is_file()
    load_params(tmp_path / "r")  # intact: loads
    victim = max((p for p in step_dir.rglob("*") if p.is_file() and p.name != "SHA256SUMS"),
                 key=lambda p: p.stat().st_size)
    raw = bytearray(victim.read_bytes())
    raw[len(raw) // 2:len(raw) // 2 + 64] = bytes(b ^ 0xFF for b in raw[len(raw) // 2:len(raw) // 2 + 64])
    victim.write_bytes(bytes(raw))
    with pytest.raises(DataError, match="checksum mismatch"):
        load_params(tmp_path / "r")
    with pytest.raises(DataError, match=victim.name):
        train(tmp_path / "r", init=init, loss=loss, get_batch=get_batch, num_examples=96,
              cfg=CFG, config={})


@pytest.mark.parametrize("schedule,warmup,steps", [("constant", 0, 20), ("constant", 5, 20), ("cosine", 0, 20),
                                                   ("cosine", 7, 30), ("cosine", 3, 4)])
def test_learning_rate_matches_optax_schedules(schedule, warmup, steps):
    import optax

    from handx_jax.optim import learning_rate, schedule_values

    cfg = OptimConfig(lr=3e-3, warmup_steps=warmup, schedule=schedule)
    if schedule == "constant":
        ref = optax.constant_schedule(cfg.lr)
        if warmup:
            ref = optax.join_schedules([optax.linear_schedule(0.0, cfg.lr, warmup), ref], [warmup])
    else:
        ref = optax.warmup_cosine_decay_schedule(0.0, cfg.lr, max(warmup, 1), max(steps, 2))
    values = schedule_values(cfg, steps)
    for count in range(steps + 3):
        assert float(learning_rate(count, values, schedule)) == pytest.approx(float(ref(count)), rel=1e-5, abs=1e-12)


def test_runs_differing_in_lr_and_length_share_one_compiled_step(tmp_path, monkeypatch):
    """The schedule's numbers are an argument of the step, not constants in it: a learning-rate scan or a
    data-fraction axis at fixed epochs compiles the step once (through the persistent cache)."""
    init, loss, get_batch, _ = _problem()
    real_jit, texts = jax.jit, []

    def spy(fn, **kw):
        jitted = real_jit(fn, **kw)
        if getattr(fn, "__name__", "") != "step_fn":
            return jitted

        def call(*args):
            if len(texts) < 3 and not any(t[0] is jitted for t in texts):
                texts.append((jitted, jitted.lower(*args).as_text()))
            return jitted(*args)
        return call

    monkeypatch.setattr(jax, "jit", spy)
    runs = [CFG, TrainConfig(**{**CFG.__dict__, "steps": 12, "optim": OptimConfig(lr=0.05, weight_decay=0.0)}),
            TrainConfig(**{**CFG.__dict__, "batch_size": 8})]  # a different batch shape: a different program
    for i, cfg in enumerate(runs):
        train(tmp_path / str(i), init=init, loss=loss, get_batch=get_batch, num_examples=96, cfg=cfg, config={})
    assert len(texts) == 3
    assert texts[0][1] == texts[1][1] and texts[0][1] != texts[2][1]


@pytest.mark.parametrize("schedule", ["constant", "cosine"])
def test_warmup_longer_than_the_run_is_capped_and_the_logged_lr_reaches_its_peak(tmp_path, schedule):
    """Issue 30: a 10-step run whose warm-up is 100 steps (a full-length recipe shortened by
    ``train.steps``) warms up over a fifth of the run; the ``lr`` of metrics.jsonl is the one applied."""
    from handx_jax.optim import effective_warmup, learning_rate, schedule_values

    assert effective_warmup(100, 10) == 2 and effective_warmup(10, 10) == 2 and effective_warmup(9, 10) == 9
    assert effective_warmup(8000, 300) == 60 and effective_warmup(5, 0) == 5
    init, loss, get_batch, _ = _problem()
    cfg = TrainConfig(steps=10, batch_size=16, log_every=1, ckpt_every=10, wandb="disabled",
                      optim=OptimConfig(lr=0.1, weight_decay=0.0, warmup_steps=100, schedule=schedule))
    train(tmp_path / "run", init=init, loss=loss, get_batch=get_batch, num_examples=96, cfg=cfg, config={})
    lrs = [json.loads(l)["lr"] for l in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    # Row k (step k) logs the lr of update k - 1: 0, 0.05 over the 2-step warm-up, then the peak.
    assert lrs[:3] == pytest.approx([0.0, 0.05, 0.1])
    if schedule == "constant":
        assert lrs[2:] == pytest.approx([0.1] * 8)
    else:  # cosine from the peak at update 2 to 0 at update 10
        want = [0.1 * 0.5 * (1 + np.cos(np.pi * (c - 2) / 8)) for c in range(2, 10)]
        assert lrs[2:] == pytest.approx(want, rel=1e-5)
    assert max(lrs) == pytest.approx(0.1)
    values = schedule_values(cfg.optim, cfg.steps)
    assert float(learning_rate(2, values, schedule)) == pytest.approx(0.1)


def test_microbatches_give_the_whole_batch_update_and_the_old_config_resumes(tmp_path):
    import dataclasses

    init, loss, get_batch, _ = _problem()
    kw = dict(init=init, loss=loss, get_batch=get_batch, num_examples=96, config={"family": "toy"})
    cfg = dataclasses.replace(CFG, steps=10, ckpt_every=10)
    whole = train(tmp_path / "whole", **kw, cfg=cfg)
    parts = train(tmp_path / "parts", **kw, cfg=dataclasses.replace(cfg, microbatch=4))  # 4 slices of 4
    # the same ten updates up to float rounding (a mean of means of equal slices is the mean)
    np.testing.assert_allclose(parts["params"]["w"], whole["params"]["w"], rtol=1e-5, atol=1e-6)
    rows = [json.loads(line) for line in (tmp_path / "parts" / "metrics.jsonl").read_text().splitlines()]
    ref = [json.loads(line) for line in (tmp_path / "whole" / "metrics.jsonl").read_text().splitlines()]
    assert [r["loss"] for r in rows] == pytest.approx([r["loss"] for r in ref], rel=1e-5)
    with pytest.raises(ValueError, match="train.microbatch 5 must divide train.batch_size 16"):
        train(tmp_path / "bad", **kw, cfg=dataclasses.replace(cfg, microbatch=5))
    # a microbatch of the batch or more is the whole batch (a preset's 32 with --set train.batch_size=8)
    over = train(tmp_path / "over", **kw, cfg=dataclasses.replace(cfg, microbatch=32))
    np.testing.assert_array_equal(over["params"]["w"], whole["params"]["w"])
    # a run folder written before the field existed resumes with its default (0: the whole batch)
    doc = json.loads((tmp_path / "whole" / "config.json").read_text())
    del doc["train"]["microbatch"]
    (tmp_path / "whole" / "config.json").write_text(json.dumps(doc))
    assert train(tmp_path / "whole", **kw, cfg=cfg)["step"] == 10
