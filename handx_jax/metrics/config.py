"""``MetricConfig``: the block size, replications, bootstrap draws, seed and thresholds every metric of
the evaluation reads (reference §5.4; paper §6, E.2)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MetricConfig:
    rprec_block: int = 32  # 32 in Table 2; 16 in Table B / Fig. 4
    top_k: int = 3
    diversity_pairs: int = 300
    multimodality_pairs: int = 20
    replications: int = 20  # re-blockings / re-drawn pairs averaged into each point value
    bootstrap: int = 200  # prompt resamples for the "bootstrap_prompts" intervals
    seed: int = 0
    intra_contact_m: float = 0.020  # thumb tip vs other tips (reference §5.4)
    inter_contact_m: float = 0.025  # tips vs the other hand's palm cloud
    palm_points: int = 100
    # MPJPE root: "none" = positions in the shared clip frame (paper reading); "left_wrist"
    # reproduces the official script, which ends up relative to each frame's left wrist (§9.17).
    mpjpe_root: str = "none"
    # APD over the first K generation groups of each prompt (G-HTT: K = 20); 0 = all groups.
    apd_samples: int = 0
    pen_threshold_m: float = 0.01  # BimArt's "Pen 1cm"
