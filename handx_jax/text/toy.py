"""A seconds-sized caption dataset for the text stack's tests and benchmarks (not the corpus builder).

Captions follow the dataset's shape: per clip, ``left``/``right``/``interaction`` lists of 5 levels,
index 0 the most concise. A small random grammar gives enough distinct captions to train a tokenizer
and to see a span-corruption loss fall within a few dozen steps. Motion is zeros: nothing here reads it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

FINGERS = ["thumb", "index finger", "middle finger", "ring finger", "little finger", "fingers"]
ACTIONS = ["flexes", "extends", "curls", "spreads", "taps", "bends slightly", "straightens", "holds still"]
SPEEDS = ["slowly", "quickly", "steadily", "smoothly", "abruptly"]
WRIST = ["rotates outward", "rotates inward", "tilts upward", "tilts downward", "stays level"]
RELATIONS = ["move toward each other", "drift apart", "touch at the fingertips", "stay parallel",
             "cross over", "hover close together", "press palm to palm", "mirror each other"]
TIMES = ["at the start", "midway", "near the end", "throughout the clip", "twice"]


def _hand(rng: np.random.Generator, side: str) -> list[str]:
    f, a, s, w, t = (rng.choice(x) for x in (FINGERS, ACTIONS, SPEEDS, WRIST, TIMES))
    f2, a2 = rng.choice(FINGERS), rng.choice(ACTIONS)
    return [
        f"{side} {f} {a}",
        f"the {side} hand's {f} {a} {s}",
        f"the {side} hand's {f} {a} {s} while the wrist {w}",
        f"the {side} hand's {f} {a} {s} {t}, and the wrist {w}",
        f"the {side} hand's {f} {a} {s} {t}; then the {f2} {a2} as the wrist {w} and the palm faces forward",
    ]


def _interaction(rng: np.random.Generator) -> list[str]:
    r, s, t, r2 = rng.choice(RELATIONS), rng.choice(SPEEDS), rng.choice(TIMES), rng.choice(RELATIONS)
    return [
        f"hands {r}",
        f"the hands {r} {s}",
        f"the two hands {r} {s} {t}",
        f"the two hands {r} {s} {t}, then {r2}",
        f"the two hands {r} {s} {t}, then they {r2} while both wrists stay relaxed and the fingers keep moving",
    ]


def toy_texts(num_clips: int, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    return [{"id": f"toy{i:05d}", "left": _hand(rng, "left"), "right": _hand(rng, "right"),
             "interaction": _interaction(rng)} for i in range(num_clips)]


def write_toy_dataset(out: str | os.PathLike, num_clips: int = 64, seed: int = 0, *, val_frac: float = 0.25,
                      overwrite: bool = False) -> Path:
    from handx_jax.dataset.format import write_dataset

    texts = toy_texts(num_clips, seed)
    n_val = int(round(val_frac * num_clips))
    idx = np.random.default_rng([seed, 1]).permutation(num_clips)
    splits = {"train": sorted(idx[n_val:].tolist()), "val": sorted(idx[:n_val].tolist()), "test": []}
    motion = np.zeros((num_clips, 60, 2, 21, 3), np.float32)
    return write_dataset(out, motion, texts, splits=splits, stats=False, overwrite=overwrite,
                         source={"kind": "toy captions (handx_jax.text.toy)", "seed": seed})
