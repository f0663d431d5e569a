"""Build the hand–object corpus (issue 52 item 2): synthesis → physics filter → annotation → the dataset format.

``handx data objects --clips N --out D``. Chunk ``k`` depends only on ``(seed, k)`` (object_motion.py), so chunks
run in parallel processes (data.parallel.map_ordered) and the corpus is the same for any worker count; clips are
taken in chunk order until N are kept. A clip is kept when its physics holds on every frame
(object_physics.LIMITS) and each hand holds with at least two fingers whose pads touch the part; the report
counts the rest by reason.

The dataset is the project's format (data/dataset.py: motion.npy, texts.jsonl, splits, stats, meta.json with
the recipe) plus the object annotations, one row per clip:

    object_state.npy  float32 (N, 60, 7)      angle, axis-angle, translation (m), in the clip's canonical frame
    held.npy          int8 (N, 60, 2)          the part each hand holds (0 top, 1 bottom), -1 none
    contact_map.npy   float16 (N, 60, 2, 2, K) hand x part x basis point: distance (m) from the part's
                                               basis-mapped point (objects/bps.py) to the hand's surface
    bps_points.npy    float32 (N, 2, K, 3)     those points, in each part's canonical frame
    objects.jsonl     per clip: category, instance seed (objects.sample_instance rebuilds the object), sizes,
                      program (grab/use), layout (split/pair), use kind, motion, and per hand its part, grasp
                      template, shape and touching fingers
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.dataset.build import CorpusSize, _jsonable, caption_seed, sequence_split
from handx_jax.dataset.format import write_dataset
from handx_jax.dataset.chunk_spool import ChunkSpool
from handx_jax.infra.diskspace import check_free_space
from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_jsonl
from handx_jax.objects import BOTTOM, CATEGORIES, TOP, sample_instance
from handx_jax.objects.bps import D_MARGIN, basis_points, category_scale_angle, map_basis
from handx_jax.synthesis import object_physics as phys
from handx_jax.synthesis.object_captions import caption_clip
from handx_jax.synthesis.object_motion import ObjectSynthConfig, pad_object, stack_objects, synth_object_chunk

# Bumped whenever the same (seed, config) would give a different corpus; part of the recipe.
OBJECT_GENERATOR_VERSION = 3
ARRAYS = ("object_state", "held", "contact_map", "bps_points")
MIN_PAD_FINGERS = 2   # a holding hand touches its part with at least this many finger pads


@dataclass(frozen=True)
class ObjectBuildConfig(CorpusSize):
    bps_k: int = 64                       # basis points per part (the contact map's width per part)
    synth: ObjectSynthConfig = field(default_factory=ObjectSynthConfig)


@functools.lru_cache(maxsize=2)
def _basis(k: int) -> np.ndarray:
    return np.asarray(basis_points(k, seed=0))


def bps_points(samples_Nx2xSx3: np.ndarray, basis_Kx3: np.ndarray, scale_angles_N: np.ndarray) -> np.ndarray:
    """objects/bps.py's mapping (Eq. 1-2) from the surface samples the synthesizer drew, in numpy (no compile):
    the points (N, 2, K, 3) each basis point maps to on each part."""
    from scipy.spatial.transform import Rotation

    out = np.empty(samples_Nx2xSx3.shape[:2] + basis_Kx3.shape, np.float32)
    for i, (pts, a) in enumerate(zip(np.asarray(samples_Nx2xSx3, np.float64), scale_angles_N)):
        top = pts[TOP] @ Rotation.from_rotvec([0.0, 0.0, -float(a)]).as_matrix().T
        s_o = (1.0 - D_MARGIN) / max(np.linalg.norm(top, axis=-1).max(), np.linalg.norm(pts[BOTTOM], axis=-1).max())
        out[i] = map_basis(pts, basis_Kx3, s_o)
    return out


@dataclass
class ObjectChunkResult:
    chunk_index: int
    motion: np.ndarray
    arrays: dict[str, np.ndarray]
    ids: list[str]
    split: list[str]
    texts: list[dict]
    records: list[dict]
    rejected: dict[str, int]
    physics: dict[str, np.ndarray]   # per kept clip: the worst value of each physics measure
    cpu_seconds: float = 0.0         # the process's CPU time on this chunk (compiles included)


def process_chunk(cfg: ObjectBuildConfig, chunk_index: int) -> ObjectChunkResult:
    cpu0 = time.process_time()
    ch = synth_object_chunk(cfg.seed, chunk_index, cfg.synth)
    objs = stack_objects(ch.objects)
    m = phys.measure(objs, ch.states, ch.joints)
    # A holding hand's pads count on the part it holds, not on the nearer part (issue 52 item 3: "held finger
    # pads within 3 mm"): a pad resting on the other part holds nothing, and in a use clip the parts move apart.
    m["pad"] = phys.pad_on_held_part(m, np.array([[h["part"] for h in pr["hands"]] for pr in ch.programs]))
    dr = phys.drift(phys.joints_in_part(ch.states, ch.joints, ch.held), ch.held)
    held = ch.held >= 0
    first = np.argmax(held, axis=1)                                                   # (N, 2)
    pad0 = np.take_along_axis(m["pad"], first[:, None, :, None], 1)[:, 0]             # (N, 2, 5)
    pad_fingers = np.abs(pad0) <= phys.LIMITS["pad_m"]
    v = phys.verdict(m, dr, ch.held, pad_fingers)
    v["grasp"] = ch.ok & (pad_fingers.sum(-1) >= MIN_PAD_FINGERS).all(-1)
    keep = np.logical_and.reduce(list(v.values()))
    rejected = {k: int((~a).sum()) for k, a in v.items()}
    rejected["any"] = int((~keep).sum())

    basis = _basis(cfg.bps_k)
    angles = np.array([category_scale_angle(p["category"]) for p in ch.programs], np.float32)
    bps = bps_points(ch.samples, basis, angles)                                     # (N, 2, K, 3)
    cmap = phys.contact_maps(objs, bps, ch.states, ch.joints)

    idx = np.flatnonzero(keep)
    ids, splits, texts, records = [], [], [], []
    for i in idx:
        g = chunk_index * cfg.synth.chunk_size + int(i)
        cid = f"objects-{cfg.seed}-{g:07d}"
        pr = ch.programs[i]
        pr = dict(pr, sizes=CATEGORIES[pr["category"]].draw_sizes(pr["instance_seed"]))
        for h in range(2):
            pr["hands"][h]["pad_fingers"] = [sk.FINGER_NAMES[f] for f in np.flatnonzero(pad_fingers[i, h])]
        ids.append(cid)
        splits.append(sequence_split(cfg.seed, g, cfg.val_fraction, cfg.test_fraction))
        texts.append({"id": cid, **caption_clip(pr, ch.states[i, :, 0], caption_seed(cfg.seed, cid))})
        records.append(_jsonable({"id": cid, **pr}))
    physics = {"depth_m": m["depth"].max((1, 2))[idx], "interhand_m": m["interhand"].min(1)[idx],
               "pad_m": np.where(held[..., None] & pad_fingers[:, None], np.abs(m["pad"]), 0).max((1, 2, 3))[idx],
               "drift_m": dr.max(1)[idx],
               "contact_frames": (m["near_part"].min(-1) <= 0.005).any(-1).sum(-1)[idx]}
    arrays = {"object_state": ch.states[idx], "held": ch.held[idx], "contact_map": cmap[idx].astype(np.float16),
              "bps_points": bps[idx]}
    return ObjectChunkResult(chunk_index, ch.joints[idx], arrays, ids, splits, texts, records, rejected, physics,
                             time.process_time() - cpu0)


def build_object_corpus(out: str | os.PathLike, cfg: ObjectBuildConfig = ObjectBuildConfig(), *,
                        overwrite: bool = False, progress: bool = True) -> Path:
    """Synthesise ``cfg.clips`` hand–object clips and write them as a dataset at ``out``."""
    cfg.validate()  # before anything is written
    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass --force to replace it")
    per_clip = sk.CLIP_LEN * (2 * sk.NUM_JOINTS * 3 * 4 + 7 * 4 + 2 + 2 * 2 * cfg.bps_k * 2) + 2 * cfg.bps_k * 12
    check_free_space(out, 2 * cfg.clips * per_clip)  # the dataset, and the chunk spool until it is written
    workers = cfg.workers or os.cpu_count() or 1
    spool = ChunkSpool(out, recipe(cfg), (ObjectChunkResult,), discard_other=overwrite)  # a killed build resumes
    t0 = time.perf_counter()
    results, n = [], 0
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=cfg.clips, unit="clip", desc="objects", dynamic_ncols=True)
    for r in spool.chunks(functools.partial(process_chunk, cfg), workers):
        take = min(len(r.ids), cfg.clips - n)
        results.append(_truncate(r, take))
        n += take
        if bar:
            bar.update(take)
        if n >= cfg.clips:
            break
        if r.chunk_index > 10 + 4 * cfg.clips:
            raise RuntimeError("the physics filter rejects almost every clip; check the configs")
    if bar:
        bar.close()
    elapsed = time.perf_counter() - t0
    motion = np.concatenate([r.motion for r in results])
    arrays = {k: np.concatenate([r.arrays[k] for r in results]) for k in ARRAYS}
    texts = [t for r in results for t in r.texts]
    records = [x for r in results for x in r.records]
    split_of = [s for r in results for s in r.split]
    splits = {k: [i for i, s in enumerate(split_of) if s == k] for k in ("train", "val", "test")}
    physics = {k: np.concatenate([r.physics[k] for r in results]) for k in results[0].physics}
    rejected: dict[str, int] = {}
    for r in results:
        for k, v in r.rejected.items():
            rejected[k] = rejected.get(k, 0) + v
    report = {
        "dataset_clips": n, "chunks": len(results), "chunks_resumed": spool.resumed, "seconds": round(elapsed, 2),
        "clips_per_second": round(n / max(elapsed, 1e-9), 1),
        "synthesised_clips": len(results) * cfg.synth.chunk_size,
        # CPU time of the chunks (their processes' own, compiles included): on a busy machine wall time says little.
        "cpu_seconds": round(sum(r.cpu_seconds for r in results), 2),
        "cpu_seconds_per_kept_clip": round(sum(r.cpu_seconds for r in results) / max(n, 1), 4),
        "rejected_by_physics": rejected,
        "physics_limits": phys.LIMITS,
        "physics_worst": {"depth_m": float(physics["depth_m"].max()), "interhand_m": float(physics["interhand_m"].min()),
                          "pad_m": float(physics["pad_m"].max()), "drift_m": float(physics["drift_m"].max())},
        "statistics": corpus_statistics(records, arrays["held"], physics["contact_frames"]),
    }
    source = {"kind": "objects", "seed": cfg.seed, "config": _jsonable(dataclasses.asdict(cfg))}
    written = write_dataset(out, motion, texts, splits=splits, source=source, report=report, fractions=cfg.fractions,
                            seed=cfg.seed, overwrite=overwrite, workers=workers, recipe=recipe(cfg), arrays=arrays,
                            records={"objects": records})
    spool.remove()
    return written


def corpus_statistics(records: list[dict], held_NxTx2: np.ndarray, contact_frames_N: np.ndarray) -> dict:
    """Clips per category and program, frames with a hand in contact (within 5 mm), held frames, grasp types."""
    by = {}
    grasps = {}
    for r in records:
        key = f"{r['category']}:{r['program']}:{r.get('use', '')}:{r['layout']}"
        by[key] = by.get(key, 0) + 1
        for h in r["hands"]:
            g = f"{r['category']}:{h['template']} ({h['shape']})"
            grasps[g] = grasps.get(g, 0) + 1
    T = held_NxTx2.shape[1] if len(held_NxTx2) else sk.CLIP_LEN
    return {"clips": len(records), "by_category_program": dict(sorted(by.items())),
            "grasp_types": dict(sorted(grasps.items())),
            "contact_frames_fraction": float(np.mean(contact_frames_N) / T) if len(records) else 0.0,
            "held_frames_fraction_per_hand": (held_NxTx2 >= 0).mean((0, 1)).round(4).tolist() if len(records) else []}


def recipe(cfg: ObjectBuildConfig) -> dict:
    options = _jsonable(dataclasses.asdict(cfg))
    for k in ("clips", "seed", "workers"):
        options.pop(k)
    return {"kind": "objects", "generator_version": OBJECT_GENERATOR_VERSION, "seed": cfg.seed, "clips": cfg.clips,
            "options": options}


def _truncate(r: ObjectChunkResult, k: int) -> ObjectChunkResult:
    if k >= len(r.ids):
        return r
    return dataclasses.replace(r, motion=r.motion[:k], arrays={a: v[:k] for a, v in r.arrays.items()},
                               ids=r.ids[:k], split=r.split[:k], texts=r.texts[:k], records=r.records[:k],
                               physics={a: v[:k] for a, v in r.physics.items()})


def open_object_annotations(root: str | os.PathLike) -> dict:
    """The object annotations of a hand–object corpus: the arrays (memory-mapped) and ``objects`` records."""
    root = Path(root)
    out = {}
    for name in ARRAYS:
        p = root / f"{name}.npy"
        if not p.exists():
            raise DataError(f"missing {name}.npy: not a hand-object corpus (handx data objects builds one)", path=root)
        out[name] = np.load(p, mmap_mode="r")
    out["objects"] = read_jsonl(root / "objects.jsonl")
    return out


def clip_object(record: dict):
    """The (padded) object of one clip, rebuilt from its record's category and instance seed."""
    return pad_object(sample_instance(record["category"], int(record["instance_seed"])))
