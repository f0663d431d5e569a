"""Official HandX ``.npz`` ⇄ handx-jax dataset.

Import: every clip of the given files becomes a dataset clip; its split is taken from the file name
(``train_*`` → train, ``test_*`` → test; the official code uses the test file as validation, reference
§1.4, so val = test unless the user gives a separate val file). Clips with non-finite frames cannot be
windowed inside 60 frames, so they are dropped and counted in the report (paper A.3). Events are
computed with the annotation pipeline so imported data has the same records as the built-in corpus.

Export writes the official layout (keys "0", "1", …) so the file can be shared or read by the
official loaders; export → import reproduces motion and texts exactly.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from handx_jax.dataset.format import DEFAULT_FRACTIONS, Dataset, write_dataset
from handx_jax.interop.handx_npz import HandXClip, read_handx_npz, write_handx_npz
from handx_jax.infra.checksums import sha256_file
from handx_jax.infra.errors import DataError
from handx_jax.infra.outputs import check_out_apart, refuse_existing


def split_from_filename(path: Path) -> str:
    name = path.name.lower()
    for split in ("train", "val", "test"):
        if name.startswith(split):
            return split
    raise DataError("cannot tell the split from the file name (expected train_*, val_* or test_*); "
                    "pass --split", path=path)


def import_handx(files: Sequence[str | os.PathLike], out: str | os.PathLike, *, split: str | None = None,
                 annotate_events: bool = True, fractions=DEFAULT_FRACTIONS, seed: int = 0,
                 overwrite: bool = False, stats=True) -> Path:
    """The clips of the official ``files`` as a dataset at ``out``; ``stats``: its normalisation statistics
    (``write_dataset``'s)."""
    for f in files:  # --force replaces --out whole: never onto (or around) the files it reads
        check_out_apart(out, f, data_flag="the input file")
    refuse_existing(out, overwrite=overwrite, flag="--out")  # before reading every file, not after
    motions, texts, split_of = [], [], []
    dropped: dict[str, list[str]] = {}
    seen_ids: set[str] = set()
    levels: tuple[int, str] | None = None  # (caption levels, "file:key" of the first clip)
    for f in map(Path, files):
        s = split or split_from_filename(f)
        for c in read_handx_npz(f, allow_nonfinite=True):
            cid = f"{f.stem}:{c.key}"
            if cid in seen_ids:
                raise DataError(f"duplicate clip key {c.key!r}", path=f, clip=c.key)
            seen_ids.add(cid)
            # Level k must mean the same on every clip (training samples a level index, `data stats` counts
            # per level): a clip with another count is refused here, naming it, not an IndexError later.
            if levels is None:
                levels = (len(c.left), f"{f.name}:{c.key}")
            elif len(c.left) != levels[0]:
                raise DataError(f"{len(c.left)} caption levels, but clip {levels[1]} has {levels[0]}; every clip "
                                "needs the same number of levels", path=f, clip=c.key)
            if not np.isfinite(c.motion).all():
                dropped.setdefault(str(f), []).append(c.key)
                continue
            motions.append(c.motion.astype(np.float32))
            texts.append({"id": cid, "left": list(c.left), "right": list(c.right),
                          "interaction": list(c.interaction)})
            split_of.append(s)
    if not motions:
        raise DataError("no usable clips in the given files", path=", ".join(map(str, files)))
    lens = {len(m) for m in motions}
    if len(lens) != 1:
        raise DataError(f"clips have different lengths {sorted(lens)}", path=", ".join(map(str, files)))
    motion = np.stack(motions)
    splits = {k: [i for i, s in enumerate(split_of) if s == k] for k in ("train", "val", "test")}
    if not splits["val"] and splits["test"]:
        splits_val_is_test = True
    else:
        splits_val_is_test = False
    events = None
    if annotate_events:
        from handx_jax.annotation.events import annotate
        events = [e for s in range(0, len(motion), 1024) for e in annotate(motion[s:s + 1024])]
    report = {"dropped_nonfinite_clips": {k: len(v) for k, v in dropped.items()},
              "dropped_keys": dropped, "imported": len(motion)}
    source = {"kind": "handx-npz", "files": [str(Path(f).resolve()) for f in files],
              "val_is_test": splits_val_is_test}
    # The recipe names the archives by content, not path: the same files imported anywhere are one dataset.
    recipe = {"kind": "handx-npz", "files": [{"name": Path(f).name, "sha256": sha256_file(f)} for f in files],
              "split": split, "events": bool(annotate_events), "fractions": list(fractions), "seed": seed}
    return write_dataset(out, motion, texts, splits=splits, events=events, source=source, report=report,
                         fractions=fractions, seed=seed, overwrite=overwrite, recipe=recipe,
                         stats=stats)


def export_handx(data_dir: str | os.PathLike, out: str | os.PathLike, *, split: str | None = None) -> Path:
    check_out_apart(out, data_dir, replaces=False)  # --out D/motion.npy would replace the dataset's own file
    ds = Dataset.open(data_dir)
    idx = np.arange(len(ds)) if split in (None, "all") else ds.split(split)
    clips = []
    for k, i in enumerate(idx.tolist()):
        t = ds.texts[i]
        clips.append(HandXClip(key=str(k), motion=np.asarray(ds.motion[i], dtype=np.float32),
                               left=list(t["left"]), right=list(t["right"]), interaction=list(t["interaction"])))
    write_handx_npz(out, clips)
    return Path(out)
