"""The paper's evaluation metrics, jitted and batched (reference §5.4; paper §6, E.2).

Embedding metrics take evaluator embeddings (text ``T_NxD``, motion ``M_NxD``); motion metrics take
joints ``(N, 60, 2, 21, 3)`` in metres. Every randomised quantity (block order, diversity pairs,
MultiModality groups, palm samples) is drawn from an explicit seed: the reference's unseeded draws
(§9.17) are not ported. Beside the paper's metrics, the neighbouring hand papers' (issue 33): G-HTT's
MPJPE-RA / MPJPE-PA and APD, BimArt's inter-hand penetration ("Pen 1cm") and contact feasibility.

Every ± is a 95% interval over values independent of each other; ``intervals.py`` says which and why.

One kind of metric per module:

    config.py       ``MetricConfig``
    embedding.py    R-Precision, MM-Dist, FID, Diversity, MultiModality (on evaluator embeddings)
    motion.py       MPJPE, acceleration, jitter, contact labels and their P/R/F1 (on joints)
    hand_papers.py  G-HTT's MPJPE-RA / -PA and APD, BimArt's inter-hand penetration (geometry: hand_surface.py)
    contact.py      contact feasibility: the contacts a clip's captions name, realised or not
    objects.py      BimArt's hand -> object metrics (obj_pen_1cm, Con, Art, Mul, Accel, CM, part F1); import the module
    intervals.py    confidence intervals: over generation groups, or a bootstrap over prompts
    replicate.py    the evaluation's rows: every metric over G groups as (point value, ± half-width)
    chunking.py     the chunked map the per-frame scans share

The names below are the package's public surface (``from handx_jax.metrics import X``).
"""

from handx_jax.metrics.config import MetricConfig
from handx_jax.metrics.contact import (CONTACT_CHANNELS, N_CONTACT_CHANNELS, NamedContacts, contact_channel_distances,
                                       contact_feasibility_counts, contact_thresholds, named_contacts)
from handx_jax.metrics.embedding import (GRAM_CHUNK, diversity, diversity_indices, expected_hit, fid, fid_resampled,
                                         multimodality, pairwise_dist, r_precision, resampled_moments,
                                         resampled_pair_mean)
from handx_jax.metrics.hand_papers import (apd_frames_mm, apd_mm, best_rotation, interhand_penetration,
                                           joint_error_frames_mm, mpjpe_pa_frames_mm, mpjpe_pa_mm, mpjpe_ra_mm,
                                           penetration_stats, procrustes_align)
from handx_jax.metrics.chunking import MOTION_CHUNK
from handx_jax.metrics.intervals import (BETWEEN_GROUPS, CI_BOOTSTRAP, CI_GROUPS, bootstrap_half_width,
                                         bootstrap_indices, ci_method, mean_ci, prompt_mean_ci)
from handx_jax.metrics.motion import (CONTACT_CHUNK, acceleration_jitter, contact_labels, contact_prf, mpjpe_mm,
                                      palm_barycentric)
from handx_jax.metrics.replicate import replicate_embedding_metrics, replicate_motion_metrics

__all__ = [
    "MetricConfig",
    "CONTACT_CHANNELS", "N_CONTACT_CHANNELS", "NamedContacts", "contact_channel_distances",
    "contact_feasibility_counts", "contact_thresholds", "named_contacts",
    "GRAM_CHUNK", "diversity", "diversity_indices", "expected_hit", "fid", "fid_resampled", "multimodality",
    "pairwise_dist", "r_precision", "resampled_moments", "resampled_pair_mean",
    "apd_frames_mm", "apd_mm", "best_rotation", "interhand_penetration", "joint_error_frames_mm",
    "mpjpe_pa_frames_mm", "mpjpe_pa_mm", "mpjpe_ra_mm", "penetration_stats", "procrustes_align",
    "MOTION_CHUNK",
    "BETWEEN_GROUPS", "CI_BOOTSTRAP", "CI_GROUPS", "bootstrap_half_width", "bootstrap_indices", "ci_method", "mean_ci",
    "prompt_mean_ci",
    "CONTACT_CHUNK", "acceleration_jitter", "contact_labels", "contact_prf", "mpjpe_mm", "palm_barycentric",
    "replicate_embedding_metrics", "replicate_motion_metrics",
]
