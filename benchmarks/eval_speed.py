"""Time to evaluate N generated clips (default 2,000) with R replications (default 20) on this machine.

Prints one JSON object with three passes over the same clips:

- ``cold_seconds_with_compile``: the first pass of the process (XLA compilation, empty reference cache:
  the reference captions and GT motion are embedded and the cache file is written);
- ``seconds_uncached``: warm (compiled), reference cache bypassed: captions through the frozen T5, GT and
  generated motion through the evaluator, metrics;
- ``seconds``: warm, reference embeddings read from the cache, as every evaluation of a sweep after the
  first one against the same evaluator, clips and caption level: only the generated motion is embedded.

The cache lives in a temporary folder (never in the evaluator folder). Each pass also reports
``metrics_parts`` (seconds of R-Precision + MM-Dist, FID with its bootstrap, Diversity, the motion
metrics) and ``cpu_total`` (process CPU seconds, all threads: on a shared machine wall time also counts
the time other processes held the cores); the output names the command, the bootstrap resample count
and the load average at start and end. The default preset matches issue 15 item 4: 2,000 clips (one
generation group, so every ± is a prompt bootstrap of ``--bootstrap`` = 200 resamples), 20 replications.

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/eval_speed.py                       # random-init small evaluator
    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/eval_speed.py --evaluator E --reference DIR   # a trained one

Without ``--evaluator`` the timing uses a randomly initialised evaluator of ``--preset`` (embedding
cost depends on the architecture, not on the weights), the tiny T5 test fixture as text encoder, and
synthetic motion/captions; with one, the first N clips of the reference dataset are used.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/_peak.py, also when loaded by path
from _peak import emit  # noqa: E402

from handx_jax.evaluation import (TextPolicy, TrainedEvaluator, _init_params,  # noqa: E402
                                  evaluate_embeddings_and_motion, model_config, motion_features,
                                  reference_embeddings)
from handx_jax.metrics import MetricConfig  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def synthetic(n: int, seed: int = 0):
    """Smooth random two-hand motion around a rest pose and toy captions (shapes and scales realistic)."""
    from handx_jax.text.toy import toy_texts

    rng = np.random.default_rng(seed)
    base = rng.normal(scale=0.05, size=(1, 1, 2, 21, 3)).astype(np.float32)
    base[..., 0, :, 0] -= 0.15
    walk = np.cumsum(rng.normal(scale=0.002, size=(n, 60, 2, 21, 3)), axis=1).astype(np.float32)
    texts = toy_texts(n, seed)
    return base + walk, [t["left"][0] for t in texts], [t["right"][0] for t in texts], \
        [t["interaction"][0] for t in texts]


def input_stats(preset: str, text_dim: int, gt_NxTx2x21x3: np.ndarray):
    """The preset's evaluator config and normalisation statistics of its own motion input, fitted on
    ``gt`` ("positions": 126 features per frame, "hand_frames": 307)."""
    from handx_jax.representation import EVALUATOR_INPUTS, NormStats

    cfg = model_config(preset, text_dim)
    to_input, dim = EVALUATOR_INPUTS[cfg.motion_input]
    feats = to_input(gt_NxTx2x21x3).reshape(-1, dim)
    return cfg, NormStats(feats.mean(0), feats.std(0) + 1e-3)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--clips", type=int, default=2000)
    p.add_argument("--groups", type=int, default=1, help="generation groups (clips = prompts × groups)")
    p.add_argument("--replications", type=int, default=20)
    p.add_argument("--evaluator", help="standard, a version such as standard-v7, or an evaluator folder")
    p.add_argument("--reference")
    p.add_argument("--preset", default="small")
    p.add_argument("--encoder", default=str(ROOT / "tests" / "fixtures" / "t5_tiny_gated"))
    p.add_argument("--bootstrap", type=int, default=MetricConfig.bootstrap, help="prompt resamples for the ±")
    a = p.parse_args(argv)
    N = a.clips // a.groups
    if a.evaluator:
        from handx_jax.dataset.format import Dataset

        from handx_jax.standard.naming import resolve_evaluator

        ev = resolve_evaluator(a.evaluator).load()  # standard, standard-vN or an evaluator folder
        ds = Dataset.open(a.reference or ev.meta["dataset"]["path"])
        clips = np.arange(min(N, len(ds)))
        N = len(clips)
        gt = np.asarray(ds.motion[clips], np.float32)
        prompts = ev.captions(ds, clips)
        source = {"evaluator": a.evaluator, "reference": str(ds.root)}
        provenance = {"dataset": ds.fingerprint, "eval_level": ev.policy.eval_level, "clips": f"first {N}"}
    else:
        from handx_jax.text.hf import load_hf_t5_encoder

        enc = load_hf_t5_encoder(a.encoder)
        gt, *prompts = synthetic(N)
        cfg, stats = input_stats(a.preset, enc.cfg.d_model, gt)
        ev = TrainedEvaluator(cfg=cfg, params=_init_params(cfg, 256, jax.random.PRNGKey(0)), stats=stats,
                              encoder=enc, policy=TextPolicy(max_len=256))
        source = {"evaluator": f"random-init {a.preset}", "encoder": a.encoder}
        provenance = {"dataset": "synthetic", "clips": f"first {N}"}
    rng = np.random.default_rng(1)
    gen = gt[None] + rng.normal(scale=0.005, size=(a.groups,) + gt.shape).astype(np.float32)
    mcfg = MetricConfig(replications=a.replications, bootstrap=a.bootstrap)

    def run(cache):
        c0, t0 = time.process_time(), time.perf_counter()
        ref = reference_embeddings(ev, prompts, gt, provenance=provenance, cache=cache)
        t1 = time.perf_counter()
        res = evaluate_embeddings_and_motion(ev, ref.text_NxD, gen, gt, mcfg, gt_NxD=ref.motion_NxD)
        s = res.meta["seconds"]
        text, motion = ref.seconds["text"], ref.seconds["motion"] + s["motion_embedding"]
        return {"text_embedding": text, "motion_embedding": motion, "embedding_total": t1 - t0 + s["motion_embedding"],
                "metrics": s["metrics"], "metrics_parts": s["metrics_parts"],
                "total": t1 - t0 + s["motion_embedding"] + s["metrics"],
                # CPU seconds of the process (all threads): on a shared machine wall time also counts the
                # time other processes held the cores, this does not
                "cpu_total": time.process_time() - c0, "reference_cache": ref.status}, res

    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory() as cache_dir:
        cold, _ = run(cache_dir)  # compiles; empty cache: embeds the reference and writes it
        uncached, _ = run(False)
        warm, res = run(cache_dir)
    t0 = time.perf_counter()
    for g in range(a.groups):  # the host-side part of motion embedding, alone (profile)
        motion_features(gen[g], ev.stats, ev.cfg.motion_input)
    features = time.perf_counter() - t0
    out = {
        "command": " ".join(["benchmarks/eval_speed.py", *(argv if argv is not None else sys.argv[1:])]),
        "clips": int(N * a.groups), "prompts": int(N), "groups": a.groups, "replications": a.replications,
        "bootstrap": a.bootstrap,
        "seconds": warm, "seconds_uncached": uncached, "cold_seconds_with_compile": cold,
        "generated_motion_features_seconds": features,
        "evaluator": {"latent": ev.cfg.latent, "layers": ev.cfg.layers, "ff": ev.cfg.ff,
                      "text_max_len": ev.policy.max_len, "encoder_d_model": ev.encoder.cfg.d_model, **source},
        "rprec_top1": res.metrics["rprec_top1"][0],
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "backend": jax.default_backend(),
                    "loadavg_start": load_start, "loadavg_end": os.getloadavg()},
    }
    emit(out, indent=1)
    return out


if __name__ == "__main__":
    main()
