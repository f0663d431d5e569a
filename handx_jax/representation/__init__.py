"""Motion representations: wrist frames, the rotation scalar, diffusion (T,42,4), AR 288-d, evaluator 126-d.

Everything here is NumPy, pure, and vectorised over any leading batch dimensions. Joints are laid out
``(..., 2, 21, 3)`` (hand 0 = left), sequences ``(..., T, 2, 21, 3)``. Geometry is computed in float64;
results come back as float64 for float64 input and float32 otherwise.

References (handx-reference.md):
- §2.1 wrist-anchored local frame, §2.2 rotation scalar (code) and paper App. C (paper), §9.1;
- §1.8 centring and normalisation, §2.3 diffusion layout;
- §2.4 AR 288-d layout and its inverse, §9.2;
- §5.3 evaluator preprocessing.

One concern per module; the layouts live here, not in their families' packages, because the corpus
build's worker processes compute the dataset's statistics with them and must not import JAX:

    geometry.py   wrist frames, local positions, the rotation scalar (§2.1, §2.2, App. C)
    diffusion.py  the diffusion layout (T, 42, 4) and ``DIFFUSION_NORM``
    ar.py         the AR 288-d layout, its exact inverse and ``AR_NORM``
    evaluator.py  the evaluator's inputs (126-d positions, "hand_frames") and ``EVALUATOR_NORM``
    norm.py       ``NormStats``, ``NormPreset`` and the streamed statistics

Which preset a family normalises with is the registry's (``Family.norm`` names ``MODULE:ATTRIBUTE``).
The names below are the package's public surface (``from handx_jax import representation as rep``).
"""

from handx_jax.representation.ar import (AR_DIM, AR_LAYOUT, AR_NORM, ARLayout, ar_to_joints, matrix_to_rotation_6d,
                                         rotation_6d_to_matrix, to_ar)
from handx_jax.representation.diffusion import (DIFFUSION_NORM, DIFFUSION_SHAPE, diffusion_center, diffusion_to_joints,
                                                to_diffusion)
from handx_jax.representation.evaluator import (EVALUATOR_DIM, EVALUATOR_HAND_FRAMES_DIM, EVALUATOR_INPUTS,
                                                EVALUATOR_NORM, to_evaluator, to_evaluator_hand_frames)
from handx_jax.representation.geometry import (CONVENTIONS, DEGENERATE_EPS, Convention, local_positions,
                                               rotation_scalar, wrist_frames)
from handx_jax.representation.norm import (NormPreset, NormStats, compute_norm_stats, compute_preset_stats,
                                           motion_norm_stats, norm_preset, norm_presets, preset_moments,
                                           stats_from_moments)

__all__ = ["AR_DIM", "AR_LAYOUT", "AR_NORM", "ARLayout", "ar_to_joints", "matrix_to_rotation_6d",
           "rotation_6d_to_matrix", "to_ar", "DIFFUSION_NORM", "DIFFUSION_SHAPE", "diffusion_center", "diffusion_to_joints", "to_diffusion",
           "EVALUATOR_DIM", "EVALUATOR_HAND_FRAMES_DIM", "EVALUATOR_INPUTS", "EVALUATOR_NORM", "to_evaluator",
           "to_evaluator_hand_frames", "CONVENTIONS", "DEGENERATE_EPS", "Convention", "local_positions",
           "rotation_scalar", "wrist_frames", "NormPreset", "NormStats", "compute_norm_stats", "compute_preset_stats",
           "motion_norm_stats", "norm_preset", "norm_presets", "preset_moments", "stats_from_moments"]
