"""Is a corpus the standard one, or a prefix of it? The test manifest (the standard test split's clip ids,
caption digests and per-clip motion moments, small enough to ship) and the check against it."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np

# Per-clip motion moments of the test clips are compared with the dataset identity's tolerance
# (data.dataset.MOTION_ATOL, 10 µm): float rounding of another numpy/jax build moves them by ~1e-7 m; any
# change to the generator moves them by millimetres.
from handx_jax.dataset.format import MOTION_ATOL
from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_npz
from handx_jax.standard.assets import MANIFEST, NAME, assets_folder, read_card, version_folder, versions
from handx_jax.standard.recipe import Recipe, recipe_of


def _caption_digest(t: Mapping[str, Any]) -> str:
    blob = json.dumps([t["left"], t["right"], t["interaction"]], ensure_ascii=False, separators=(",", ":"))
    return hashlib.blake2b(blob.encode(), digest_size=8).hexdigest()


def _moments(motion_NxTx2x21x3: np.ndarray) -> np.ndarray:
    """(N, 2, 3, 2) per clip, hand and axis: mean and root-mean-square of the joint coordinates (metres)."""
    m = np.asarray(motion_NxTx2x21x3, np.float64)
    mean = m.mean(axis=(1, 3))
    rms = np.sqrt((m ** 2).mean(axis=(1, 3)))
    return np.stack([mean, rms], -1)


def test_manifest(ds) -> dict[str, np.ndarray]:
    """ids, caption digests and motion moments of ``ds``'s test split, in clip order."""
    clips = np.sort(ds.split("test"))
    moments = np.concatenate([_moments(ds.motion[clips[s:s + 512]]) for s in range(0, len(clips), 512)]) \
        if len(clips) else np.zeros((0, 2, 3, 2))
    return {"ids": np.array([ds.texts[int(c)]["id"] for c in clips]),
            "captions": np.array([_caption_digest(ds.texts[int(c)]) for c in clips]),
            "moments": moments.astype(np.float64)}


def read_manifest(assets: Path | None = None) -> dict[str, np.ndarray]:
    return read_npz(assets_folder(assets) / MANIFEST)


def _other_version(got: Recipe, opts: Mapping[str, Any], assets: Path) -> str:
    """", but it is the recipe of standard evaluator vN: score it with --evaluator standard-vN" when another
    packaged standard evaluator was trained on this recipe (a corpus-v2 prefix scored by v6, say), else ""."""
    for v in versions():
        folder = version_folder(v)
        if folder.resolve() == Path(assets).resolve():
            continue
        card = read_card(folder)
        if card["recipe_options"] == dict(opts) and \
                (card["recipe"]["generator"], card["recipe"]["seed"]) == (got.generator, got.seed):
            return f", but it is the recipe of standard evaluator v{v}: score it with --evaluator {NAME}-v{v}"
    return ""


def check_reference(ds, card: Mapping[str, Any] | None = None, assets: Path | None = None) -> dict:
    """Raise ``DataError`` unless ``ds`` is the standard corpus or a prefix of it; return what was found.

    Accepted: the card's recipe (generator, seed, build options) with at most its clip count, whose
    test clips are the first test clips of the standard split (same ids and captions, motion moments
    within :data:`MOTION_ATOL`) and whose train/val clips include no standard test clip. A content
    hash that differs (another numpy/jax build) is reported, not refused.
    """
    assets = assets_folder(assets)
    card = card if card is not None else read_card(assets)
    want = Recipe.from_card(card["recipe"])
    got, opts = recipe_of(ds)
    fix = (f"build it with `handx standard corpus --out DIR` (or `--clips M` for a prefix), or score with "
           f"your own evaluator (`--evaluator E`)")
    if got is None:
        raise DataError(f"not the standard corpus: its recipe {(ds.meta.get('recipe') or {}).get('kind')!r} is "
                        f"not the built-in generator's; {fix}", path=ds.root / "meta.json")
    for name, a, b in (("generator version", got.generator, want.generator), ("seed", got.seed, want.seed)):
        if a != b:
            raise DataError(f"not the standard recipe: {name} {a} where the standard evaluator (v{card['version']}) "
                            f"was trained on {b}; {fix}", path=ds.root / "meta.json")
    want_opts = card["recipe_options"]
    diff = sorted(k for k in set(opts) | set(want_opts) if opts.get(k) != want_opts.get(k))
    if diff:
        raise DataError(f"not the standard recipe: build option(s) {diff} differ from the standard's "
                        f"(v{card['version']}){_other_version(got, opts, assets)}; {fix}", path=ds.root / "meta.json")
    if got.clips > want.clips:
        raise DataError(f"{got.clips} clips: more than the standard corpus's {want.clips}, so its test split is not "
                        f"the standard one; {fix}", path=ds.root / "meta.json")
    man = read_manifest(assets)
    mine = test_manifest(ds)
    k = len(mine["ids"])
    if k == 0:
        raise DataError("the test split is empty", path=ds.root / "splits.json")
    if k > len(man["ids"]) or not np.array_equal(mine["ids"], man["ids"][:k]):
        bad = next((i for i in range(min(k, len(man["ids"]))) if mine["ids"][i] != man["ids"][i]), k)
        raise DataError(f"test split is not the standard one: test clip {bad} is {mine['ids'][min(bad, k - 1)]!r}, "
                        f"expected {man['ids'][bad] if bad < len(man['ids']) else 'none'}; {fix}",
                        path=ds.root / "splits.json")
    if got.clips == want.clips:  # the whole corpus: the data package's identity check (every split, caption)
        from handx_jax.dataset.format import check_compatible

        check_compatible(card["corpus"]["record"], ds, what=f"the standard evaluator v{card['version']}", fix=fix)
    cap = np.flatnonzero(mine["captions"] != man["captions"][:k])
    if cap.size:
        raise DataError(f"captions differ from the standard corpus's ({cap.size} test clips; first "
                        f"{mine['ids'][cap[0]]}); {fix}", path=ds.root / "texts.jsonl", clip=mine["ids"][cap[0]])
    dev = np.abs(mine["moments"] - man["moments"][:k]).reshape(k, -1).max(1)
    if (dev > MOTION_ATOL).any():
        i = int(np.argmax(dev))
        raise DataError(f"motion differs from the standard corpus's by {dev[i]:.2e} m (tolerance {MOTION_ATOL:g}); "
                        f"{fix}", path=ds.root / "motion.npy", clip=mine["ids"][i])
    test_ids = set(man["ids"].tolist())
    for split in ("train", "val"):
        overlap = [ds.texts[int(c)]["id"] for c in ds.split(split) if ds.texts[int(c)]["id"] in test_ids]
        if overlap:
            raise DataError(f"{len(overlap)} {split} clip(s) are standard test clips (first {overlap[0]}): the "
                            f"standard evaluator would score clips it may have been trained beside; {fix}",
                            path=ds.root / "splits.json")
    return {"prefix": got.clips < want.clips, "clips": got.clips, "test_clips": k,
            "fingerprint": ds.fingerprint, "standard_fingerprint": card["corpus"]["fingerprint"],
            "same_bytes": ds.fingerprint == card["corpus"]["fingerprint"] and got.clips == want.clips,
            "max_motion_deviation_m": float(dev.max())}
