"""An 8-clip dataset written directly (``write_dataset``, no synthesis): small random motion, two caption
levels, 4/2/2 clips in train/val/test. For the bad-input tests of the commands that read a dataset: it opens
like any dataset and costs a fraction of a second to write."""

from pathlib import Path

import numpy as np


def write_tiny_dataset(out: Path) -> Path:
    from handx_jax import skeleton as sk
    from handx_jax.dataset.format import write_dataset

    n = 8
    motion = (np.random.default_rng(0).normal(size=(n, sk.CLIP_LEN, 2, sk.NUM_JOINTS, 3)) * 0.01).astype(np.float32)
    texts = [{"id": f"c{i}", "left": [f"left {i}", "left"], "right": ["right", "right"],
              "interaction": ["apart", "apart"]} for i in range(n)]
    return write_dataset(out, motion, texts, splits={"train": [0, 1, 2, 3], "val": [4, 5], "test": [6, 7]},
                         workers=1)
