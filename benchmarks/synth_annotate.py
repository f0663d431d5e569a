"""Throughput of corpus building: synthesis, clip extraction + filter, annotation, captions.

Prints JSON. Usage: python benchmarks/synth_annotate.py [--clips N] [--workers W]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/_peak.py, also when loaded by path
from _peak import emit  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--clips", type=int, default=2000)
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()

    from handx_jax import skeleton as sk
    from handx_jax.dataset.build import BuildConfig, build_corpus, process_chunk
    from handx_jax.annotation.caption import TemplateCaptioner
    from handx_jax.dataset.clips import extract_clips
    from handx_jax.annotation.events import annotate
    from handx_jax.synthesis.bimanual import synth_chunk

    cfg = BuildConfig(clips=a.clips, seed=a.seed, workers=a.workers)
    # Stage timings on one core (one chunk, warm).
    process_chunk(cfg, 0)
    t = time.perf_counter(); ch = synth_chunk(a.seed, 1, cfg.synth); t_synth = time.perf_counter() - t
    t = time.perf_counter()
    clips = [extract_clips(sk.canonicalize(s, ref_frame=int(np.argmax(np.isfinite(s).reshape(len(s), -1).all(1)))))[0]
             for s in ch.joints]
    clips = np.concatenate(clips)
    t_clip = time.perf_counter() - t
    t = time.perf_counter(); recs = annotate(clips); t_ann = time.perf_counter() - t
    cap = TemplateCaptioner()
    t = time.perf_counter(); [cap.caption(r, seed=i) for i, r in enumerate(recs)]; t_cap = time.perf_counter() - t
    n_seg = ch.joints.shape[0] * cfg.synth.segments_per_sequence
    stages = {
        "synth_segments_per_s": round(n_seg / t_synth, 1),
        "extract_filter_clips_per_s": round(len(clips) / t_clip, 1),
        "annotate_clips_per_s": round(len(clips) / t_ann, 1),
        "caption_clips_per_s": round(len(clips) / t_cap, 1),
    }
    with tempfile.TemporaryDirectory() as d:
        t = time.perf_counter()
        build_corpus(os.path.join(d, "ds"), cfg, progress=False)
        total = time.perf_counter() - t
    emit({
        "benchmark": "synth_annotate",
        "clips": a.clips,
        "workers": cfg.workers or os.cpu_count(),
        "cpu_count": os.cpu_count(),
        "end_to_end_seconds": round(total, 2),
        "end_to_end_clips_per_s": round(a.clips / total, 1),
        "projected_100k_minutes": round(100_000 / (a.clips / total) / 60, 1),
        "single_core_stages": stages,
    })


if __name__ == "__main__":
    main()
