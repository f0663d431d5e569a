"""The run-folder contract: what a training run folder holds, and the results row read from it.

The training loop writes, and :func:`row_from_run_dir` reads, a folder holding:

``config.json`` (required)
    A JSON object: the run's full configuration. Schema columns are looked up by name at the top
    level, then in the sub-objects ``"model"`` and ``"data"`` (so a config composed from parts
    works); the same key with two different values is an error. Keys that are not schema columns
    (learning rate, seed, ...) are ignored: this is the training config, not a results row.
    ``family`` is required, or ``trainable`` naming a row kind (``ROW_KINDS``: the evaluator's runs).
    ``run_id`` defaults to the folder name.
``metrics.jsonl`` (required)
    One JSON object per logged step, each with an integer ``"step"``; any other keys. The row takes
    ``steps``, ``samples_seen`` and ``train_flops`` from the last line (highest step) that has
    them; ``params``, ``params_non_embedding``, ``flops_per_sample`` and
    ``text_flops_per_sample`` may also be logged here (e.g. at init) when config.json lacks them.
    ``train_flops`` is the *cumulative* training compute. If no line logs it, it is estimated as
    ``3 * flops_per_sample * samples_seen`` (forward + backward of the trainable model; the frozen
    text encoder's outputs are cached and cost no training compute). A torn last line (a run killed
    mid-write) is skipped.
``eval.json`` (optional)
    A JSON object mapping metric names (:data:`METRICS`) to ``{"mean": x, "ci": y}`` (``ci``
    optional), to ``[mean, ci]`` (what ``json.dump`` makes of ``handx_jax.metrics.mean_ci``'s
    tuple), or to a plain number. ``<name>_ci`` keys are also accepted. Keys starting with ``_``
    (e.g. ``"_meta": {"step": 1000, "checkpoint": "..."}``) are ignored; any other key is an error.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

from analysis.schema.columns import METRICS, ROW_KINDS, Row, validate_row
from handx_jax.families import family_axes
from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_json, read_jsonl


# The columns a run folder's config.json gives (beside the registered families' axes: _config_keys).
_CONFIG_KEYS = ("run_id", "family", "label", "layers", "dim", "heads", "ff", "data_fraction",
                "params", "params_non_embedding", "flops_per_sample", "text_flops_per_sample",
                "flops_per_sample_paper", "text_flops_per_sample_paper", "data_sampling", "device_kind", "git_commit")
_LOGGED_LAST = ("steps", "samples_seen", "train_flops")
_LOGGED_STATIC = ("params", "params_non_embedding", "flops_per_sample", "text_flops_per_sample",
                  "flops_per_sample_paper", "text_flops_per_sample_paper")


def _read_json_object(path: Path) -> dict[str, Any]:
    return read_json(path, expect=dict)  # the project's one reader: damaged or not an object, one line naming it


def _config_keys() -> tuple[str, ...]:
    """The config.json keys a row takes: the shared ones and each registered family's axes (``Family.axes``)."""
    return (*_CONFIG_KEYS, *family_axes())


def _config_values(config: Mapping[str, Any], path: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    scopes = [("", config)]
    for sub in ("model", "data"):
        if isinstance(config.get(sub), Mapping):
            scopes.append((f"{sub}.", config[sub]))
    for key in _config_keys():
        found = [(prefix, scope[key]) for prefix, scope in scopes if scope.get(key) is not None]
        if not found:
            continue
        values = {json.dumps(v, sort_keys=True) for _, v in found}
        if len(values) > 1:
            where = ", ".join(f"{p}{key}={v!r}" for p, v in found)
            raise DataError(f"conflicting values: {where}", path=path, field=key)
        out[key] = found[0][1]
    return out


def _eval_values(ev: Mapping[str, Any], path: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, val in ev.items():
        if key.startswith("_"):
            continue
        base = key[:-3] if key.endswith("_ci") else key
        if base not in METRICS:
            raise DataError(f"unknown metric; known metrics: {', '.join(METRICS)}", path=path, field=key)
        if key.endswith("_ci"):
            out[key] = val
        elif isinstance(val, (list, tuple)):
            if len(val) != 2:
                raise DataError("expected [mean, ci]", path=path, field=key)
            out[key], out[f"{key}_ci"] = val
        elif isinstance(val, Mapping):
            extra = set(val) - {"mean", "ci"}
            if "mean" not in val or extra:
                raise DataError('expected {"mean": x, "ci": y} or a number', path=path, field=key)
            out[key] = val["mean"]
            if val.get("ci") is not None:
                out[f"{key}_ci"] = val["ci"]
        else:
            out[key] = val
    return out


def _find_key(obj: Any, key: str) -> Any:
    """The first value of ``key`` anywhere in nested dicts (eval.json's ``_meta``), else None."""
    if isinstance(obj, Mapping):
        if key in obj:
            return obj[key]
        for v in obj.values():
            found = _find_key(v, key)
            if found is not None:
                return found
    return None


def row_from_run_dir(run_dir: str | os.PathLike) -> dict[str, Any]:
    """Turn a training run folder (see the module docstring) into one validated results row."""
    run_dir = Path(run_dir)
    cfg_path, log_path, eval_path = run_dir / "config.json", run_dir / "metrics.jsonl", run_dir / "eval.json"
    if not cfg_path.exists():
        raise DataError("run folder has no config.json", path=run_dir)
    config = _read_json_object(cfg_path)
    values = _config_values(config, cfg_path)
    seed = config.get("train", {}).get("seed") if isinstance(config.get("train"), Mapping) else None
    if isinstance(seed, int) and not isinstance(seed, bool):
        values["seed"] = seed
    values.setdefault("run_id", run_dir.name)
    if "family" not in values and config.get("trainable") in ROW_KINDS:
        # the evaluator's runs name their trainable, not a family (issue 42); their rows are of its kind
        values["family"] = config["trainable"]
    if "family" not in values:
        raise DataError("required key is missing", path=cfg_path, field="family")

    if not log_path.exists():
        raise DataError("run folder has no metrics.jsonl", path=run_dir)
    logged = read_jsonl(log_path, strict=False)
    for i, line in enumerate(logged):
        step = line.get("step") if isinstance(line, dict) else None
        if isinstance(step, bool) or not isinstance(step, int):
            raise DataError(f"line {i + 1} has no integer 'step'", path=log_path, field="step")
    logged = sorted(logged, key=lambda d: d["step"])
    if logged:
        values["steps"] = logged[-1]["step"]
    for key in _LOGGED_LAST[1:]:
        for line in reversed(logged):
            if line.get(key) is not None:
                values[key] = line[key]
                break
    for key in _LOGGED_STATIC:
        if key in values:
            continue
        for line in logged:
            if line.get(key) is not None:
                values[key] = line[key]
                break
    if values.get("train_flops") is None and values.get("flops_per_sample") and values.get("samples_seen"):
        values["train_flops"] = 3.0 * float(values["flops_per_sample"]) * float(values["samples_seen"])

    if eval_path.exists():
        ev = _read_json_object(eval_path)
        values.update(_eval_values(ev, eval_path))
        block = _find_key(ev.get("_meta"), "rprec_block")
        if isinstance(block, int) and not isinstance(block, bool):
            values["rprec_block"] = block
        meta = ev.get("_meta") if isinstance(ev.get("_meta"), dict) else {}
        if isinstance(meta.get("evaluator_id"), str):
            values["evaluator_id"] = meta["evaluator_id"]
            values["evaluator"] = meta.get("evaluator_name") or meta["evaluator_id"]
    return Row(validate_row(values, path=run_dir, row=values["run_id"]), source=f"run folder {run_dir}",
               cells=values, file=os.fspath(run_dir))
