"""Build the procedural corpus end to end: synthesis → canonical frame → clips + filter → annotation.

The text of every clip comes from running the annotation pipeline (features → events → captioner)
on the generated motion, never from the motion program's own labels (issue 2, §5), so the pipeline
is exercised for real. Work is split into chunks of sequences; chunk ``k`` depends only on
``(seed, k)``, so chunks run in parallel processes and the result is identical for any worker count.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.dataset.clips import ClipConfig, ClipReport, extract_clips
from handx_jax.dataset.format import DEFAULT_FRACTIONS, write_dataset
from handx_jax.annotation.events import AnnotationConfig, annotate
from handx_jax.dataset.chunk_spool import ChunkSpool
from handx_jax.infra.diskspace import check_free_space
from handx_jax.infra.values import check, check_split_fractions
from handx_jax.annotation.caption import TemplateCaptioner
from handx_jax.synthesis.bimanual import GENERATOR_VERSION, MOTIONS, SynthConfig, synth_chunk

if TYPE_CHECKING:
    from handx_jax.representation import NormPreset


@dataclass(frozen=True)
class CorpusSize:
    """What every corpus build shares (the hand corpus here, the hand-object corpus in synthesis.object_build):
    how many clips, the seed, the split fractions and the worker count."""
    clips: int = 2000
    seed: int = 0
    val_fraction: float = 0.05
    test_fraction: float = 0.05
    fractions: tuple[float, ...] = DEFAULT_FRACTIONS
    workers: int = 0  # 0 → one per CPU core

    def validate(self) -> None:
        """Refuse a corpus that cannot be built as asked, before any work (``infra.values``; issue 54): no
        clips, a negative seed (numpy's seeding fails inside a worker) or worker count, split fractions that
        leave a split empty."""
        check(self.clips, "clips", whole=True, minimum=1)
        check(self.seed, "seed", whole=True, minimum=0)
        check(self.workers, "workers", whole=True, minimum=0)
        check_split_fractions(self.val_fraction, self.test_fraction)


@dataclass(frozen=True)
class BuildConfig(CorpusSize):
    synth: SynthConfig = field(default_factory=SynthConfig)
    clip: ClipConfig = field(default_factory=ClipConfig)
    annotation: AnnotationConfig = field(default_factory=AnnotationConfig)
    # Where the template captioner's word choices come from (data.caption.TemplateCaptioner): "shared"
    # for every corpus built before issue 40; "per_fact" words each fact independently of the others.
    wording: str = "shared"


# The captioner wording that goes with each annotation reading (events.ANNOTATIONS): a corpus built
# with the stable reading also words each fact independently (issue 40).
WORDING = {"reference": "shared", "stable": "per_fact", "gist": "per_fact", "surface": "per_fact"}


def reading_of_options(options: dict) -> str | None:
    """The named annotation reading a corpus's recipe options record (``meta.json`` ``recipe.options``),
    or None when its annotation is none of them (a custom AnnotationConfig)."""
    from handx_jax.annotation.events import ANNOTATIONS

    ann = (options or {}).get("annotation")
    for name, cfg in ANNOTATIONS.items():
        probe = {"annotation": _jsonable(dataclasses.asdict(cfg))}
        _drop_neutral(probe)
        if probe["annotation"] == ann:
            return name
    return None


def reading_of(ds) -> tuple[str, str]:
    """(annotation reading, captioner wording) a dataset was built with, from its recipe: a synthetic
    corpus records both; a derived one (``handx data reverse``) records what it was annotated with in its
    ``source``; anything else (an imported release) is read with the reference reading."""
    from handx_jax.annotation.events import ANNOTATIONS

    opts = ((ds.meta.get("recipe") or {}).get("options") or {})
    reading = reading_of_options(opts)
    if reading is not None:
        return reading, opts.get("wording", WORDING[reading])
    src = ds.meta.get("source") or {}
    if src.get("annotation") in ANNOTATIONS:
        return src["annotation"], src.get("wording", WORDING[src["annotation"]])
    return "reference", opts.get("wording", WORDING["reference"])


def corpus_seed(ds) -> int:
    """The seed a corpus's caption seeds derive from (:func:`caption_seed`)."""
    rec = ds.meta.get("recipe") or {}
    return int(rec.get("seed", (ds.meta.get("source") or {}).get("seed", 0)))


def with_reading(cfg: BuildConfig, name: str) -> BuildConfig:
    """``cfg`` annotated and captioned with the named reading (``handx data synth --annotation``)."""
    from handx_jax.annotation.events import annotation_config

    return dataclasses.replace(cfg, annotation=annotation_config(name), wording=WORDING[name])


# The clip filter's intensity thresholds (°/s, paper A.4) that go with corpus v3's transition motion. The paper's
# 25 / 30 were set for captured hands, and corpora v1–v2 top every acting hand up to 40 °/s with incidental
# finger motion. A transition holds still around one move, so one finger pinching reads 9–13 °/s and a claw
# 16–19, while an idle segment reads 4.4–5.4 (docs/results/validity/corpus-v3/). 7 keeps the acting hands
# and still drops the idle ones.
TRANSITION_TAU = 7.0


def with_motion(cfg: BuildConfig, name: str) -> BuildConfig:
    """``cfg`` with the named motion (``handx data synth --motion``): "oscillate" (corpora v1–v2: the defaults)
    or "transition" (corpus v3: one segment per sequence, and the clip filter's thresholds for motion that
    holds still around each move, ``TRANSITION_TAU``) or "chain" (corpus v4: the same, with up to two more moves per hand)."""
    if name == "oscillate":
        return dataclasses.replace(cfg, synth=dataclasses.replace(cfg.synth, motion="oscillate"))
    if name not in MOTIONS:
        raise ValueError(f"unknown motion {name!r}; choose {', '.join(MOTIONS)}")
    return dataclasses.replace(cfg, synth=dataclasses.replace(cfg.synth, motion=name, segments_per_sequence=1),
                               clip=dataclasses.replace(cfg.clip, tau_hand=TRANSITION_TAU, tau_avg=TRANSITION_TAU))


@dataclass
class ChunkResult:
    chunk_index: int
    clips: np.ndarray  # (K, 60, 2, 21, 3) float32
    ids: list[str]
    split: list[str]
    texts: list[dict]
    events: list[dict]
    intensity: np.ndarray  # (K, 2)
    report: ClipReport
    programs: dict[str, int]


def sequence_split(seed: int, global_seq: int, val_fraction: float, test_fraction: float) -> str:
    """Assign a whole sequence to one split (clips of one sequence never straddle splits).

    A hash of (seed, sequence) gives a uniform number, so the assignment does not depend on how many
    clips are built: a larger corpus extends a smaller one's splits.
    """
    u = int.from_bytes(hashlib.blake2b(f"{seed}/{global_seq}".encode(), digest_size=8).digest(), "little") / 2**64
    return "test" if u < test_fraction else "val" if u < test_fraction + val_fraction else "train"


def first_valid_frame(seq_Tx2x21x3: np.ndarray) -> int:
    ok = np.isfinite(seq_Tx2x21x3).reshape(seq_Tx2x21x3.shape[0], -1).all(1)
    return int(np.argmax(ok)) if ok.any() else -1


def process_chunk(cfg: BuildConfig, chunk_index: int) -> ChunkResult:
    chunk = synth_chunk(cfg.seed, chunk_index, cfg.synth)
    report = ClipReport()
    clips, ids, splits, inten = [], [], [], []
    programs: dict[str, int] = {}
    for q, seq in enumerate(chunk.joints):
        for seg in chunk.programs[q]:
            for key in ("left", "right", "interaction", "left_then", "right_then"):
                if seg.get(key):
                    programs[f"{key}:{seg[key]}"] = programs.get(f"{key}:{seg[key]}", 0) + 1
        f0 = first_valid_frame(seq)
        if f0 < 0:
            report.sequences += 1
            report.frames += seq.shape[0]
            report.defective_frames["nonfinite"] += seq.shape[0]
            continue
        c, starts, i, rep = extract_clips(sk.canonicalize(seq, ref_frame=f0), cfg.clip)
        report.merge(rep)
        if not len(c):
            continue
        # Per-window translation as in the released clips (reference §1.7): right wrist at the
        # origin in each clip's first frame; the rotation stays the sequence's canonical one.
        c = c - c[:, :1, sk.RIGHT:sk.RIGHT + 1, :1, :]
        gseq = chunk_index * cfg.synth.chunk_size + q
        split = sequence_split(cfg.seed, gseq, cfg.val_fraction, cfg.test_fraction)
        clips.append(c)
        inten.append(i)
        ids.extend(f"synth-{cfg.seed}-{gseq:07d}-{s:04d}" for s in starts)
        splits.extend([split] * len(c))
    clips_a = np.concatenate(clips) if clips else np.zeros((0, sk.CLIP_LEN, 2, sk.NUM_JOINTS, 3), np.float32)
    events = annotate(clips_a, cfg.annotation) if len(clips_a) else []
    captioner = TemplateCaptioner(cfg.wording)
    texts = []
    for cid, rec in zip(ids, events):
        levels = captioner.caption(rec, seed=caption_seed(cfg.seed, cid))
        texts.append({"id": cid, **{k: [lv[k] for lv in levels] for k in ("left", "right", "interaction")}})
    return ChunkResult(chunk_index, clips_a, ids, splits, texts, events,
                       np.concatenate(inten) if inten else np.zeros((0, 2), np.float32), report, programs)


def caption_seed(seed: int, clip_id: str) -> int:
    """The template captioner's seed for one clip of a corpus of ``seed`` (re-captioning reproduces it)."""
    return int.from_bytes(hashlib.blake2b(f"{seed}/{clip_id}".encode(), digest_size=4).digest(), "little")


def build_corpus(out: str | os.PathLike, cfg: BuildConfig = BuildConfig(), *, overwrite: bool = False,
                 progress: bool = True, stats: bool | Sequence[NormPreset] = True) -> Path:
    """Synthesise and annotate ``cfg.clips`` clips and write them as a dataset at ``out``; ``stats``: the
    normalisation statistics it holds (:func:`~handx_jax.dataset.format.write_dataset`)."""
    cfg.validate()
    out = Path(out)
    if out.exists() and not overwrite:  # refuse before spending minutes of work
        raise FileExistsError(f"{out} already exists; pass --force to replace it")
    # The motion alone takes clips × 30 KB (texts, events and stats add ~20 %), and the chunk spool holds it once
    # more until the dataset is written: refuse a disk that cannot hold both now rather than after the synthesis.
    check_free_space(out, 2 * cfg.clips * sk.CLIP_LEN * 2 * sk.NUM_JOINTS * 3 * 4)
    workers = cfg.workers or os.cpu_count() or 1
    spool = ChunkSpool(out, recipe(cfg), (ChunkResult, ClipReport), discard_other=overwrite)  # a killed build resumes
    t0 = time.perf_counter()
    results: list[ChunkResult] = []
    n = 0
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=cfg.clips, unit="clip", desc="synth+annotate", dynamic_ncols=True)
    surplus = 0  # clips built by the last chunk beyond the target, dropped to hit it exactly
    for r in spool.chunks(functools.partial(process_chunk, cfg), workers):
        take = min(len(r.ids), cfg.clips - n)
        surplus += len(r.ids) - take
        results.append(_truncate(r, take))
        n += take
        if bar:
            bar.update(take)
        if n >= cfg.clips:
            break
        if r.chunk_index > 50 + 20 * cfg.clips:  # nothing survives the filter: stop, don't spin
            raise RuntimeError("the clip filter rejects almost every synthesised clip; check the configs")
    if bar:
        bar.close()
    elapsed = time.perf_counter() - t0

    motion = np.concatenate([r.clips for r in results])
    texts = [t for r in results for t in r.texts]
    events = [e for r in results for e in r.events]
    split_of = [s for r in results for s in r.split]
    splits = {k: [i for i, s in enumerate(split_of) if s == k] for k in ("train", "val", "test")}
    report = ClipReport()
    programs: dict[str, int] = {}
    for r in results:
        report.merge(r.report)
        for k, v in r.programs.items():
            programs[k] = programs.get(k, 0) + v
    intensity = np.concatenate([r.intensity for r in results])
    build_report = {
        "clips": report.to_json(),
        "dataset_clips": n,
        "surplus_clips_dropped": surplus,
        "chunks": len(results),
        "chunks_resumed": spool.resumed,  # read back from a killed build's spool, not computed by this run
        "seconds": round(elapsed, 2),
        "clips_per_second": round(n / max(elapsed, 1e-9), 1),
        "intensity_mean": intensity.mean(0).round(2).tolist() if len(intensity) else None,
        "program_counts": dict(sorted(programs.items())),
        "note": "program_counts are the generator's own labels, kept for diagnostics; captions come "
                "from the annotation pipeline.",
    }
    source = {"kind": "synth", "seed": cfg.seed, "config": _jsonable(dataclasses.asdict(cfg))}
    written = write_dataset(out, motion, texts, splits=splits, events=events, source=source,
                            report=build_report, fractions=cfg.fractions, seed=cfg.seed, overwrite=overwrite,
                            workers=workers, recipe=recipe(cfg), stats=stats)
    spool.remove()
    return written


def recipe(cfg: BuildConfig) -> dict:
    """The corpus's identity (issue 14.5): generator version, seed, clip count and every option that
    shapes the content; not ``workers`` (the result does not depend on it) nor the numpy build."""
    options = _jsonable(dataclasses.asdict(cfg))
    for k in ("clips", "seed", "workers"):
        options.pop(k)
    _drop_neutral(options)
    return {"kind": "synth", "generator_version": GENERATOR_VERSION, "seed": cfg.seed, "clips": cfg.clips,
            "options": options}


# Options added after corpora were built with this recipe format, with the value that reproduces
# those corpora (issue 40's stable annotation and per-fact wording). They are recorded only when they
# change the content, so every earlier corpus (and its prefixes) keeps its identity.
_NEUTRAL_OPTIONS = {"wording": "shared"}
_NEUTRAL_SYNTH = {"motion": "oscillate"}
_NEUTRAL_ANNOTATION = {"smooth_sigma_frames": 0.0, "contact_hysteresis_m": 0.0, "contact_gap_frames": 0,
                       "contact_min_frames": 1, "segmentation": "greedy",
                       "merge_gap_frames": 10, "state_delta": True, "finger_curl_swing_deg": 0.0,
                       "surface_contact_m": 0.0}
_NEUTRAL_SPEC = {"hysteresis": 0.0}
_NEUTRAL_FEATURES = {"thumb_mcp": "reference", "dip_coupling": 0.0}


def _drop_neutral(options: dict) -> None:
    def drop(d: dict, neutral: dict) -> None:
        for k, v in neutral.items():
            if k in d and d[k] == v:
                d.pop(k)

    drop(options, _NEUTRAL_OPTIONS)
    if isinstance(options.get("synth"), dict):
        drop(options["synth"], _NEUTRAL_SYNTH)
    ann = options.get("annotation")
    if isinstance(ann, dict):
        # merge_gap_frames and state_delta only act with the "states" segmentation.
        if ann.get("segmentation") == "greedy":
            ann.pop("merge_gap_frames", None)
            ann.pop("state_delta", None)
        drop(ann, _NEUTRAL_ANNOTATION)
        if isinstance(ann.get("features"), dict):
            drop(ann["features"], _NEUTRAL_FEATURES)
        for v in ann.values():
            specs = v if isinstance(v, list) else [v]
            for sp in specs:
                if isinstance(sp, dict) and "min_duration" in sp:
                    drop(sp, _NEUTRAL_SPEC)


def _truncate(r: ChunkResult, k: int) -> ChunkResult:
    if k >= len(r.ids):
        return r
    return dataclasses.replace(r, clips=r.clips[:k], ids=r.ids[:k], split=r.split[:k], texts=r.texts[:k],
                               events=r.events[:k], intensity=r.intensity[:k])


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x
