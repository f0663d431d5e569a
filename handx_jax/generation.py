"""What every family's generation shares: prompts, constraint clips from a file or a dataset, and
writing generated motion in the official ``.npz`` layout. Each family samples in its own home
(``families/diffusion/sampling.py``, ``families/ar/decode.py``) behind ``run.generate``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from handx_jax.dataset.format import TEXT_FIELDS
from handx_jax.infra.errors import DataError


@dataclass(frozen=True)
class Prompt:
    left: str
    right: str
    interaction: str
    # The structured record (events.jsonl) the captions were written from, where the prompt comes from a
    # dataset clip and a sampler asks for it (contact guidance from the caption, guidance.py); else None.
    record: dict | None = field(default=None, compare=False, repr=False)

    def texts(self) -> tuple[str, str, str]:
        return self.left, self.right, self.interaction


# ------------------------------------------------------------------------------------------------
# Sources


@dataclass(frozen=True)
class SourceClip:
    key: str
    joints: np.ndarray  # (F, 2, 21, 3)
    prompts: list[Prompt]  # one per annotation level


def load_source(path: str, clip: str | None = None, *, records: bool = False) -> SourceClip:
    """A constraint clip from an official-layout ``.npz`` (``clip`` = key, default the first) or a
    dataset directory (``clip`` = id or index, required). ``records``: a dataset clip's prompts carry its
    structured record (``Prompt.record``; an .npz holds none)."""
    from handx_jax.dataset.format import Dataset
    from handx_jax.interop.handx_npz import read_handx_npz

    p = Path(path)
    if p.is_dir():
        ds = Dataset.open(p)
        if clip is None:
            raise DataError("a dataset source needs --clip (clip id or index)", path=p)
        ids = ds.ids
        i = ids.index(clip) if clip in ids else (int(clip) if str(clip).isdigit() and int(clip) < len(ds) else None)
        if i is None:
            raise DataError(f"no clip {clip!r} in the dataset", path=p)
        t = ds.texts[i]
        ps = [Prompt(*x) for x in zip(t["left"], t["right"], t["interaction"])]
        return SourceClip(ids[i], np.asarray(ds.motion[i], np.float32), with_records(ps, ds, [i] * len(ps)) if records
                          else ps)
    clips = read_handx_npz(p, clip_len=None)
    if not clips:
        raise DataError("archive holds no clips", path=p)
    c = clips[0] if clip is None else next((c for c in clips if c.key == str(clip)), None)
    if c is None:
        raise DataError(f"no key {clip!r} in the archive (keys {[c.key for c in clips[:5]]}…)", path=p)
    return SourceClip(c.key, c.motion, [Prompt(*x) for x in zip(c.left, c.right, c.interaction)])


def with_records(prompts: Sequence[Prompt], ds, clips) -> list[Prompt]:
    """``prompts`` with the structured record (events.jsonl) of their clip attached; a DataError where the
    dataset has no records."""
    import dataclasses

    events = ds.events
    if events is None:
        raise DataError("the dataset has no events.jsonl: its clips carry no structured records", path=ds.root)
    return [dataclasses.replace(p, record=events[int(c)]) for p, c in zip(prompts, clips)]


def check_level(level: int, levels: int, where) -> None:
    """``level`` must index one of the ``levels`` caption levels of the dataset at ``where`` (-1, -2, ...
    count from the most detailed): a ValueError naming ``--level`` otherwise."""
    if isinstance(level, bool) or not isinstance(level, int) or not -levels <= level < levels:
        raise ValueError(f"--level must be in 0..{levels - 1} or -{levels}..-1 (-1 = the most detailed): the dataset "
                         f"{where} has {levels} caption levels, got {level}")


def check_limit(limit: int | None) -> None:
    """``--limit`` of the commands that score or generate a split's clips: None (all) or at least 1."""
    if limit is not None:
        from handx_jax.infra.values import check

        check(limit, "--limit", whole=True, minimum=1, why="or left out: every clip")


def split_prompts(ds, split: str, limit: int | None = None, level: int = -1):
    """Batch mode's prompts (``handx generate --data``, ``handx eval prediction``): the clips of a
    dataset split (at most ``limit``: shuffled with seed 42, the first ``limit`` taken, sorted back, as
    the reference selects its evaluation clips), their captions at ``level`` and their motion.
    Returns (clip indices, prompts, motions (float32, one per clip))."""
    check_limit(limit)
    check_level(level, int(ds.meta["levels"]), ds.root)
    clips = np.asarray(ds.split(split))
    if limit and limit < len(clips):
        clips = np.sort(np.random.default_rng(42).permutation(clips)[:limit])
    prompts = [Prompt(*(ds.texts[c][f][level] for f in TEXT_FIELDS)) for c in clips]
    return clips, prompts, [np.asarray(ds.motion[c], np.float32) for c in clips]


# ------------------------------------------------------------------------------------------------
# Output


def generated_entries(joints_NxTx2x21x3: np.ndarray, prompts: Sequence[Sequence[Prompt]], *,
                      source_clips: Sequence[str | None] | None = None,
                      groups: Sequence[int | None] | None = None) -> list:
    """Generated motion as the official layout's entries (keys "0".."N−1"), what ``read_handx_npz`` of
    :func:`write_generated`'s file returns: scored in memory (``evaluation.evaluate_generated``) or written."""
    from handx_jax.interop.handx_npz import HandXClip

    clips = []
    for i, (j, ps) in enumerate(zip(joints_NxTx2x21x3, prompts)):
        extra = {}
        if source_clips is not None and source_clips[i] is not None:
            extra["source_clip"] = source_clips[i]
        if groups is not None and groups[i] is not None:
            extra["group"] = groups[i]
        clips.append(HandXClip(key=str(i), motion=np.asarray(j, np.float32), left=[p.left for p in ps],
                               right=[p.right for p in ps], interaction=[p.interaction for p in ps], **extra))
    return clips


def write_generated(out: str | Path, joints_NxTx2x21x3: np.ndarray, prompts: Sequence[Sequence[Prompt]], *,
                    source_clips: Sequence[str | None] | None = None, groups: Sequence[int | None] | None = None):
    """Write generated motion in the official layout (keys "0".."N−1"). ``prompts[i]`` is entry i's
    list of prompts (one for a clip; one per segment for long-horizon motion), stored as the three
    annotation lists. ``source_clips``/``groups`` fill the optional evaluation fields."""
    from handx_jax.interop.handx_npz import write_handx_npz

    return write_handx_npz(out, generated_entries(joints_NxTx2x21x3, prompts, source_clips=source_clips,
                                                  groups=groups), clip_len=None)
