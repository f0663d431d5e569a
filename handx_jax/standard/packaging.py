"""(Maintainers) packaging the assets: copy the encoder and evaluator trained on the standard corpus, score
the Ground Truth rows, write the manifest and the card; put a validity report's figures on a card."""

from __future__ import annotations

import dataclasses
import os
import platform
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from handx_jax.infra.atomic import atomic_write_json, atomic_write_text
from handx_jax.infra.checksums import sha256_file, write_checksum
from handx_jax.infra.errors import DataError
from handx_jax.standard.assets import (CARD_JSON, CARD_MD, ENCODER_DIR, EVALUATOR_DIR, MANIFEST, VERSION, asset_files,
                                       assets_folder, verify_assets)
from handx_jax.standard.card import card_markdown, validity_summary
from handx_jax.standard.evaluator import load
from handx_jax.standard.identity import test_manifest
from handx_jax.standard.recipe import Recipe, build_options, code_recipe, recipe_of


def _copy_folder(src: Path, dst: Path, names: Sequence[str]) -> None:
    dst.mkdir(parents=True, exist_ok=True)
    for n in names:
        if not (src / n).exists():
            raise DataError(f"missing {n}", path=src)
        shutil.copy2(src / n, dst / n)


def package(data: str | os.PathLike, encoder: str | os.PathLike, evaluator: str | os.PathLike,
            out: str | os.PathLike | None = None, *, training: Mapping[str, Any] | None = None,
            replications: int = 20, blocks: Sequence[int] = (32, 16), recipe: Recipe | None = None,
            validity: Mapping[str, Any] | None = None, version: int | None = None, log=print) -> Path:
    """Copy the encoder and evaluator trained on the standard corpus ``data`` into ``out``, score the
    Ground Truth rows (blocks 32 and 16) on the full test split, and write the manifest and the card.

    ``recipe`` and ``version`` (default: this code's, ``code_recipe()`` and ``VERSION``) package the next
    standard evaluator before the code names it the standard one: evaluator v8 on corpus v5
    (``scripts/build_standard_v8.sh``), whose card then says version 8 and recipe v5."""
    from handx_jax.dataset.format import Dataset
    from handx_jax.evaluation import EVAL_FILE, META_FILE, PARAMS_FILE, STATS_FILE, evaluate_ground_truth, \
        read_meta
    from handx_jax.metrics import MetricConfig

    ds = Dataset.open(data)
    rec, opts = recipe_of(ds)
    want = recipe or code_recipe()
    if rec != want or opts != build_options(want):
        raise DataError(f"{data} is not this code's standard corpus: recipe {rec}, expected {want}"
                        + ("" if opts == build_options(want) else " (build options differ)"), path=data)
    meta = read_meta(evaluator)
    if meta["dataset"]["fingerprint"] != ds.fingerprint:
        raise DataError(f"the evaluator was trained on dataset {meta['dataset']['fingerprint']}, not {data} "
                        f"({ds.fingerprint})", path=evaluator)
    out = assets_folder(out)
    tmp = out.with_name(f".{out.name}.packaging")
    if tmp.exists():
        shutil.rmtree(tmp)
    enc_src = Path(encoder)
    _copy_folder(enc_src, tmp / ENCODER_DIR, sorted(p.name for p in enc_src.iterdir() if p.is_file()))
    _copy_folder(Path(evaluator), tmp / EVALUATOR_DIR, [PARAMS_FILE, STATS_FILE])
    # evaluator.json: paths made relative to the package (they pointed into the maintainer's machine).
    meta = dict(meta)
    version = VERSION if version is None else int(version)
    meta["dataset"] = {**meta["dataset"], "path": f"standard corpus v{version} (handx standard corpus)"}
    meta["encoder"] = {**meta["encoder"], "path": ENCODER_DIR}
    atomic_write_json(tmp / EVALUATOR_DIR / META_FILE, meta)
    man = test_manifest(ds)
    np.savez_compressed(tmp / MANIFEST, **man)
    from handx_jax.dataset.format import dataset_record

    card = {"version": version, "recipe": dataclasses.asdict(rec), "recipe_options": opts,
            "corpus": {"record": dataset_record(ds), "fingerprint": ds.fingerprint, "clips": len(ds), "split_sizes": ds.meta["split_sizes"],
                       "build_seconds": ds.report.get("seconds"), "test_clips": len(man["ids"])},
            "evaluator": {"preset": meta["preset"], "params": meta["params"], "config": meta["evaluator_config"],
                          "text": meta["text"], "training": meta["training"],
                          "encoder_fingerprint": meta["encoder"]["fingerprint"],
                          "tokenizer_fingerprint": meta["encoder"]["tokenizer_fingerprint"]},
            "training_run": dict(training or {}),
            "validity": validity_summary(validity) if validity else None,
            "packaged": {"machine": f"{platform.machine()}, {os.cpu_count()} CPU cores, "
                                    f"{_accelerator() or 'no accelerator'}",
                         "python": sys.version.split()[0], "numpy": np.__version__, "jax": _jax_version(),
                         "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime())},
            "sha256": {}}
    card["sha256"] = {rel: sha256_file(tmp / rel) for rel in asset_files(tmp)}
    atomic_write_json(tmp / CARD_JSON, card)
    write_checksum(tmp / CARD_JSON)
    # Score the GT rows with the packaged copy, through the same check users go through.
    ev = load(tmp)
    rows = {}
    for block in blocks:
        t0 = time.perf_counter()
        res = evaluate_ground_truth(ev, ds, MetricConfig(rprec_block=block, replications=replications), cache=False)
        rows[str(block)] = {**res.flat(), "prompts": res.meta["prompts"], "replications": replications,
                            "ci_method": res.meta.get("ci_method", {}).get("rprec_top1"),
                            "bootstrap": res.meta.get("bootstrap"), "seconds": round(time.perf_counter() - t0, 1)}
        log(f"GT block {block}: top-1 {rows[str(block)]['rprec_top1']:.3f} top-3 {rows[str(block)]['rprec_top3']:.3f}")
    card["ground_truth"] = rows
    atomic_write_json(tmp / CARD_JSON, card)
    atomic_write_json(tmp / EVALUATOR_DIR / EVAL_FILE,
                      {**rows[str(blocks[0])], "_meta": {"split": "test", "block": blocks[0]}})
    card["sha256"] = {rel: sha256_file(tmp / rel) for rel in asset_files(tmp)}
    atomic_write_json(tmp / CARD_JSON, card)
    write_checksum(tmp / CARD_JSON)
    atomic_write_text(tmp / CARD_MD, card_markdown(card))
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)
    return out


def _accelerator() -> str | None:
    """The accelerator JAX runs on (e.g. 'NVIDIA H200'), or None on CPU."""
    try:
        import jax

        if jax.default_backend() == "cpu":
            return None
        return str(jax.devices()[0].device_kind)
    except Exception:  # noqa: BLE001 - packaging must not fail on a missing backend
        return None


def _jax_version() -> str:
    try:
        import jax

        return jax.__version__
    except Exception:  # noqa: BLE001
        return "?"


def add_validity(assets: Path, report: Mapping[str, Any]) -> dict:
    """Put a validity report's figures (``handx standard validity`` with this very evaluator, which
    accepts prefixes of its corpus only once packaged) on an assets folder's card: card.json, its
    checksum and CARD.md. The other files, and so their checksums, are untouched."""
    assets = Path(assets)
    card = verify_assets(assets)
    card["validity"] = validity_summary(report)
    atomic_write_json(assets / CARD_JSON, card)
    write_checksum(assets / CARD_JSON)
    atomic_write_text(assets / CARD_MD, card_markdown(card))
    return card
