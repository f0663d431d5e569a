"""The BimArt motion run's configuration: data (the corpus and the contact run), p_f, sampling, presets.

One concern: what a BimArt run is configured with (``make_config``); the family module re-exports it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from handx_jax.config import ConfigError, apply_overrides, from_dict, get_preset
from handx_jax.families import entry, run_config
from handx_jax.families.bimart import common as C
from handx_jax.families.bimart import contact as CM
from handx_jax.families.bimart import physics as PH
from handx_jax.families.diffusion.guidance import SCHEDULES
from handx_jax.models import bimart as BM
from handx_jax.train import TrainConfig

FAMILY = "bimart"
KIND = "motion"
PRESETS = BM.PRESETS
TASKS = entry(FAMILY).tasks
CONTACTS = ("generated", "ground_truth", "none")  # Ĉ from the contact run; the oracle; no contact condition


@dataclass(frozen=True)
class DataConfig:
    path: str = ""
    contact: str = ""  # the trained bimart-contact run
    fraction: float = 1.0


@dataclass(frozen=True)
class SampleConfig:
    """§3.5: λ_f = 0.5; contact guidance at unit strength; 100 refinement iterations (physics.RefineConfig's
    weights: this corpus's, BimArt's ARCTIC ones an option)."""

    cfg_scale: float = 0.5
    contact: str = "generated"
    guidance: float = 1.0            # s; 0 = no contact guidance
    schedule: str = "constant"       # Eq. 6 as written (guidance.SCHEDULES)
    guide_at: str = "before_cfg"
    refine: bool = True
    refine_cfg: PH.RefineConfig = PH.RefineConfig()


@dataclass(frozen=True)
class MotionRunConfig:
    preset: str = "tiny"
    model: BM.BimArtConfig = PRESETS["tiny"]
    train: TrainConfig = C.CPU_TRAIN
    data: DataConfig = field(default_factory=DataConfig)
    p_drop: float = 0.5  # p_f, §3.5
    sample: SampleConfig = SampleConfig()

    def validate(self) -> None:
        C.check_model(self.model)
        s = self.sample
        if not 0 < self.data.fraction <= 1:
            raise ConfigError(f"data.fraction must be in (0, 1], got {self.data.fraction}")
        if not 0 <= self.p_drop <= 1:
            raise ConfigError(f"p_drop must be in [0, 1], got {self.p_drop}")
        for name, val, allowed in (("contact", s.contact, CONTACTS), ("schedule", s.schedule, SCHEDULES),
                                   ("guide_at", s.guide_at, PH.GUIDE_AT), ("refine_cfg.param", s.refine_cfg.param,
                                                                           PH.PARAMS),
                                   ("refine_cfg.reduce", s.refine_cfg.reduce, PH.REDUCE)):
            if val not in allowed:
                raise ConfigError(f"sample.{name} must be one of {', '.join(allowed)}, got {val!r}")
        if not (s.cfg_scale >= 0 and s.guidance >= 0):
            raise ConfigError("sample.cfg_scale and sample.guidance must be >= 0")


Config = MotionRunConfig


def make_config(preset: str = "tiny", overrides: Sequence[str] = (), *, data: str = "", contact: str = "") -> MotionRunConfig:
    """A run config of a named size; the model's K and sizes shared with the contact run are the contact run's."""
    import dataclasses

    model = get_preset(PRESETS, preset, "BimArt preset")
    if contact:
        cm = from_dict(BM.BimArtConfig, run_config(contact, CM.FAMILY)["model"])
        model = dataclasses.replace(model, k=cm.k, steps=cm.steps, frames=cm.frames)
    cfg = MotionRunConfig(preset=preset, model=model, train=C.TRAIN_PRESETS[preset],
                          data=DataConfig(*(str(Path(p).absolute()) if p else "" for p in (data, contact))))
    return apply_overrides(cfg, overrides)
