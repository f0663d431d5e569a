"""Corpus statistics: size, the paper's Table 1(b) quantities, and caption uniqueness.

Contact quantities follow the dataset contact statistic of reference §5.4 (a frame is in contact if
any inter-hand tip–tip distance < 2 cm or any tip to the other hand's joints 0–15 < 2.5 cm); motion
intensity is the bimanual intensity ω̄ of paper Eq. F (deg/s).
"""

from __future__ import annotations

import functools

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.dataset.clips import ClipConfig, hand_intensity
from handx_jax.dataset.format import Dataset
from handx_jax.annotation.descriptors import contact_frames, contact_segments_stats
from handx_jax.dataset.parallel import map_ordered


def dataset_stats(ds: Dataset, *, chunk: int = 2048, workers: int = 1) -> dict:
    """Corpus summary; per-clip contact and intensity are computed by ``workers`` processes."""
    n = len(ds)
    fps = ds.meta.get("fps", sk.FPS)
    frames = n * ds.meta["clip_len"]
    per_chunk = list(map_ordered(functools.partial(_clip_quantities, str(ds.root / "motion.npy"), fps),
                                 ((s, min(s + chunk, n)) for s in range(0, n, chunk)), workers))
    contact_NxT = (np.concatenate([c for c, _ in per_chunk]) if n
                   else np.zeros((0, ds.meta["clip_len"]), bool))
    intensity = np.concatenate([i for _, i in per_chunk]) if n else np.zeros((0, 2))
    cs = contact_segments_stats(contact_NxT, fps=fps)
    levels = ds.meta.get("levels") or (len(ds.texts[0]["left"]) if n else 0)
    unique = {}
    for lv in range(levels):
        triples = {(t["left"][lv], t["right"][lv], t["interaction"][lv]) for t in ds.texts}
        unique[str(lv)] = round(len(triples) / max(n, 1), 4)
    return {
        "clips": n,
        "hours": round(frames / fps / 3600, 4),
        "frames": frames,
        "texts": int(sum(len(t["left"]) for t in ds.texts)),
        "splits": {k: int(len(v)) for k, v in ds.splits.items()},
        "contact_ratio": round(float(cs["ratio"]), 4),
        "contact_duration_s": round(float(cs["duration_s"]), 4),
        "contact_events_per_min": round(float(cs["events_per_min"]), 4),
        "motion_intensity": round(float(intensity.mean()) if n else 0.0, 2),
        "motion_intensity_per_hand": intensity.mean(0).round(2).tolist() if n else [0.0, 0.0],
        "unique_caption_fraction": unique,
    }


def _clip_quantities(motion_path: str, fps: float, span: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    j = np.asarray(np.load(motion_path, mmap_mode="r")[span[0]:span[1]], dtype=np.float32)
    return contact_frames(j), hand_intensity(j, ClipConfig(fps=fps))


def format_stats(st: dict) -> str:
    lines = [
        f"clips                {st['clips']:,}  (train {st['splits'].get('train', 0):,} / "
        f"val {st['splits'].get('val', 0):,} / test {st['splits'].get('test', 0):,})",
        f"hours                {st['hours']:.3f}   frames {st['frames']:,}",
        f"texts                {st['texts']:,}",
        f"contact ratio        {st['contact_ratio']:.3f}",
        f"contact duration     {st['contact_duration_s']:.3f} s",
        f"contact frequency    {st['contact_events_per_min']:.2f} /min",
        f"motion intensity     {st['motion_intensity']:.1f} deg/s  (L {st['motion_intensity_per_hand'][0]:.1f}, "
        f"R {st['motion_intensity_per_hand'][1]:.1f})",
        "unique caption triples per level: " + ", ".join(
            f"L{k} {v:.3f}" for k, v in st["unique_caption_fraction"].items()),
    ]
    return "\n".join(lines)
