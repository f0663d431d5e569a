"""Caption stability: what the annotation pipeline (events → captions) does under a perturbation.

For every clip the clean and the perturbed motion are annotated with the same ``AnnotationConfig``
and captioned with the same captioner and per-clip seed (the corpus's). Reported per perturbation:

- ``events_unchanged``: the share of DESCRIPTOR EVENT LISTS whose labels come out identical: the
  sequence of states, speeds and directions (one list per descriptor key of the record, e.g. the left
  index PIP's flexing events or one inter-hand tip pair's contacts; a key present in either record
  counts, a contact pair that never touches is an empty list). Frames are left out: they move by a
  frame under any noise and only the detailed levels quote them;
- ``events_exact_unchanged``: the same share with the frames (and wrist displacements) compared too;
- ``records_unchanged``: the share of clips whose whole record is identical;
- ``captions_unchanged[level]``: the share of clips whose three texts at that level are all identical.
"""

from __future__ import annotations

import json
from typing import Sequence

import numpy as np

from handx_jax.dataset.build import caption_seed
from handx_jax.annotation.caption import LEVELS, TemplateCaptioner
from handx_jax.annotation.events import AnnotationConfig, annotate

_FIELDS = ("left", "right", "interaction")


_TIMING = ("start", "end", "displacement_m")


def _event_lists(record: dict):
    """(path, event list) of every descriptor of a record."""
    for top, groups in record.items():
        if isinstance(groups, dict):
            for group, lists in groups.items():
                for key, evs in lists.items():
                    yield f"{top}/{group}/{key}", evs


def descriptor_lists(record: dict, *, labels_only: bool = False) -> dict[str, str]:
    """Every descriptor's event list of a record, as canonical JSON keyed by its path; with
    ``labels_only`` each event keeps only its labels (states, speed, direction)."""
    return {path: json.dumps([{k: v for k, v in e.items() if k not in _TIMING} for e in evs] if labels_only else evs,
                             sort_keys=True) for path, evs in _event_lists(record)}


def captions(records: Sequence[dict], ids: Sequence[str], seed: int, captioner=None) -> list[list[tuple]]:
    """``[clip][level] -> (left, right, interaction)`` with the corpus's per-clip caption seeds."""
    cap = captioner or TemplateCaptioner()
    out = []
    for rec, cid in zip(records, ids):
        lv = cap.caption(rec, seed=caption_seed(seed, cid))
        out.append([tuple(l[f] for f in _FIELDS) for l in lv])
    return out


def compare(clean: Sequence[dict], pert: Sequence[dict], caps_a, caps_b) -> dict:
    """The shares of unchanged descriptor lists, records and captions per level."""
    same_lab = same_exact = total = same_rec = 0
    for a, b in zip(clean, pert):
        da, db = descriptor_lists(a), descriptor_lists(b)
        la, lb = descriptor_lists(a, labels_only=True), descriptor_lists(b, labels_only=True)
        keys = set(da) | set(db)
        exact = sum(da.get(k, "[]") == db.get(k, "[]") for k in keys)
        same_exact += exact
        same_lab += sum(la.get(k, "[]") == lb.get(k, "[]") for k in keys)
        total += len(keys)
        same_rec += exact == len(keys)
    n = max(len(clean), 1)
    per_level = [float(np.mean([ca[l] == cb[l] for ca, cb in zip(caps_a, caps_b)])) for l in range(LEVELS)]
    return {"events_unchanged": same_lab / max(total, 1), "events_exact_unchanged": same_exact / max(total, 1),
            "records_unchanged": same_rec / n, "captions_unchanged": per_level}


class Annotator:
    """Annotate and caption clips with one config; the clean clips' results are computed once."""

    def __init__(self, clean_NxTx2x21x3: np.ndarray, ids: Sequence[str], seed: int,
                 cfg: AnnotationConfig = AnnotationConfig(), captioner=None):
        self.cfg, self.ids, self.seed, self.captioner = cfg, list(ids), int(seed), captioner
        self.clean_records = annotate(clean_NxTx2x21x3, cfg)
        self.clean_captions = captions(self.clean_records, self.ids, self.seed, captioner)

    def records_and_captions(self, x_NxTx2x21x3: np.ndarray):
        recs = annotate(x_NxTx2x21x3, self.cfg)
        return recs, captions(recs, self.ids, self.seed, self.captioner)

    def against_clean(self, x_NxTx2x21x3: np.ndarray) -> dict:
        recs, caps = self.records_and_captions(x_NxTx2x21x3)
        return compare(self.clean_records, recs, self.clean_captions, caps)


def variety(records: Sequence[dict], caps: Sequence[Sequence[tuple]]) -> dict:
    """How varied a set of clean annotations is: events per clip (non-constant events over every
    descriptor) and the share of distinct captions per level (over the three texts joined)."""
    n_ev = []
    for r in records:
        n_ev.append(sum(1 for _, evs in _event_lists(r) for e in evs
                        if not ("state" in e and e.get("start") == 0 and e.get("end") == r["frame_count"]
                                and e["state"] != "contact")))
    distinct = [len({c[l] for c in caps}) / max(len(caps), 1) for l in range(LEVELS)]
    return {"events_per_clip": float(np.mean(n_ev)) if n_ev else 0.0, "distinct_captions": distinct}

