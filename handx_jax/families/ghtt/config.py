"""The G-HTT run configuration (the A run over a trained P run): data, loss weights, sampling, presets.

One concern: what a G-HTT run is configured with (``make_config``); the family module re-exports it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence


from handx_jax.config import ConfigError, apply_overrides, from_dict, get_preset
from handx_jax.families import entry, run_config
from handx_jax.families.ghtt import pose as PP
from handx_jax.models import ghtt as G
from handx_jax.train import TrainConfig

FAMILY = "ghtt"
PRESETS = G.PRESETS
TASKS = entry(FAMILY).tasks  # declared in the registry (families.FAMILIES)
PATHS = ("action", "pose")  # §3.2's P.b (P + A) and P.a (P alone)


@dataclass(frozen=True)
class DataConfig:
    path: str = ""
    encoder: str = ""
    pose: str = ""  # the trained P run (``handx train ghtt-pose``)
    fraction: float = 1.0
    levels: tuple[int, ...] = ()  # caption levels of the training items (empty: all)
    text_max_len: int = 128  # the joined text cache's
    cache_dtype: str = "float16"


@dataclass(frozen=True)
class LossConfig:
    """§3.3's weights λ4 = 1, λ5 = 0.1, λ6 = 1e-5; ``m_noise``: the std of App. B.3's noise on the observed
    latents, relative to their RMS (the paper's absolute 1.5 is in the scale of its own latents)."""

    mid: float = 1.0
    action: float = 0.1
    kl: float = 1e-5
    m_noise: float = 0.25


@dataclass(frozen=True)
class SampleConfig:
    """Prediction defaults (``handx generate`` flags override them): §4.2 samples N(μ, 5Σ)."""

    path: str = "action"
    sigma_scale: float = 5.0
    # Each predicted span's hand poses p start from the frame before it (the last observed frame, then each
    # span's last), the offset blended out linearly over the span: the paper's rectification of E^P's
    # trajectory (App. B.2, Eq. 10: linear interpolation with weights (t − i)/(t − 1)) applied where a
    # decoded span meets the frames before it. D^P decodes a span from the latent alone, which keeps the
    # gist of the poses, not the exact fingers: unrectified, the first predicted frame of a 200-step tiny
    # run was 21.7 mm (MPJPE-RA) from the truth where holding the last frame is 3.4 mm off.
    rectify: bool = True


TRAIN_PRESETS = {name: dataclasses.replace(PP.TRAIN_PRESETS[name],
                                           steps=200 * 3600 * 5 // 256 if name == "paper" else 1000)
                 for name in PRESETS}  # §3.3: A for 200 epochs


@dataclass(frozen=True)
class GHTTRunConfig:
    preset: str = "tiny"
    model: G.GHTTConfig = PRESETS["tiny"]
    train: TrainConfig = TRAIN_PRESETS["tiny"]
    data: DataConfig = field(default_factory=DataConfig)
    loss: LossConfig = LossConfig()
    sample: SampleConfig = SampleConfig()

    def validate(self) -> None:
        b = self.model.action
        if b.dim % b.heads:
            raise ConfigError(f"model.action.dim {b.dim} must be a multiple of model.action.heads {b.heads}")
        if self.sample.path not in PATHS:
            raise ConfigError(f"sample.path must be one of {', '.join(PATHS)}, got {self.sample.path!r}")
        if not self.sample.sigma_scale >= 0:
            raise ConfigError(f"sample.sigma_scale must be >= 0, got {self.sample.sigma_scale}")
        if not 0 < self.data.fraction <= 1:
            raise ConfigError(f"data.fraction must be in (0, 1], got {self.data.fraction}")


Config = GHTTRunConfig


def make_config(preset: str = "tiny", overrides: Sequence[str] = (), *, data: str = "", encoder: str = "",
                pose: str = "") -> GHTTRunConfig:
    """A run config of a named size; P's part (``model.pose``, ``model.span``) is the P run's when given."""
    model = get_preset(PRESETS, preset, "G-HTT preset")
    if pose:
        pm = from_dict(G.GHTTConfig, run_config(pose, PP.FAMILY)["model"])
        model = dataclasses.replace(model, pose=pm.pose, span=pm.span)
    cfg = GHTTRunConfig(preset=preset, model=model, train=TRAIN_PRESETS[preset],
                        data=DataConfig(*(str(Path(p).absolute()) if p else "" for p in (data, encoder, pose))))
    return apply_overrides(cfg, overrides)
