"""The official HandX models' outputs, in their own layouts, from imported weights: the parity oracles'
interface (tests/test_interop_official.py compares them with the official PyTorch code's outputs).

- :func:`denoise`: the diffusion model's eval-mode forward (x0 prediction) on the official layout
  ``(B, 42, 4, T)``, from a run folder written by ``handx import handx-diffusion``.
- :func:`embed`: the official evaluator's text and motion μ-embeddings of raw joint positions, from an
  evaluator folder written by ``handx import handx-evaluator``, with the official preprocessing.
"""

from __future__ import annotations

import os
from functools import lru_cache
from typing import Sequence

import numpy as np


def _run(run):
    if isinstance(run, (str, os.PathLike)):
        from handx_jax.families import get_family

        return get_family("diffusion").load(run)
    return run


@lru_cache(maxsize=8)
def _forward(model):
    """The model's eval-mode forward, jitted once per model (run eagerly it costs seconds per call)."""
    import jax

    return jax.jit(lambda params, *args: model.apply(params, *args, deterministic=True))


def denoise(run, x_BxJxFxT, t_B, left: Sequence[str], right: Sequence[str], interaction: Sequence[str]) -> np.ndarray:
    """x̂0 ``(B, 42, 4, T)`` of the denoiser for noisy ``x_BxJxFxT`` at integer timesteps ``t_B`` with the three
    texts of each sample: the official model's ``forward(x, t, y)`` in eval mode (no text dropped, every
    frame valid). ``run``: a run folder or a loaded diffusion run."""
    import jax.numpy as jnp

    run = _run(run)
    x = np.asarray(x_BxJxFxT, np.float32)
    B = x.shape[0]
    texts = [list(left), list(right), list(interaction)]
    if any(len(t) != B for t in texts):
        raise ValueError(f"need {B} texts per field, got {[len(t) for t in texts]}")
    hs, ms = zip(*(run.encode(t) for t in texts))
    x_BxTxJxF = jnp.asarray(np.transpose(x, (0, 3, 1, 2)))
    out = _forward(run.model)(run.params, x_BxTxJxF, jnp.asarray(t_B, jnp.int32), jnp.asarray(np.stack(hs)),
                              jnp.asarray(np.stack(ms)), jnp.zeros((B, 3), bool))
    return np.transpose(np.asarray(out), (0, 2, 3, 1))


def embed(ev, motions_Nx60x2x21x3, left: Sequence[str], right: Sequence[str], interaction: Sequence[str]
          ) -> tuple[np.ndarray, np.ndarray]:
    """(text_mu, motion_mu), each ``(N, latent)``: the official evaluator's μ-embeddings of the captions
    built from the three texts and of the motions (joint positions in metres), preprocessed as
    ``run_evaluation.py`` does (reference §5.3, §5.5). ``ev``: an evaluator folder or a loaded one."""
    from handx_jax.interop import official_evaluator as oe

    ev = oe.load(ev) if isinstance(ev, (str, os.PathLike)) else ev
    captions = [oe.caption(*f) for f in zip(left, right, interaction)]
    return ev.embed_joined(captions), ev.embed_motion(motions_Nx60x2x21x3)
