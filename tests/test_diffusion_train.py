"""Diffusion family: config overrides, training lowers the loss, exact kill-and-resume, the run
folder becomes a results row, `handx params diffusion`."""

import dataclasses
import json

import jax
import numpy as np
import pytest

from analysis.schema import row_from_run_dir
from handx_jax.cli import main
from handx_jax.families.diffusion import (DiffusionRunConfig, apply_overrides, load_train_data, make_loss,
                                          make_model, params_non_embedding)
from handx_jax.families.diffusion import train as train_diffusion
from handx_jax.models.dit import PRESETS, forward_flops, param_count
from handx_jax.train import load_params
from tests.diffusion_fixtures import ENCODER, RUN_OVERRIDES, make_dataset, make_run, tiny_config


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("diff"))


def test_overrides_are_typed_and_checked():
    cfg = apply_overrides(DiffusionRunConfig(), ["model.layers=3", "train.optim.lr=3e-4", "train.bf16=true",
                                                 "diffusion.blend=xt", "data.fraction=0.2", "train.steps=1e3"])
    assert (cfg.model.layers, cfg.train.optim.lr, cfg.train.bf16, cfg.diffusion.blend, cfg.data.fraction,
            cfg.train.steps) == (3, 3e-4, True, "xt", 0.2, 1000)
    for bad, msg in [("model.layer=3", "did you mean 'model.layers'"), ("modle.layers=3", "did you mean 'model'"),
                     ("model.layers=2.5", "expected an integer"), ("train.optim.lr=fast", "expected a number"),
                     ("train.bf16=maybe", "expected a boolean"), ("train.optim=1", "is a group"),
                     ("model.layers.x=1", "is a value"), ("model.layers", "expected key=value"),
                     ("diffusion.blend=mid", "blend must be"), ("model.heads=5", "not divisible")]:
        with pytest.raises(ValueError, match=msg):
            apply_overrides(DiffusionRunConfig(), [bad])


def test_cli_set_errors_are_clear(data, tmp_path, capsys):
    rc = main(["train", "diffusion", "--data", str(data), "--encoder", str(ENCODER), "--preset", "tiny",
               "--set", "train.stpes=3", "--out", str(tmp_path / "r")])
    assert rc == 2 and "did you mean 'train.steps'" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_preset_and_task_names_agree_with_the_code(capsys):
    from handx_jax.families.diffusion.process import TASKS as D_TASKS

    assert main(["train", "diffusion", "--help"]) == 0
    out = "".join(capsys.readouterr().out.split())  # help text wraps lines (also at hyphens)
    assert all(name in out for name in PRESETS)
    assert main(["generate", "--help"]) == 0
    out = "".join(capsys.readouterr().out.split())
    assert all(t in out for t in D_TASKS)


def test_items_are_clip_level_pairs_with_aligned_fields(data):
    d = load_train_data(tiny_config(data))
    assert d.num_items == len(d.clips) * 5
    b = d.batch(np.array([0, 7]))  # clip 0 level 0, clip 1 level 2
    assert b["x0"].shape == (2, 60, 42, 4) and b["text"].shape[:2] == (2, 3) and b["mask"].shape[:2] == (2, 3)
    for f, name in enumerate(("left", "right", "interaction")):
        h, _ = d.cache.lookup(d.clips[1], name, 2)
        np.testing.assert_array_equal(b["text"][1, f], h)
    assert abs(float(d.x_NxFx42x4.mean())) < 0.2 and 0.5 < float(d.x_NxFx42x4.std()) < 1.5  # normalised


def test_training_lowers_the_loss_and_writes_a_results_row(data, tmp_path):
    # tiny_config's batch size: the same compiled step as the other tiny runs of the session (the learning
    # rate and the length are arguments of the step, not constants in it)
    # 10 steps: the fixed batch's loss falls to 0.39 of the initial one (measured; 0.21 after 30 steps)
    cfg = tiny_config(data, "train.steps=10", "train.log_every=5", "train.ckpt_every=10", "train.optim.lr=2e-3")
    tr = load_train_data(cfg)
    model = make_model(cfg.model)
    loss = jax.jit(make_loss(model, cfg.diffusion), static_argnums=3)  # one compile, not one per op (eager)
    batch = tr.batch(np.arange(0, tr.num_items, 2)[:32])
    # numpy leaves: the initial and the restored params (placed differently) then share one compiled loss
    fixed = lambda p: float(np.mean([loss(jax.tree.map(np.asarray, p), batch, jax.random.PRNGKey(s), False)[0]  # noqa: E731
                                     for s in range(4)]))
    cfg_model = dataclasses.replace(cfg.model, text_dim=32)
    # the run's own initial params: the loop stopped before its first step returns its initial state (the compiled
    # initial state of the session's tiny runs, where a separate init_denoiser would compile a program of its own)
    p0 = train_diffusion(tmp_path / "p0", cfg, stop_at=0)["params"]
    train_diffusion(tmp_path / "run", cfg)
    p1, step = load_params(tmp_path / "run")
    assert step == 10
    assert fixed(p1) < 0.8 * fixed(p0), (fixed(p1), fixed(p0))

    row = row_from_run_dir(tmp_path / "run")
    assert row["family"] == "diffusion" and (row["layers"], row["dim"], row["heads"], row["ff"]) == (2, 64, 4, 128)
    assert row["params"] == param_count(cfg_model) and row["params_non_embedding"] == params_non_embedding(cfg_model)
    doc = json.loads((tmp_path / "run" / "config.json").read_text())
    assert row["flops_per_sample"] == forward_flops(cfg_model, round(doc["text_len_mean"]))
    assert row["data_fraction"] == 1.0 and row["steps"] == 10 and row["samples_seen"] == 10 * 8
    assert row["train_flops"] == pytest.approx(3 * row["flops_per_sample"] * 10 * 8)
    cache_meta = load_train_data(cfg).cache.meta  # three captions through the frozen encoder per sample
    assert row["text_flops_per_sample"] == pytest.approx(3 * cache_meta["encoder_flops_per_caption"]["mean"])
    assert (tmp_path / "run" / "norm_stats.npz").exists()


def test_kill_and_resume_is_exact(tmp_path):
    # The uninterrupted run: the session's tiny run (tests/diffusion_fixtures.py make_run: 4 steps, a checkpoint
    # every 2, a metrics row every step), trained on the same corpus bytes; test_generate.py samples from it.
    data, full = make_run(tmp_path)
    cfg = tiny_config(data, *RUN_OVERRIDES)
    train_diffusion(tmp_path / "b", cfg, stop_at=3)  # "killed" after step 3; last checkpoint is step 2
    resumed = train_diffusion(tmp_path / "b", cfg)
    assert int(resumed["step"]) == load_params(full)[1] == 4
    for ema in (False, True):
        want = jax.tree_util.tree_leaves(load_params(full, ema=ema)[0])
        got = jax.tree_util.tree_leaves(resumed["ema" if ema else "params"])
        assert len(want) == len(got) > 0
        for a, b in zip(want, got):
            np.testing.assert_array_equal(a, b)
    steps = [json.loads(x)["step"] for x in (tmp_path / "b" / "metrics.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 3, 4]  # step 3's row, written before the kill, once
    # Resuming with a different configuration is refused.
    with pytest.raises(ValueError, match="different configuration"):
        train_diffusion(tmp_path / "b", tiny_config(data, "train.optim.lr=5e-4"))


def test_data_fraction_selects_the_nested_subset(data):
    d = load_train_data(tiny_config(data, "data.fraction=0.2"))
    from handx_jax.dataset.format import Dataset

    np.testing.assert_array_equal(d.clips, Dataset.open(data).split("train", 0.2))


def test_params_json(capsys):
    assert main(["params", "diffusion", "--layers", "8", "--dim", "512", "--heads", "8", "--ff", "1024",
                 "--text-dim", "768", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"params", "params_non_embedding", "flops_per_sample", "text_flops_per_sample"}
    assert out["params"] == 26_329_256  # Table C's 26.33M, exactly (tests/test_dit.py counts it by hand)
    assert out["flops_per_sample"] == forward_flops(PRESETS["paper-8L"], 32)
    assert main(["params", "diffusion", "--layers", "2", "--dim", "64", "--heads", "4", "--ff", "128", "--text-dim",
                 "32", "--text-len", "16", "--encoder", str(ENCODER), "--json"]) == 0
    small = json.loads(capsys.readouterr().out)
    from handx_jax.text.hf import load_hf_t5_encoder
    from handx_jax.text.t5 import encoder_flops

    assert small["text_flops_per_sample"] == 3 * encoder_flops(load_hf_t5_encoder(ENCODER).cfg, 16)
