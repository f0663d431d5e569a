"""Evaluator inputs: the text policy, motion features and their normalisation, the joined caption,
and the (clip, level) training items (paper E.2; reference §5.1–§5.3)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from handx_jax import representation as rep
from handx_jax.infra.errors import DataError
from handx_jax.text.cache import bucket_length

JOINED = "joined"


@dataclass(frozen=True)
class TextPolicy:
    """Which captions the evaluator sees. ``train_levels=None`` means every level of the dataset.

    ``max_len`` truncates the joined caption (first max_len−1 tokens + eos, as the cache and Hugging
    Face do); the truncated fraction is recorded at training time. ``eval_level`` indexes the level
    lists (negative from the end, −1 = most detailed, 0 = most concise).
    """

    max_len: int = 256
    train_levels: tuple[int, ...] | None = None
    eval_level: int = 0
    cache_dtype: str = "float16"
    # The caption string (``joined_caption``): "sentinels" (this project's, with T5's real sentinels) or
    # "official" (the official run_evaluation.py's ``<extra_id0> …``, used by imported official evaluators).
    caption: str = "sentinels"



def motion_features(joints_NxTx2x21x3: np.ndarray, stats: rep.NormStats, kind: str = "positions") -> np.ndarray:
    """Evaluator input ``(N, T, F)`` float32, then z-scored. ``kind`` "positions": per-frame right-wrist
    centring (§5.3, F = 126); "hand_frames": those plus derived features (F = 307)."""
    fn, _ = rep.EVALUATOR_INPUTS[kind]
    x = fn(np.asarray(joints_NxTx2x21x3, np.float32))
    return np.asarray(stats.normalize(x), np.float32)


STATS_CLIPS = 4096  # clips (evenly spaced over the train split) behind the "hand_frames" statistics


def evaluator_stats(ds, kind: str = "positions", clips: np.ndarray | None = None) -> rep.NormStats:
    """Normalisation of the evaluator input. "positions": the dataset's ``evaluator_mean/std`` (train
    split, written at build time). Other inputs: mean/std over frames of up to :data:`STATS_CLIPS`
    evenly spaced ``clips`` (default the train split); constant features (e.g. the middle MCP's
    local y, z, zero by construction) get std 1. Stored with the evaluator, so evaluation reuses them."""
    if kind == "positions":
        return rep.NormStats.from_npz_dict(ds.stats, "evaluator", path=ds.root / "stats.npz")
    clips = np.sort(np.asarray(ds.split("train") if clips is None else clips, np.int64))
    if len(clips) == 0:
        raise DataError("no clips to compute evaluator input statistics from", path=ds.root)
    pick = clips[np.unique(np.linspace(0, len(clips) - 1, min(len(clips), STATS_CLIPS)).round().astype(np.int64))]
    fn, _ = rep.EVALUATOR_INPUTS[kind]
    # Streamed 256 clips at a time (4,096 clips of 307 float64 features would be 600 MB at once), with
    # the positions preset's std floor.
    chunks = (fn(np.asarray(ds.motion[pick[s:s + 256]], np.float32)) for s in range(0, len(pick), 256))
    return rep.compute_norm_stats(chunks, axis=(0, 1), min_std=rep.EVALUATOR_NORM.min_std)


CAPTION_STYLES = ("sentinels", "official")


def joined_caption(left: str, right: str, interaction: str, style: str = "sentinels") -> str:
    """The evaluator's caption. "sentinels": reference §5.3 with real sentinels, identical to the joined
    cache's. "official": the string the official run_evaluation.py builds (reference §5.5), whose markers
    ``<extra_id0>`` … have no underscore, so T5's tokenizer splits them as plain text."""
    from handx_jax.text.tokenizer import join_fields, sentinel

    if style == "official":
        return f"<extra_id0> {left} <extra_id1> {right} <extra_id2> {interaction} <extra_id3>"
    if style != "sentinels":
        raise ValueError(f"unknown caption style {style!r}; choose from {CAPTION_STYLES}")
    return f"{join_fields(left, right, interaction)} {sentinel(3)}"


def _level_index(level: int, levels: int) -> int:
    if not -levels <= level < levels:
        raise ValueError(f"level {level} out of range for {levels} levels")
    return level % levels


def caption_ids(ds, clips: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """One int64 per (clip, level): equal ⟺ the three captions are identical (an 8-byte digest of them),
    so identical captions are recognised across datasets (a corpus and its reversed copy)."""
    out = np.empty(len(clips), np.int64)
    for i, (c, lv) in enumerate(zip(np.asarray(clips).tolist(), np.asarray(levels).tolist())):
        t = ds.texts[c]
        key = "\x1f".join(t[f][lv] for f in ("left", "right", "interaction")).encode()
        out[i] = int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "little", signed=True)
    return out


class TrainingData:
    """(clip, level) items of one split: motion from the dataset memmap, text from the joined cache.

    ``companion``: (dataset, its joined cache) of extra training pairs (``data.reverse``: the split's
    clips played backwards with their own captions); each item is replaced by a random companion item
    with probability ``companion_share`` (a pure function of (seed, the batch's indices): exact resume);
    with ``companion_pairs`` the last share of the batch is instead the reversals of its first items.
    The companion's motion is normalised with this corpus's ``stats``."""

    def __init__(self, ds, cache, stats: rep.NormStats, clips: np.ndarray, levels: Sequence[int], seed: int,
                 text_bucket: int = 16, motion_input: str = "positions", *, augment_white_m: float = 0.0,
                 augment_lowfreq_m: float = 0.0, reversed_copy: bool = False, text_ids: bool = False,
                 companion: tuple | None = None, companion_share: float = 0.0, companion_pairs: bool = False,
                 hard_negatives: Sequence[str] = ()):
        self.ds, self.cache, self.stats = ds, cache, stats
        self.hard_negatives = tuple(hard_negatives)
        self.augment_white_m, self.augment_lowfreq_m = float(augment_white_m), float(augment_lowfreq_m)
        self.reversed_copy, self.text_ids = bool(reversed_copy), bool(text_ids)
        self.companion = companion if companion_share > 0 else None
        self.companion_share = float(companion_share)
        self.companion_pairs = bool(companion_pairs)
        if self.companion is not None:  # which companion clip is which source clip's reversal
            where = {cid: i for i, cid in enumerate(ds.ids)}
            src = [where.get(cid.rsplit("~", 1)[0], -1) for cid in self.companion[0].ids]
            self._comp_src = np.asarray(src, np.int64)
            self._rev_of = np.full(len(ds), -1, np.int64)
            ok = self._comp_src >= 0
            self._rev_of[self._comp_src[ok]] = np.flatnonzero(ok)
        self.motion_input = motion_input
        self.clips = np.asarray(clips, np.int64)
        self.levels = np.asarray(levels, np.int64)
        self.seed = int(seed)
        self.text_bucket = int(text_bucket)

    def __len__(self) -> int:
        return len(self.clips)

    def item_levels(self, idx: np.ndarray) -> np.ndarray:
        """One random level per sample, a pure function of (seed, the batch's indices): exact resume."""
        rng = np.random.default_rng([self.seed, 0x1E7, *np.asarray(idx, np.int64).tolist()])
        return self.levels[rng.integers(0, len(self.levels), len(idx))]

    @staticmethod
    def _read(ds, cache, clips: np.ndarray, levels: np.ndarray):
        order = np.argsort(clips, kind="stable")  # sorted memmap reads
        joints = np.empty((len(clips),) + ds.motion.shape[1:], np.float32)
        joints[order] = ds.motion[clips[order]]
        h, m = cache.lookup(clips, JOINED, levels)
        return joints, np.asarray(h), np.asarray(m)

    def batch(self, idx: np.ndarray, levels: np.ndarray | None = None) -> dict[str, np.ndarray]:
        clips = self.clips[np.asarray(idx)]
        levels = self.item_levels(idx) if levels is None else np.array(levels)  # a copy: pairing edits it
        from_comp = None
        if self.companion is None:
            joints, h, m = self._read(self.ds, self.cache, clips, levels)
            ids = caption_ids(self.ds, clips, levels) if self.text_ids else None
        else:
            joints, h, m, ids, from_comp = self._mix(idx, clips, levels)
        # Trim the text to the batch's longest caption, rounded up to a multiple of ``text_bucket`` tokens:
        # concise levels then cost a fraction of Lmax, and at most Lmax/bucket step shapes are compiled.
        # Masking makes the loss independent of the padding; on an accelerator, where each new shape
        # is a compile of the whole step, pass a bucket ≥ Lmax (one shape).
        Lb = bucket_length(int(m.sum(1).max()), max(self.text_bucket, 1), m.shape[1])
        if self.augment_white_m > 0 or self.augment_lowfreq_m > 0:
            joints = self._augment(joints, idx)
        out = {"motion": motion_features(joints, self.stats, self.motion_input), "text": np.asarray(h[:, :Lb], np.float32),
               "text_mask": np.asarray(m[:, :Lb], bool)}
        if self.reversed_copy:
            out["motion_rev"] = motion_features(np.ascontiguousarray(joints[:, ::-1]), self.stats, self.motion_input)
            if from_comp is not None and ids is not None:
                out["rev_same_text"] = self._reversal_reads_the_same(clips, levels, ids, from_comp)
        if self.hard_negatives:
            out["motion_hard"], out["hard_same_text"] = self._hard(joints, idx, clips, levels, from_comp)
        if ids is not None:
            out["text_id"] = ids
        return out

    def _hard(self, joints, idx, clips, levels, from_comp):
        """Each item's edits (``hard_negatives``, validity.perturb kinds) as motion features ``(B, K, T, F)``,
        from a stream that is a pure function of (seed, the batch's indices): exact resume; and ``(B, K)``: the
        edits known to read as the item's own caption (``perturb.reads_the_same``), left out of its negatives."""
        from handx_jax.validity import perturb as P

        feats, same = [], np.zeros((len(clips), len(self.hard_negatives)), bool)
        for k, kind in enumerate(self.hard_negatives):
            rng = np.random.default_rng([self.seed, 0x4A2D, k, *np.asarray(idx, np.int64).tolist()])
            feats.append(motion_features(P.KINDS[kind].fn(joints, 0.0, rng), self.stats, self.motion_input))
        for i, (c, lv) in enumerate(zip(np.asarray(clips).tolist(), np.asarray(levels).tolist())):
            comp = from_comp is not None and from_comp[i] >= 0
            t = self.companion[0].texts[int(from_comp[i])] if comp else self.ds.texts[c]
            for k, kind in enumerate(self.hard_negatives):
                same[i, k] = P.reads_the_same(kind, t["left"][lv], t["right"][lv], t["interaction"][lv], lv)
        return np.stack(feats, axis=1), same

    def _mix(self, idx, clips, levels):
        """The batch with a ``companion_share`` of its items taken from the companion (same levels): random
        companion items, or with ``companion_pairs`` the reversals of the batch's first items. Only the
        items that stay are read from this corpus, only the taken ones from the companion."""
        cds, ccache = self.companion
        if self.companion_pairs:
            take, cclips = self._pairs(idx, levels)
        else:
            rng = np.random.default_rng([self.seed, 0xC0A, *np.asarray(idx, np.int64).tolist()])
            take = np.flatnonzero(rng.random(len(idx)) < self.companion_share)
            cclips = rng.integers(0, len(cds), len(take))
        keep = np.setdiff1d(np.arange(len(idx)), take)
        parts = [(keep, self._read(self.ds, self.cache, clips[keep], levels[keep]))]
        if len(take):
            parts.append((take, self._read(cds, ccache, cclips, levels[take])))
        L = max(h.shape[1] for _, (_, h, _) in parts)  # the two caches' Lmax may differ: pad to the longer
        j0, h0, m0 = parts[0][1]
        joints = np.empty((len(idx),) + j0.shape[1:], j0.dtype)
        h = np.zeros((len(idx), L) + h0.shape[2:], h0.dtype)
        m = np.zeros((len(idx), L), m0.dtype)
        for where, (pj, ph, pm) in parts:
            joints[where], h[where, :ph.shape[1]], m[where, :pm.shape[1]] = pj, ph, pm
        ids = None
        if self.text_ids:
            ids = np.empty(len(idx), np.int64)
            ids[keep] = caption_ids(self.ds, clips[keep], levels[keep])
            if len(take):
                ids[take] = caption_ids(cds, cclips, levels[take])
        from_comp = np.full(len(idx), -1, np.int64)
        from_comp[take] = cclips
        return joints, h, m, ids, from_comp

    def _pairs(self, idx, levels):
        """Paired mode: the last ``round(share · B)`` items become the reversals of the first ones (each with
        its partner's caption level), so a clip and its own reversal meet in one batch with their two
        captions: the contrast that carries the order of events. A partner the companion does not hold
        keeps its own item."""
        B = len(idx)
        k = min(int(round(self.companion_share * B)), B // 2)
        partners = self.clips[np.asarray(idx)[:k]]
        rev = self._rev_of[partners]
        take = np.arange(B - k, B)[rev >= 0]
        levels[take] = levels[:k][rev >= 0]
        return take, rev[rev >= 0]

    def _reversal_reads_the_same(self, clips, levels, ids, from_comp) -> np.ndarray:
        """Per item: is its reversal's caption its own (then the reversal is no negative of its text)? A
        forward clip's reversal is read from the companion, a companion clip's from its source clip; a
        forward clip the companion does not hold counts as different (v5's assumption)."""
        cds = self.companion[0]
        same = np.zeros(len(clips), bool)
        comp = from_comp >= 0
        if comp.any():  # reversal of a reversed clip: the source clip, with the source's caption
            src = self._comp_src[from_comp[comp]]
            known = src >= 0
            rid = caption_ids(self.ds, src[known], levels[comp][known])
            same[np.flatnonzero(comp)[known]] = rid == ids[comp][known]
        fwd = np.flatnonzero(~comp)
        r = self._rev_of[clips[fwd]]
        known = r >= 0
        if known.any():
            rid = caption_ids(cds, r[known], levels[fwd][known])
            same[fwd[known]] = rid == ids[fwd][known]
        return same

    def _augment(self, joints: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Caption-preserving noise on the finger joints (validity.perturb), per-clip amplitudes, drawn
        from a stream that is a pure function of (seed, the batch's indices): exact resume."""
        from scipy.ndimage import gaussian_filter1d

        rng = np.random.default_rng([self.seed, 0xA06, *np.asarray(idx, np.int64).tolist()])
        N = len(joints)
        y = joints.copy()
        fingers = y[..., 1:, :]
        if self.augment_white_m > 0:
            a = rng.uniform(0, self.augment_white_m, N).astype(np.float32)[:, None, None, None, None]
            fingers += a * rng.standard_normal(fingers.shape).astype(np.float32)
        if self.augment_lowfreq_m > 0:
            n = gaussian_filter1d(rng.standard_normal(fingers.shape), 4.0, axis=1, mode="reflect")
            n /= np.sqrt(np.mean(n * n, axis=(1, 2, 3, 4), keepdims=True)) + 1e-12
            a = rng.uniform(0, self.augment_lowfreq_m, N)[:, None, None, None, None]
            fingers += (a * n).astype(np.float32)
        y[..., 1:, :] = fingers
        return y
