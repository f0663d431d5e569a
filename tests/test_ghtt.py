"""G-HTT (issue 41): the frame representation's round trip, P fitting a few clips, the gradients of the KL and
contrastive terms, the registry's refusals, and a real tiny sweep scored on prediction."""

from __future__ import annotations

import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from diffusion_fixtures import ENCODER, make_dataset, make_evaluator

from handx_jax.models import ghtt as G
from handx_jax.models import ghtt_motion as HM


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    from handx_jax.dataset.format import Dataset

    data = make_dataset(tmp_path_factory.mktemp("ghtt_ds"), joined=True)
    return data, np.asarray(Dataset.open(data).motion[:8], np.float32)


def test_frames_round_trip_and_ignore_where_the_clip_is(clips):
    _, x = clips
    frames = jax.jit(jax.vmap(HM.to_frames))  # one program each (op by op, the 60-step scans take seconds)
    H, (R, o), s = frames(jnp.asarray(x))
    back = jax.jit(jax.vmap(HM.from_frames))(H, R[:, 0], o[:, 0], s)
    assert float(jnp.abs(back - x).max()) < 1e-4  # metres, over 60 frames of accumulated palm motion
    # continuing from the frame before a span (how predicted spans are placed) is the same inverse
    cont = jax.jit(jax.vmap(lambda h, r, oo, ss: HM.from_frames(h[20:], r, oo, ss, first_is_anchor=False)))(
        H, R[:, 19], o[:, 19], s)
    assert float(jnp.abs(cont - x[:, 20:]).max()) < 1e-4
    # v and r are relative (App. B.2 as read here): a rigid motion of the whole clip changes none of H
    move = jax.jit(lambda y: jnp.einsum("ij,...j->...i", HM.axis_angle_rotation(
        jnp.asarray([0.3, -1.0, 0.5]), jnp.asarray(1.1)), y) + jnp.asarray([0.2, -0.1, 0.4]))
    H2 = frames(move(jnp.asarray(x)))[0]
    assert float(jnp.abs(H2 - H).max()) < 1e-4
    assert H.shape == (8, 60, HM.FRAME_DIM) and HM.FRAME_DIM == 6 * 21 + 27


def test_pose_block_reconstructs_and_predicts_clips_it_was_fitted_on(clips):
    import optax

    from handx_jax.families.ghtt import common as C
    from handx_jax.families.ghtt import pose as PP

    _, x = clips
    x = x[:4]
    cfg = PP.make_config("tiny", ["aug.on=false", "model.pose.layers=1", "model.pose.dim=32", "model.pose.heads=2",
                                  "model.pose.ff=128"])
    H = C.clip_frames(x)
    norm = C.fit_norm(H)
    loss = PP.make_loss(cfg, norm)
    batch = {"H": jnp.asarray(np.concatenate([H[:, s:s + 30] for s in (0, 30)]))}
    params = G.init_pose(jax.random.PRNGKey(0), cfg.model)
    tx = optax.adam(3e-3)
    state = tx.init(params)

    @jax.jit
    def steps(p, s, key):
        def one(c, k):
            p, s = c
            g = jax.grad(lambda q: loss(q, batch, k, True)[0])(p)
            u, s = tx.update(g, s, p)
            return (optax.apply_updates(p, u), s), None

        return jax.lax.scan(one, (p, s), jax.random.split(key, 100))[0]

    before = PP.span_errors_mm(params, cfg.model, norm, x)
    for i in range(2):
        params, state = steps(params, state, jax.random.PRNGKey(i))
    e = PP.span_errors_mm(params, cfg.model, norm, x)
    # the refined span (E^P) and the predicted next span (D^P, m = μ) both well below the clips' mean pose
    assert e["recon_mm"] < 0.5 * e["mean_pose_mm"] and e["pred_mm"] < 0.5 * e["mean_pose_mm"], e
    assert e["pred_mm"] < 0.5 * before["pred_mm"], (before, e)


def _central_diff(f, x, eps=1e-6):
    g = np.zeros_like(x)
    for i in np.ndindex(x.shape):
        d = np.zeros_like(x)
        d[i] = eps
        g[i] = (f(x + d) - f(x - d)) / (2 * eps)
    return g


def test_kl_and_contrastive_gradients():
    from jax import enable_x64

    with enable_x64():
        rng = np.random.default_rng(0)
        mu, lv = rng.normal(size=(3, 5)), rng.normal(size=(3, 5)) * 0.5
        # KL(N(μ, e^lv) ‖ N(0, I)): ∂/∂μ = μ, ∂/∂lv = (e^lv − 1) / 2 (the closed form)
        gmu, glv = jax.grad(lambda m, v: G.kl_normal(m, v).sum(), (0, 1))(jnp.asarray(mu), jnp.asarray(lv))
        np.testing.assert_allclose(gmu, mu, rtol=1e-12)
        np.testing.assert_allclose(glv, 0.5 * (np.exp(lv) - 1.0), rtol=1e-12)
        # Eqs. 3-4 (L1 + InfoNCE at τ 0.07) against central differences, both arguments
        alpha, a = rng.normal(size=(4, 6)), rng.normal(size=(4, 6))
        f = jax.jit(lambda al, aa: sum(G.action_loss(al, aa)))  # one program for the 96 central differences
        ga, gt = jax.grad(f, (0, 1))(jnp.asarray(alpha), jnp.asarray(a))
        np.testing.assert_allclose(ga, _central_diff(lambda z: float(f(jnp.asarray(z), jnp.asarray(a))), alpha),
                                   rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(gt, _central_diff(lambda z: float(f(jnp.asarray(alpha), jnp.asarray(z))), a),
                                   rtol=1e-5, atol=1e-7)
        # the contrastive term prefers the matching caption: aligned pairs score lower than shuffled ones
        l1, nce = G.action_loss(jnp.asarray(a), jnp.asarray(a))
        _, nce_shuf = G.action_loss(jnp.asarray(a[::-1]), jnp.asarray(a))
        assert float(nce) < float(nce_shuf) and float(l1) == 0.0


def test_param_count_is_length_free_and_flops_match_xla():
    cfg = G.PRESETS["tiny"]
    n = G.param_counts(cfg)
    params = G.init_pose(jax.random.PRNGKey(0), cfg)
    assert n["params_pose"] == G.count(params) and n["params"] == n["params_pose"] + n["params_action"]
    paper = G.param_counts(G.PRESETS["paper"])
    # App. B.3: per block 9 encoder layers (4d² + 2dF ≈ 3.15 M) and 9 decoder layers (+ cross-attention 4d²:
    # ≈ 4.2 M), ≈ 66 M per block, P and A alike
    assert 125e6 < paper["params"] < 140e6 and abs(paper["params_pose"] - paper["params_action"]) < 0.02 * paper["params"]
    t = cfg.span
    fn = lambda p, H: G.pose_decode(p, cfg, G.pose_encode(p, cfg, H)[0])  # noqa: E731
    xla = jax.jit(fn).lower(params, jnp.zeros((1, t, HM.FRAME_DIM))).compile().cost_analysis()
    xla = (xla[0] if isinstance(xla, list) else xla)["flops"]
    analytic = G.forward_flops(cfg)["pose"] / (60 // t)  # one span through E^P and D^P
    assert 0.8 < analytic / xla < 1.25, (analytic, xla)


def test_registry_declares_tasks_and_the_launcher_refuses_a_step_as_a_point(tmp_path):
    from handx_jax.families import entry, sweep_task
    from sweeps.launcher import RunSpec, SweepConfig, launch

    assert entry("ghtt").tasks == ("prediction", "recognition") and sweep_task("ghtt") == "prediction"
    assert sweep_task("diffusion") == "text2motion"
    with pytest.raises(ValueError, match="run p: family ghtt-pose generates nothing") as e:
        launch([RunSpec("p", "ghtt-pose")], SweepConfig(data="D", encoder="", out=str(tmp_path / "s"), evaluator="E"))
    assert "\n" not in str(e.value) and not (tmp_path / "s").exists()


@pytest.mark.e2e
def test_real_tiny_ghtt_sweep_scored_on_prediction(tmp_path, capsys, monkeypatch):
    # The stages (subprocesses) compile at LLVM -O0: each trains or samples a few steps, so compiling is
    # their cost, and -O0 compiles faster (the maths is the same; tests/test_first_hour.py says more).
    from test_first_hour import level0

    monkeypatch.setenv("XLA_FLAGS", level0(os.environ.get("XLA_FLAGS", "")))
    from analysis.tables import render_table
    from sweeps.launcher import SweepConfig, launch, load_sweep

    data = make_dataset(tmp_path, joined=True)
    E = make_evaluator(tmp_path / "E")
    specs = load_sweep("sweeps/ghtt_cpu_study.py", preset="tiny", sizes=[(1, 16)],
                       pose_set=["train.batch_size=8", "train.optim.warmup_steps=0"],
                       action_set=["train.batch_size=8", "train.optim.warmup_steps=0"])
    cfg = SweepConfig(data=str(data), encoder=str(ENCODER), out=str(tmp_path / "sweep"), evaluator=str(E),
                      eval_limit=4, rprec_block=4)
    res = launch(specs, cfg)
    assert not res.failed, res.failed
    rows = [json.loads(x) for x in Path(res.results).read_text().splitlines()]
    assert [(r["family"], r["status"], r["layers"], r["dim"]) for r in rows] == [("ghtt", "done", 1, 16)]
    r = rows[0]
    # scored on prediction: the completed clips by the evaluator, the predicted frames by the benchmark
    assert 0 <= r["rprec_top3"] <= 1 and r["fid"] >= 0 and r["mpjpe_ra_left"] > 0 and r["apd_right"] >= 0
    run = tmp_path / "sweep/runs" / specs[0].name
    pred = json.loads((run / "eval_prediction.json").read_text())
    assert pred["_meta"]["observed_frames"] == 16 and pred["_meta"]["samples"] == 20
    assert pred["observed"]["max_joint_error_mm"] < 1.0  # the observed frames come back as given
    assert r["mpjpe_ra_left"] == pytest.approx(pred["predicted"]["mpjpe_ra_left"])
    assert "mpjpe_ra_left" in render_table(rows, "csv").splitlines()[0]
    # the P run is a shared step, passed as --ghtt-pose
    prov = json.loads((run / "provenance.json").read_text())
    assert "--ghtt-pose" in prov["stages"]["train"]["argv"]
    # text-to-motion from nothing is refused in one line, no traceback (the CLI in this process: a subprocess
    # would import JAX and parse the run again for one refusal)
    from handx_jax.cli import main

    capsys.readouterr()
    assert main(["generate", "--run", str(run), "--left", "a", "--right", "b", "--interaction", "c",
                 "--out", str(tmp_path / "x.npz")]) != 0
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "does not do --task text2motion" in err and not (tmp_path / "x.npz").exists()
    # recognition through the registry's contract
    from handx_jax.families import load_run
    from handx_jax.dataset.format import Dataset
    from handx_jax.generation import split_prompts

    ghtt = load_run(run)
    _, prompts, motions = split_prompts(Dataset.open(data), "test", 4, 0)
    em, et = ghtt.embed_motions(np.stack(motions)), ghtt.embed_texts(prompts)
    assert em.shape == et.shape and np.allclose(np.linalg.norm(em, axis=-1), 1, atol=1e-5)
    # ... and `handx eval recognition` beside the evaluator's own retrieval of the same clips
    assert main(["eval", "recognition", "--run", str(run), "--evaluator", str(E), "--block", "4", "--limit", "4",
                 "--replications", "2"]) == 0
    rec = json.loads((run / "eval_recognition.json").read_text())
    assert rec["_meta"]["rprec_block"] == 4 and rec["_meta"]["clips"] == len(prompts)
    for side in ("run", "evaluator_ground_truth"):
        assert 0 <= rec[side]["rprec_top1"]["mean"] <= rec[side]["rprec_top3"]["mean"] <= 1
    assert main(["eval", "recognition", "--run", str(tmp_path / "sweep/steps")]) == 2  # not a run: one line


def test_rectify_starts_a_span_at_the_frame_before_it():
    from handx_jax.families.ghtt import rectify

    rng = np.random.default_rng(1)
    span, before = jnp.asarray(rng.normal(size=(2, 15, HM.FRAME_DIM))), jnp.asarray(rng.normal(size=(2, HM.FRAME_DIM)))
    out = np.asarray(rectify(span, before))
    np.testing.assert_allclose(out[:, 0, HM.P_SLICE], np.asarray(before)[:, HM.P_SLICE], atol=1e-6)
    np.testing.assert_allclose(out[:, -1], np.asarray(span)[:, -1], atol=1e-6)  # blended out by the span's end
    np.testing.assert_array_equal(out[..., HM.V_SLICE.start:], np.asarray(span)[..., HM.V_SLICE.start:])  # motion kept
