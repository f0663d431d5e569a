"""The prediction benchmark's arithmetic (handx_jax/evaluation/prediction.py) with known answers, the
last-frame baseline through the CLI, and its bad input. No model is trained here: the end-to-end runs of
each family are in tests/test_generate.py and tests/test_ar_family.py (their module fixtures)."""

import json

import numpy as np
import pytest

from handx_jax.cli import main
from handx_jax.evaluation import prediction as PR
from handx_jax.metrics import MetricConfig, prompt_mean_ci
from tests.diffusion_fixtures import make_dataset


def test_default_bins_are_ghtts_after_16_frames_and_follow_n():
    assert PR.horizon_bins(16) == ((16, 32), (32, 48), (48, 60))
    assert [PR.label(a, b) for a, b in PR.horizon_bins(16)] == ["17-32", "33-48", "49-60"]
    assert PR.horizon_bins(20) == ((20, 36), (36, 52), (52, 60))  # an 8-frame rest: half a bin, kept
    assert PR.horizon_bins(40) == ((40, 60),)  # 41-56 and a 4-frame rest, merged
    assert PR.horizon_bins(10) == ((10, 26), (26, 42), (42, 60))  # 58-60 merged into 43-58
    assert PR.horizon_bins(58) == ((58, 60),)
    for n in (0, 60):
        with pytest.raises(ValueError, match="--observed-frames must be in"):
            PR.horizon_bins(n)


def test_horizons_option_parses_one_based_ranges_and_refuses_the_observation():
    assert PR.parse_horizons("17-32, 33-60", 16) == ((16, 32), (32, 60))
    assert PR.parse_horizons("60", 16) == ((59, 60),)
    for bad, words in (("10-20", "must lie in frames 17-60"), ("33-32", "must lie"), ("17-61", "must lie"),
                       ("a-b", "not a frame range"), (",", "names no frame range")):
        with pytest.raises(ValueError, match=words):
            PR.parse_horizons(bad, 16)


def _clips(n=4, seed=0):
    return np.random.default_rng(seed).normal(0, 0.05, (n, 60, 2, 21, 3)).astype(np.float32)


def test_a_perfect_predictor_scores_zero_everywhere():
    gt = _clips()
    res = PR.score(np.stack([gt, gt, gt]), gt, 16, PR.horizon_bins(16))
    rows = [res["observed"], res["first"], *res["horizons"], res["predicted"]]
    assert [r["frames"] for r in rows] == ["1-16", "17-17", "17-32", "33-48", "49-60", "17-60"]
    for r in rows:
        for k in ("mpjpe_ra_left", "mpjpe_ra_right", "mpjpe_ra_both", "mpjpe_pa_both", "mpjpe_both",
                  "mpjpe_ra_best_of_k", "apd_left", "apd_right", "apd_both"):
            assert r[k] == pytest.approx(0.0, abs=1e-3) and r[k + "_ci"] == pytest.approx(0.0, abs=1e-3)
    assert res["observed"]["max_joint_error_mm"] == 0.0


def test_known_errors_diversity_and_best_of_k():
    """Sample 0 is the clip; sample 1 moves the 20 non-wrist joints of both hands by 30 mm along x in the
    predicted frames. Per joint the root-aligned error is 30 mm on 20 of 21 joints: MPJPE-RA of sample 1
    is 30·20/21 mm, of the two samples' mean half that, best-of-K 0, APD 30·20/21; a translation of the
    whole finger set is not a similarity of the hand, so PA is > 0 but below RA."""
    gt = _clips()
    moved = gt.copy()
    moved[:, 16:, :, 1:, 0] += 0.030
    res = PR.score(np.stack([gt, moved]), gt, 16, PR.horizon_bins(16))
    want = 30.0 * 20 / 21
    for r in (*res["horizons"], res["predicted"]):
        assert r["mpjpe_ra_left"] == pytest.approx(want / 2, rel=1e-4)
        assert r["mpjpe_ra_both"] == pytest.approx(want / 2, rel=1e-4)
        assert r["mpjpe_both"] == pytest.approx(want / 2, rel=1e-4)  # no wrist moved: the same in the clip frame
        assert r["mpjpe_ra_best_of_k"] == pytest.approx(0.0, abs=1e-4)
        assert r["apd_left"] == pytest.approx(want, rel=1e-4) and r["apd_both"] == pytest.approx(want, rel=1e-4)
        assert 0 < r["mpjpe_pa_both"] < r["mpjpe_ra_both"]
        # Every clip has the same error, so resampling the clips cannot move the mean: the interval is 0.
        assert r["mpjpe_ra_both_ci"] == pytest.approx(0.0, abs=1e-6)
    assert res["observed"]["mpjpe_ra_both"] == 0 and res["observed"]["apd_both"] == 0


def test_the_interval_is_a_bootstrap_over_clips():
    m, h = prompt_mean_ci(np.arange(1.0, 101.0), MetricConfig(seed=1, bootstrap=2000))
    # 1.96 × the standard error of the mean of 1..100 (sd 28.87, ddof 0): 1.96 · 28.87 / √100 = 5.66
    assert m == 50.5 and h == pytest.approx(5.66, rel=0.08)
    assert prompt_mean_ci([5.0, 5.0, 5.0]) == (5.0, 0.0)
    v = np.random.default_rng(0).normal(size=50)
    assert prompt_mean_ci(v, MetricConfig(seed=3)) == prompt_mean_ci(v, MetricConfig(seed=3))  # seeded draws


def test_last_frame_baseline_holds_the_last_observed_frame():
    gt = _clips(2)
    b = PR.last_frame(gt, 16)
    np.testing.assert_array_equal(b[:, :16], gt[:, :16])
    np.testing.assert_array_equal(b[:, 16:], np.broadcast_to(gt[:, 15:16], b[:, 16:].shape))
    still = np.repeat(gt[:, :1], 60, 1)  # a clip that does not move: the baseline is exact
    assert PR.score(PR.last_frame(still, 16)[None], still, 16, PR.horizon_bins(16))["predicted"]["mpjpe_both"] == 0


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("pred"))


def test_baseline_through_the_cli(data, tmp_path, capsys):
    out = tmp_path / "base.json"
    assert main(["eval", "prediction", "--baseline", "last-frame", "--data", str(data), "--observed-frames", "16",
                 "--samples", "2", "--evaluator", "none", "--out", str(out)]) == 0
    table = capsys.readouterr().out
    assert "49-60" in table and "observed 1-16" in table and "largest joint error 0 mm" in table
    res = json.loads(out.read_text())
    assert [r["frames"] for r in res["horizons"]] == ["17-32", "33-48", "49-60"]
    assert res["_meta"]["baseline"] == "last-frame" and res["_meta"]["samples"] == 2
    assert res["observed"]["mpjpe_both"] == 0 and res["predicted"]["apd_both"] == 0  # identical samples
    # Holding still drifts from moving clips: the error grows with the horizon.
    ra = [r["mpjpe_both"] for r in res["horizons"]]
    assert 0 < ra[0] < ra[2] and res["predicted"]["mpjpe_both_ci"] > 0  # over clips: > 0 for a fixed predictor


@pytest.mark.parametrize("argv, words", [
    (["--baseline", "last-frame", "--observed-frames", "16"], "--baseline needs --data"),
    (["--observed-frames", "16"], "give --run RUN or --baseline last-frame|velocity|ground-truth"),
    (["--baseline", "last-frame", "--data", "{data}", "--observed-frames", "16"],
     "not the standard recipe"),  # the standard evaluator (the default) refuses a dataset it was not made for
    (["--run", "{tmp}/nowhere", "--observed-frames", "16"], "not a run folder (no config.json)"),
    (["--baseline", "last-frame", "--data", "{data}", "--observed-frames", "60"],
     "--observed-frames must be in (0, 60)"),
    (["--baseline", "last-frame", "--data", "{data}", "--observed-frames", "16", "--horizons", "5-20"],
     "--horizons: 5-20 must lie in frames 17-60"),
    (["--baseline", "last-frame", "--data", "{data}", "--observed-frames", "16", "--samples", "0"], "--samples"),
    (["--baseline", "last-frame", "--data", "{data}", "--observed-frames", "16", "--sampler", "ddim"],
     "family flags need --run"),
    (["--run", "{ar}", "--data", "{data}", "--observed-frames", "15", "--evaluator", "none"],
     "--observed-frames must be even"),
    (["--run", "{ar}", "--data", "{data}", "--observed-frames", "16", "--bogus", "3"],
     "unrecognized arguments: --bogus"),
    (["--run", "{tok}", "--data", "{data}", "--observed-frames", "16"],
     "family tokenizer does not do --task prediction"),
])
def test_bad_input_is_one_line(data, tmp_path, capsys, argv, words):
    for fam in ("ar", "tokenizer"):  # the family's flags are checked before its run is read
        (tmp_path / fam[:3]).mkdir()
        (tmp_path / fam[:3] / "config.json").write_text(f'{{"family": "{fam}"}}')
    argv = [a.format(tmp=tmp_path, data=data, ar=tmp_path / "ar", tok=tmp_path / "tok") for a in argv]
    assert main(["eval", "prediction", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("handx eval prediction: error: ") and words in err and "\n" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ar", "tok"]  # nothing written


def test_the_held_baseline_matches_an_independent_computation_and_the_paired_difference():
    """MPJPE-RA of holding the last frame, computed here with plain numpy (each hand's joints minus its wrist,
    the mean distance), equals the benchmark's; a predictor's paired difference to it is its own error minus
    this, per clip; the first-frame row is frame N + 1 alone; the error of the samples' mean is that of the
    mean pose."""
    gt = _clips(5, seed=2)
    held = PR.last_frame(gt, 16)
    ra = lambda p: np.linalg.norm((p - p[..., :1, :]) - (gt - gt[..., :1, :]), axis=-1).mean(-1)  # noqa: E731 (N,T,2)
    want_N = 1000 * ra(held)[:, 16:].mean((1, 2))
    res = PR.score(held[None], gt, 16, PR.horizon_bins(16))
    assert res["predicted"]["mpjpe_ra_both"] == pytest.approx(want_N.mean(), rel=1e-5)
    assert res["first"]["mpjpe_ra_both"] == pytest.approx(1000 * ra(held)[:, 16].mean(), rel=1e-5)
    assert res["predicted"]["mpjpe_ra_vs_last_frame"] == pytest.approx(0.0, abs=1e-4)
    # A perfect predictor is better than holding still by exactly the held error, clip by clip.
    res = PR.score(np.stack([gt, gt]), gt, 16, PR.horizon_bins(16))
    assert res["predicted"]["mpjpe_ra_vs_last_frame"] == pytest.approx(-want_N.mean(), rel=1e-5)
    assert res["predicted"]["mpjpe_ra_best_of_k_vs_last_frame"] == pytest.approx(-want_N.mean(), rel=1e-5)
    # Two samples on either side of the clip: each is 30 mm off (20 of 21 joints), their mean is the clip.
    up, down = gt.copy(), gt.copy()
    up[:, 16:, :, 1:, 0] += 0.030
    down[:, 16:, :, 1:, 0] -= 0.030
    res = PR.score(np.stack([up, down]), gt, 16, PR.horizon_bins(16))
    assert res["predicted"]["mpjpe_ra_both"] == pytest.approx(30.0 * 20 / 21, rel=1e-4)
    assert res["predicted"]["mpjpe_ra_sample_mean"] == pytest.approx(0.0, abs=1e-3)


def test_the_commands_baseline_names_are_the_benchmarks():
    from handx_jax.commands.eval import PR_BASELINES

    assert PR_BASELINES == tuple(PR.BASELINES)


def test_velocity_baseline_continues_the_last_step():
    """A clip moving at constant velocity is continued exactly; holding still falls behind it linearly."""
    t = np.arange(60, dtype=np.float32)[None, :, None, None, None]
    base = _clips(2, seed=4)[:, :1]
    step = np.random.default_rng(5).normal(0, 0.002, (2, 1, 2, 21, 3)).astype(np.float32)
    clip = base + t * step
    v = PR.velocity(clip, 16)
    np.testing.assert_allclose(v, clip, atol=1e-5)
    np.testing.assert_array_equal(PR.velocity(clip, 1), PR.last_frame(clip, 1))  # one frame: no step to continue
    res = PR.score(PR.last_frame(clip, 16)[None], clip, 16, PR.horizon_bins(16))
    assert res["first"]["mpjpe_both"] < res["horizons"][0]["mpjpe_both"] < res["horizons"][2]["mpjpe_both"]
    assert PR.score(v[None], clip, 16, PR.horizon_bins(16))["predicted"]["mpjpe_both"] == pytest.approx(0, abs=1e-2)


@pytest.fixture(scope="module")
def evaluator(data, tmp_path_factory):
    """A two-step tiny evaluator of the test corpus (the standard one is made for the standard corpus only)."""
    from handx_jax.evaluation import make_evaluator_config, train_evaluator
    from tests.diffusion_fixtures import ENCODER

    cfg = make_evaluator_config("tiny", ("train.steps=2", "train.batch_size=8", "train.wandb=disabled",
                                         "text.max_len=64", "final_eval=false"), data=str(data), encoder=str(ENCODER))
    return train_evaluator(tmp_path_factory.mktemp("ev") / "E", cfg, log=lambda s: None)


def test_completed_clips_are_scored_by_the_evaluator(data, evaluator, tmp_path):
    """The completed clips' FID and R-Precision through ``--evaluator``: the ground-truth baseline gives the
    evaluator's own Ground Truth row on the same clips (FID 0), holding still a larger FID."""
    from handx_jax.evaluation import evaluate_ground_truth, load_evaluator
    from handx_jax.dataset.format import Dataset
    from handx_jax.metrics import MetricConfig

    got = {}
    for base in ("ground-truth", "last-frame"):
        out = tmp_path / f"{base}.json"
        assert main(["eval", "prediction", "--baseline", base, "--data", str(data), "--observed-frames", "16",
                     "--samples", "2", "--evaluator", str(evaluator), "--json", "--out", str(out)]) == 0
        got[base] = json.loads(out.read_text())["completed"]
    gt = evaluate_ground_truth(load_evaluator(evaluator), Dataset.open(data), MetricConfig(seed=0), cache=False).flat()
    assert got["ground-truth"]["fid"] == pytest.approx(0.0, abs=1e-3)
    for k in ("rprec_top1", "rprec_top3", "mm_dist"):
        assert got["ground-truth"][k] == pytest.approx(gt[k], rel=1e-4)
    assert got["last-frame"]["fid"] > got["ground-truth"]["fid"] + 1e-3
    assert got["ground-truth"]["_meta"]["groups"] == 1  # a baseline's K copies are one group
