"""Shared tiny fixtures for the diffusion-family tests: a 32-clip corpus with a per-field text cache
(the gated tiny T5 fixture) and a few-step tiny run."""

from __future__ import annotations

from pathlib import Path

ENCODER = Path(__file__).parent / "fixtures" / "t5_tiny_gated"


def make_dataset(root: Path) -> Path:
    from handx_jax.data.build import BuildConfig, build_corpus
    from handx_jax.text.cache import build_cache

    data = build_corpus(root / "ds", BuildConfig(clips=32, seed=3, workers=1, val_fraction=0.2, test_fraction=0.2),
                        progress=False)
    build_cache(data, ENCODER, log=lambda s: None)
    return data


def tiny_config(data: Path, *overrides: str):
    from handx_jax.families.diffusion import make_config

    base = ("train.steps=6", "train.batch_size=8", "train.log_every=2", "train.ckpt_every=3", "train.wandb=disabled",
            "train.optim.warmup_steps=0", "train.optim.lr=1e-3")
    return make_config("tiny", base + overrides, data=str(data), encoder=str(ENCODER))
