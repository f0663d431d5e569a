"""A dataset's clips played backwards, annotated and captioned again: the order of events as data.

Issue 40 asks the yardstick to read the order of events. The validity suite measured why a negative
alone does not teach it (``docs/results/validity``): evaluator v5 saw each clip's reversal as a
negative of the clip's own caption, yet picks the right one of (caption, reversed clip's caption) for
a reversed clip only 54% of the time, and for the 14% of clips whose reversal reads the same (a finger
that curls and uncurls) that negative punished the right answer. The remedy is what the annotation
pipeline can already give: a reversed clip is a valid clip with its OWN caption (the events in the
other order, directions flipped), so it is a training pair like any other.

``build_reversed(data, out)`` writes a dataset of a split's clips time-reversed, annotated with the
corpus's own reading and captioned with its own wording and caption seeds (the source clip's seed, so
the wording of an unchanged fact stays the same), every clip in its train split. Its ids are the
source ids with ``~rev``; ``meta.json`` ``source`` names the dataset and split it came from.
``handx data reverse --data D --out R`` builds it; ``handx train evaluator --set data.reversed_path=R``
mixes it into the evaluator's batches (``evaluation.features.TrainingData``).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from handx_jax.dataset.build import caption_seed, corpus_seed, reading_of
from handx_jax.dataset.format import TEXT_FIELDS, Dataset, write_dataset
from handx_jax.dataset.parallel import map_ordered
from handx_jax.infra.errors import DataError
from handx_jax.infra.outputs import check_out_apart, refuse_existing
from handx_jax.infra.values import check

SUFFIX = "~rev"
CHUNK = 512  # clips per annotation task


def _annotate_chunk(reading: str, wording: str, seed: int, item: tuple[np.ndarray, list[str]]):
    from handx_jax.annotation.caption import TemplateCaptioner
    from handx_jax.annotation.events import annotate, annotation_config

    joints, ids = item
    records = annotate(joints, annotation_config(reading))
    cap = TemplateCaptioner(wording)
    texts = []
    for cid, rec in zip(ids, records):
        levels = cap.caption(rec, seed=caption_seed(seed, cid))
        texts.append({"id": cid + SUFFIX, **{f: [lv[f] for lv in levels] for f in TEXT_FIELDS}})
    return records, texts


def pick_clips(ds, split: str, limit: int | None) -> np.ndarray:
    """The split's clips, or ``limit`` of them evenly spaced over it (a deterministic subset that spans
    the corpus, not its first sequences)."""
    clips = np.sort(np.asarray(ds.split(split), np.int64))
    if limit is not None and limit < len(clips):
        clips = clips[np.unique(np.linspace(0, len(clips) - 1, limit).round().astype(np.int64))]
    return clips


def build_reversed(data: str | os.PathLike, out: str | os.PathLike, *, split: str = "train",
                   limit: int | None = None, workers: int = 0, overwrite: bool = False,
                   log=print, stats=True) -> Path:
    """Write the time-reversed, re-annotated copy of ``data``'s ``split`` (at most ``limit`` clips) to
    ``out``; returns ``out``. ``stats``: its normalisation statistics (``write_dataset``'s). Refused before any
    work: an ``out`` that exists (without ``overwrite``), is ``data``, lies inside it or contains it (the write
    would replace the dataset read; issue 54), a ``limit`` or ``workers`` that is no count."""
    if limit is not None:
        check(limit, "--clips", whole=True, minimum=1)
    check(workers, "--workers", whole=True, minimum=0)
    check_out_apart(out, data)
    refuse_existing(out, overwrite=overwrite, flag="--out")
    ds = Dataset.open(data)
    clips = pick_clips(ds, split, limit)
    if len(clips) == 0:
        raise DataError(f"split {split!r} has no clips to reverse", path=ds.root)
    reading, wording = reading_of(ds)
    seed = corpus_seed(ds)
    log(f"reversing {len(clips)} {split} clips of {ds.root}: annotation {reading!r}, wording {wording!r}")
    ids = [ds.ids[int(c)] for c in clips]
    motion = np.empty((len(clips),) + ds.motion.shape[1:], np.float32)

    def chunks():
        # Each chunk's rows come from one contiguous read of the memmap (the split's clips are sorted), not
        # a gather of scattered rows, which on a corpus larger than the free page cache re-reads pages;
        # a thin subset (``limit``) spreads a chunk over most of the corpus, so it gathers its rows instead.
        for s in range(0, len(clips), CHUNK):
            c = clips[s:s + CHUNK]
            if int(c[-1] - c[0]) + 1 <= 4 * len(c):
                block = np.asarray(ds.motion[int(c[0]):int(c[-1]) + 1], np.float32)[c - c[0]]
            else:
                block = np.asarray(ds.motion[c], np.float32)
            motion[s:s + len(c)] = block[:, ::-1]
            yield motion[s:s + len(c)], ids[s:s + CHUNK]

    records, texts = [], []
    fn = functools.partial(_annotate_chunk, reading, wording, seed)
    for recs, txts in map_ordered(fn, chunks(), workers or os.cpu_count() or 1):
        records.extend(recs)
        texts.extend(txts)
    same = float(np.mean([all(t[f][0] == ds.texts[int(c)][f][0] for f in TEXT_FIELDS)
                          for t, c in zip(texts, clips)]))
    source = {"kind": "reversed", "of": str(Path(ds.root).resolve()), "of_fingerprint": ds.fingerprint,
              "split": split, "clips": int(len(clips)), "annotation": reading, "wording": wording, "seed": seed}
    report = {"level0_same_as_forward": same}
    log(f"{same:.1%} of the reversed clips' level-0 captions read as their forward clip's")
    return write_dataset(out, motion, texts, events=records, source=source, report=report, seed=seed,
                         overwrite=overwrite, workers=workers or os.cpu_count() or 1, stats=stats)
