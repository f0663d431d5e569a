"""The run folder's plain files: ``config.json`` (with the software versions that ran it) and
``metrics.jsonl`` (one fsynced JSON line per log), mirrored to wandb (offline by default; WANDB_MODE
overrides), written by process 0 only. ``handx_jax.train`` logs through :class:`RunLogger`. How an older
config.json reads today, for the resume check: :func:`trainable_renamed`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Callable

import jax

from handx_jax.infra.atomic import append_jsonl, atomic_write_json
from handx_jax.infra.readers import read_jsonl


def _versions_record(config_path: Path) -> dict:
    """config.json's ``versions`` (handx_jax.infra.provenance: python, jax, jaxlib, flax, optax, orbax, numpy):
    those that started the run. A resume under other versions keeps them and adds ``versions_at_resume``,
    so the record never claims a single stack for a run trained on two."""
    from handx_jax.infra.provenance import versions

    now = versions()
    try:
        old = json.loads(config_path.read_text()).get("versions") if config_path.exists() else None
    except (json.JSONDecodeError, AttributeError):
        old = None
    if not isinstance(old, dict) or old == now:
        return {"versions": now}
    return {"versions": old, "versions_at_resume": now}


class RunLogger:
    """config.json + metrics.jsonl in the run folder, mirrored to wandb (process 0 only)."""

    def __init__(self, run_dir: Path, config: dict, mode: str = "offline"):
        self.run_dir = Path(run_dir)
        self.enabled = jax.process_index() == 0
        self._wandb = None
        self.metrics_path = self.run_dir / "metrics.jsonl"
        if not self.enabled:
            return
        self.run_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_json(self.run_dir / "config.json", {**config, **_versions_record(self.run_dir / "config.json")})
        mode = os.environ.get("WANDB_MODE", mode)
        if mode != "disabled":
            try:
                import wandb

                os.environ.setdefault("WANDB_DIR", str(self.run_dir))
                os.environ.setdefault("WANDB_CACHE_DIR", str(self.run_dir / ".wandb-cache"))
                self._wandb = wandb.init(project=config.get("wandb_project", "handx-jax"), dir=str(self.run_dir),
                                         config=config, mode=mode, id=self.run_dir.name.replace("/", "-"),
                                         resume="allow", reinit=True)
            except Exception as e:  # wandb is a mirror: never let it kill a run
                print(f"[wandb disabled: {e}]")

    def log(self, row: dict) -> None:
        if not self.enabled:
            return
        append_jsonl(self.metrics_path, row)
        if self._wandb is not None:
            self._wandb.log({k: v for k, v in row.items() if k != "step"}, step=int(row["step"]))

    def truncate_after(self, step: int) -> None:
        """On resume, drop the metric rows that the run logs again from ``step``, the checkpoint it restarts
        from: those after it, and with no checkpoint yet (``step`` 0) every row, the step-0 evaluation
        included (a fresh start logs it again; kept, a run killed before its first checkpoint held that row
        twice). Rows of a restored step were written before its checkpoint and are kept."""
        if self.enabled and self.metrics_path.exists():
            rows = [r for r in read_jsonl(self.metrics_path, strict=False)
                    if step > 0 and isinstance(r, dict) and r.get("step", 0) <= step]
            from handx_jax.infra.atomic import atomic_write_jsonl

            atomic_write_jsonl(self.metrics_path, rows)

    def close(self) -> None:
        if self._wandb is not None:
            self._wandb.finish()




def read_config(run_dir: str | os.PathLike) -> dict:
    from handx_jax.infra.readers import read_json

    return read_json(Path(run_dir) / "config.json", expect=dict)


def trainable_renamed(old_family: str, trainable: str) -> Callable[[dict], dict]:
    """How a run folder of a trainable (``families.TRAINABLES``: the evaluator, T5 pretraining) written before
    issue 42 reads today: it named what trained it as a model family (``"family": old_family``), where a
    run of a trainable now says ``"trainable": NAME`` and leaves ``family`` to the registry's families. A
    ``train.TrainSpec``'s ``upgrade_config``; the resumed run rewrites config.json with the new key."""

    def upgrade(old: dict) -> dict:
        if old.get("family") != old_family or "trainable" in old:
            return old
        return {**{k: v for k, v in old.items() if k != "family"}, "trainable": trainable}

    return upgrade
