"""Scoring generated motion (paper Table 2 metrics): alignment to the reference prompts, the Ground
Truth row, the printed table and ``eval.json``."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from handx_jax.evaluation.checkpoint import evaluator_id
from handx_jax.evaluation.model import TrainedEvaluator
from handx_jax.evaluation.reference import ReferenceEmbeddings, _digest, reference_embeddings
from handx_jax.infra.atomic import atomic_write_json
from handx_jax.infra.errors import DataError
from handx_jax.metrics import (MetricConfig, NamedContacts, ci_method, named_contacts, replicate_embedding_metrics,
                               replicate_motion_metrics)


@dataclass
class EvalResult:
    metrics: dict[str, tuple[float, float]]
    meta: dict

    def flat(self) -> dict[str, float]:
        """``{name: mean, name_ci: half-width}`` with the analysis schema's metric names."""
        out: dict[str, float] = {}
        for k, (m, c) in self.metrics.items():
            out[k], out[f"{k}_ci"] = float(m), float(c)
        return out


def _schema_names(motion: dict) -> dict:
    # replicate_motion_metrics names contacts contact_<p|r|f1>_<intra|inter>; the schema spells them out.
    ren = {"precision": "precision", "recall": "recall", "f1": "f1"}
    out = {}
    for k, v in motion.items():
        if k.startswith("contact_") and k.count("_") == 2:
            _, what, scope = k.split("_")
            out[f"contact_{ren[what]}_{scope}"] = v
        else:
            out[k] = v
    return out


def evaluate_embeddings_and_motion(ev: TrainedEvaluator, text_NxD: np.ndarray, gen_GxNxTx2x21x3: np.ndarray,
                                   gt_NxTx2x21x3: np.ndarray, cfg: MetricConfig, *,
                                   gt_NxD: np.ndarray | None = None, gen_GxNxD: np.ndarray | None = None,
                                   meta: dict | None = None, named: NamedContacts | None = None) -> EvalResult:
    """All metrics of G generation groups against the GT; motion embeddings given are not recomputed
    (the reference cache's GT embeddings; the GT row's generation, which is the GT). ``named``: the
    contacts the prompts' records name (:func:`_named_contacts`), for contact feasibility."""
    t0 = time.perf_counter()
    G, N = gen_GxNxTx2x21x3.shape[:2]
    if cfg.apd_samples > G:
        raise DataError(f"APD over {cfg.apd_samples} samples per prompt (--samples) but the generated clips hold "
                        f"{G} group(s) per prompt; generate with --samples {cfg.apd_samples} or ask for fewer",
                        field="group")
    gt_emb = ev.embed_motion(gt_NxTx2x21x3) if gt_NxD is None else gt_NxD
    if gen_GxNxD is None:
        gen_GxNxD = np.stack([ev.embed_motion(gen_GxNxTx2x21x3[g]) for g in range(G)])
    gen_emb = np.asarray(gen_GxNxD, np.float32)
    t1 = time.perf_counter()
    parts: dict[str, float] = {}
    emb = replicate_embedding_metrics(text_NxD, gen_emb, gt_emb, cfg, timings=parts)
    tm = time.perf_counter()
    mot = _schema_names(replicate_motion_metrics(gen_GxNxTx2x21x3, gt_NxTx2x21x3, cfg, named))
    t2 = time.perf_counter()
    parts["motion_metrics"] = t2 - tm
    order = ("rprec_top1", "rprec_top2", "rprec_top3", "fid", "mm_dist", "diversity", "multimodality", "mpjpe",
             "acceleration", "jitter", "contact_precision_intra", "contact_recall_intra", "contact_f1_intra",
             "contact_precision_inter", "contact_recall_inter", "contact_f1_inter", "mpjpe_ra_left", "mpjpe_ra_right",
             "mpjpe_pa_left", "mpjpe_pa_right", "apd_left", "apd_right", "pen_1cm", "pen_depth", "contact_feasibility")
    allm = {**emb, **mot}
    metrics = {k: allm[k] for k in order if k in allm}
    block = rprec_block_used(cfg.rprec_block, N)
    m = {"prompts": int(N), "groups": int(G), "replications": cfg.replications, "rprec_block": block,
         "rprec_chance": [round(k / block, 6) for k in range(1, cfg.top_k + 1)],
         **({"rprec_block_requested": cfg.rprec_block, "warnings": [rprec_block_warning(cfg.rprec_block, N, cfg.top_k)]}
            if block != cfg.rprec_block else {}),
         "seed": cfg.seed, "mpjpe_root": cfg.mpjpe_root, "evaluator": str(ev.root) if ev.root else None,
         **_evaluator_identity(ev),
         "eval_level": ev.policy.eval_level, "seconds": {"motion_embedding": t1 - t0, "metrics": t2 - t1,
                                                              "metrics_parts": parts},
         "ci_method": {k: ci_method(k, G) for k in metrics}, "bootstrap": cfg.bootstrap,
         "apd_samples": (cfg.apd_samples or G) if G > 1 else None,
         "contact_feasibility_named": None if named is None else len(named),
         **(meta or {})}
    return EvalResult(metrics, m)


def rprec_block_used(block: int, prompts: int) -> int:
    """The R-Precision block the metric really uses: ``block``, or one block of all the prompts when there
    are fewer (metrics.r_precision). ``eval.json``'s ``rprec_block`` and the printed header are this one."""
    return block if prompts >= block else prompts


def rprec_block_warning(block: int, prompts: int, top_k: int = 3) -> str:
    """What a score on fewer prompts than the block says about itself (issue 43: it was labelled block 32)."""
    used = rprec_block_used(block, prompts)
    chance = "/".join(f"{k / used:.3f}" for k in range(1, top_k + 1))
    return (f"{prompts} prompts, fewer than the R-Precision block of {block}: R-Precision is computed on one block "
            f"of {used} (top-1/2/3 chance {chance}, not {'/'.join(f'{k / block:.3f}' for k in range(1, top_k + 1))}),"
            f" so it does not compare with block-{block} scores; score at least {block} prompts, or pass --block "
            f"{used} to ask for this block")


def _evaluator_identity(ev: TrainedEvaluator) -> dict:
    """Which evaluator scored: ``evaluator_id`` (checkpoint.evaluator_id, from its folder's files) and, for
    the packaged standard evaluator, ``evaluator_name`` (``standard-vN``). A results table carries both,
    so scores from two yardsticks are never mixed silently."""
    out = {"evaluator_id": evaluator_id(ev.root) if ev.root else None}
    card = getattr(ev, "card", None)
    if card and "version" in card:
        out["evaluator_name"] = f"standard-v{card['version']}"
    return out


def _dataset_reference(ev: TrainedEvaluator, ds, clips: np.ndarray, cache: bool | str | os.PathLike):
    """GT motion and (cached) reference embeddings of ``clips`` of ``ds`` at the evaluator's caption level."""
    gt = np.asarray(ds.motion[clips], np.float32)
    provenance = {"dataset": ds.fingerprint, "eval_level": ev.policy.eval_level,
                  "clips": _digest(np.asarray(clips, np.int64).tobytes())}
    return gt, reference_embeddings(ev, ev.captions(ds, clips), gt, provenance=provenance, cache=cache)


def _named_contacts(ds, clips: np.ndarray) -> NamedContacts | None:
    """The contacts named by the records (events.jsonl) of ``clips``, the events their captions were
    written from; None where the dataset carries no records (contact feasibility is then not scored)."""
    events = ds.events
    return None if events is None else named_contacts([events[int(c)] for c in clips])


def _note_reference(res: EvalResult, ref: ReferenceEmbeddings) -> EvalResult:
    """Booked in meta: text seconds (the cache read on a hit), GT motion seconds, the cache status."""
    res.meta["seconds"]["text_embedding"] = ref.seconds["text"]
    res.meta["seconds"]["motion_embedding"] += ref.seconds["motion"]
    res.meta["reference_cache"] = ref.status
    return res


def evaluate_ground_truth(ev: TrainedEvaluator, ds, cfg: MetricConfig = MetricConfig(), split: str = "test", *,
                          cache: bool | str | os.PathLike = True) -> EvalResult:
    """The "Ground Truth" row: the split's GT motion scored as if it were the generation (G = 1).

    ``cache``: where the reference embeddings are cached (:func:`reference_embeddings`); False bypasses it.
    """
    ev.check_dataset(ds)
    clips = np.sort(ds.split(split))
    if len(clips) < 2:
        raise DataError(f"split {split!r} has {len(clips)} clips; need at least 2", path=ds.root)
    gt, ref = _dataset_reference(ev, ds, clips, cache)
    res = evaluate_embeddings_and_motion(ev, ref.text_NxD, gt[None], gt, cfg, gt_NxD=ref.motion_NxD,
                                         gen_GxNxD=ref.motion_NxD[None],
                                         meta={"split": split, "ground_truth": True, "reference": str(ds.root)},
                                         named=_named_contacts(ds, clips))
    return _note_reference(res, ref)


@dataclass
class Generated:
    """Generated clips aligned to reference prompts: motion (G, N, T, 2, 21, 3) for clips ``clips`` (N,)."""

    motion: np.ndarray
    clips: np.ndarray
    keys: list[list[str]]


def align_generated(entries: Sequence, ds, split: str = "test") -> Generated:
    """Arrange generated :class:`~handx_jax.interop.handx_npz.HandXClip` entries as (group, prompt).

    With ``source_clip`` on every entry, it names the reference clip (any split); ``group`` defaults
    to the entry's occurrence index among entries of the same source clip. Without ``source_clip`` on
    any entry, entry i is taken as generation i // N of clip i mod N of the reference ``split`` (in
    split order). Every group must cover the same prompts; captions stored in an entry must be the
    reference clip's captions (all levels, or a subset of them), which catches misaligned files.
    """
    if not entries:
        raise DataError("no generated clips")
    has = [e.source_clip is not None for e in entries]
    if any(has) and not all(has):
        bad = next(e.key for e, h in zip(entries, has) if not h)
        raise DataError("some entries carry source_clip and some do not; either all or none must", clip=bad,
                        field="source_clip")
    id_to_idx = {cid: i for i, cid in enumerate(ds.ids)}
    cells: dict[tuple[int, int], Any] = {}
    if all(has):
        seen: dict[int, int] = {}
        for e in entries:
            if e.source_clip not in id_to_idx:
                raise DataError(f"source_clip {e.source_clip!r} is not a clip of the reference dataset {ds.root}",
                                clip=e.key, field="source_clip")
            c = id_to_idx[e.source_clip]
            g = e.group if e.group is not None else seen.get(c, 0)
            seen[c] = max(seen.get(c, 0), g + 1)
            if (g, c) in cells:
                raise DataError(f"duplicate (source_clip {e.source_clip!r}, group {g})", clip=e.key, field="group")
            cells[(g, c)] = e
    else:
        order = np.asarray(ds.split(split))
        n = len(order)
        if n == 0 or len(entries) % n:
            raise DataError(f"{len(entries)} entries without source_clip cannot be matched to the {n} clips of the "
                            f"reference {split!r} split (need a multiple of {n}); write source_clip per entry")
        for i, e in enumerate(entries):
            cells[(i // n, int(order[i % n]))] = e
    groups = sorted({g for g, _ in cells})
    if groups != list(range(len(groups))):
        raise DataError(f"generation groups must be 0..G-1, got {groups}", field="group")
    clips = np.array(sorted({c for _, c in cells}), np.int64)
    for g in groups:
        missing = [ds.ids[c] for c in clips if (g, c) not in cells]
        if missing:
            raise DataError(f"group {g} lacks {len(missing)} of the {len(clips)} prompts (e.g. {missing[:3]}); "
                            "every group must cover the same prompts", field="group")
    G, N = len(groups), len(clips)
    T = entries[0].motion.shape[0]
    motion = np.zeros((G, N, T, 2, 21, 3), np.float32)
    keys = [[""] * N for _ in range(G)]
    for (g, c), e in cells.items():
        j = int(np.searchsorted(clips, c))
        if e.motion.shape != motion.shape[2:]:
            raise DataError(f"motion shape {e.motion.shape}, expected {motion.shape[2:]}", clip=e.key, field="motion")
        check_motion_range(e.motion, clip=e.key)
        _check_captions(e, ds.texts[c])
        motion[g, j], keys[g][j] = e.motion, e.key
    return Generated(motion, clips, keys)


# Joints are metres in the canonical frame: both hands within about a metre of the right wrist's start.
# Far beyond that is not motion in metres (millimetres, or a sample that diverged), and finite but huge
# values (×1e30) overflow the evaluator's features and the FID covariance (numpy's LinAlgError, issue 31).
MAX_ABS_METRES = 100.0


def check_motion_range(motion: np.ndarray, *, clip: Any = None) -> None:
    """Refuse motion the evaluator cannot score: non-finite values, or joints farther than
    :data:`MAX_ABS_METRES` from the origin. A ``DataError`` naming the clip, the field and the frame."""
    m = np.asarray(motion, np.float64)
    bad = ~np.isfinite(m)
    if bad.any():
        f = int(np.argwhere(bad)[0, 0])
        raise DataError(f"{int(bad.sum())} non-finite (NaN/inf) values, the first in frame {f}", clip=clip,
                        field="motion")
    far = np.abs(m) > MAX_ABS_METRES
    if far.any():
        f = int(np.argwhere(far)[0, 0])
        raise DataError(f"joint coordinates up to {np.abs(m).max():.3g} m (first in frame {f}); the evaluator scores "
                        f"motion in metres within ±{MAX_ABS_METRES:g} m of the origin: is it in millimetres, or did "
                        f"the sample diverge?", clip=clip, field="motion")


def _check_captions(entry, ref: dict) -> None:
    for name, have in (("left", entry.left), ("right", entry.right), ("interaction", entry.interaction)):
        want = ref[name]
        ok = have == want if len(have) == len(want) else all(s in want for s in have)
        if not ok:
            raise DataError(f"captions differ from reference clip {ref.get('id')!r} (generated for another prompt, "
                            f"or source_clip/order is wrong)", clip=entry.key, field=f"{name}_annotation")


def evaluate_generated(ev: TrainedEvaluator, entries: Sequence, ds, cfg: MetricConfig = MetricConfig(),
                       split: str = "test", *, cache: bool | str | os.PathLike = True) -> EvalResult:
    """Table 2 metrics of generated clips against the reference dataset's GT and captions.

    ``cache``: where the reference embeddings are cached (:func:`reference_embeddings`); False bypasses it.
    """
    ev.check_dataset(ds)
    gen = align_generated(entries, ds, split)
    gt, ref = _dataset_reference(ev, ds, gen.clips, cache)
    res = evaluate_embeddings_and_motion(ev, ref.text_NxD, gen.motion, gt, cfg, gt_NxD=ref.motion_NxD,
                                         meta={"ground_truth": False, "reference": str(ds.root)},
                                         named=_named_contacts(ds, gen.clips))
    return _note_reference(res, ref)


# ------------------------------------------------------------------------------------------------
# Output


TABLE_COLUMNS = (  # (metric, header) in the paper's Table 2 order, plus MPJPE and contact F1
    ("rprec_top1", "Top-1"), ("rprec_top2", "Top-2"), ("rprec_top3", "Top-3"), ("fid", "FID"),
    ("mm_dist", "MM-Dist"), ("diversity", "Diversity"), ("multimodality", "MModality"), ("mpjpe", "MPJPE(mm)"),
    ("contact_f1_intra", "F1-intra"), ("contact_f1_inter", "F1-inter"),
    ("mpjpe_pa_left", "PA-L(mm)"), ("mpjpe_pa_right", "PA-R(mm)"), ("apd_left", "APD-L(mm)"),  # G-HTT
    ("apd_right", "APD-R(mm)"), ("pen_1cm", "Pen1cm(%)"), ("contact_feasibility", "C-feas"),  # BimArt
)


def format_table(rows: Sequence[tuple[str, EvalResult]], block: int = 32) -> str:
    """Rows in the paper's Table 2 layout: mean±CI (95%, 1.96·σ/√n over replications)."""
    w_name = max(14, *(len(n) for n, _ in rows))
    cells = [[f"{r.metrics[k][0]:.3f}±{r.metrics[k][1]:.3f}" if k in r.metrics else "-" for k, _ in TABLE_COLUMNS]
             for _, r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, (_, h) in enumerate(TABLE_COLUMNS)]
    span = sum(widths[:3]) + 4
    lines = [" " * w_name + "  " + f"R-Precision (block {block}) ↑".ljust(span) + "  "
             + "  ".join(h.ljust(w) for (_, h), w in list(zip(TABLE_COLUMNS, widths))[3:]),
             " " * w_name + "  " + "  ".join(h.ljust(w) for (_, h), w in list(zip(TABLE_COLUMNS, widths))[:3])]
    for (name, _), c in zip(rows, cells):
        lines.append(name.ljust(w_name) + "  " + "  ".join(x.ljust(w) for x, w in zip(c, widths)))
    return "\n".join(lines)


def write_eval_json(path: str | os.PathLike, result: EvalResult) -> Path:
    """``eval.json`` as the analysis run-folder contract reads it: ``name``/``name_ci`` plus ``_meta``."""
    return atomic_write_json(path, {**result.flat(), "_meta": result.meta})
