"""``make demo``: the main job on the built-in data.

Builds a small procedural corpus (synthesis → clips + intensity filter → annotation → captions),
prints its statistics, and renders one clip with its three texts as a GIF. Later stages (text
encoder, generators, evaluation) extend this script as they land.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="runs/demo", help="demo folder (rebuilt each time)")
    p.add_argument("--clips", type=int, default=600)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)

    from handx_jax.data.build import BuildConfig, build_corpus
    from handx_jax.data.caption import build_prompt
    from handx_jax.data.dataset import Dataset
    from handx_jax.data.render import render_gif
    from handx_jax.data.stats import dataset_stats, format_stats
    from handx_jax.io import atomic_write_json, atomic_write_text

    out = Path(a.out)
    t0 = time.perf_counter()
    data_dir = build_corpus(out / "data", BuildConfig(clips=a.clips, seed=a.seed), overwrite=True)
    ds = Dataset.open(data_dir)
    print(f"\n== corpus: {data_dir} ({len(ds)} clips, built in {time.perf_counter() - t0:.1f} s)")
    rep = ds.report["clips"]
    print(f"cut report: {rep['sequences']} sequences, {rep['windows']} windows; defective frames "
          f"{rep['defective_frames']}; rejected by intensity {rep['rejected_intensity']}; kept {rep['kept']}")
    st = dataset_stats(ds)
    print(format_stats(st))
    atomic_write_json(out / "stats.json", st)

    i = int(np.argmax([len(t["interaction"][-1]) for t in ds.texts[:50]]))  # a clip with a rich interaction
    t = ds.texts[i]
    print(f"\n== clip {t['id']} — captions by level")
    for lv in range(len(t["left"])):
        print(f"[L{lv}] left: {t['left'][lv]}\n      right: {t['right'][lv]}\n      both: {t['interaction'][lv]}")
    gif = render_gif(np.asarray(ds.motion[i]), out / "clip.gif",
                     texts=(t["left"][0], t["right"][0], t["interaction"][0]), title=t["id"])
    atomic_write_text(out / "prompt.txt", build_prompt(ds.events[i]))
    print(f"\nwrote {gif}, {out / 'prompt.txt'} (LLM prompt for that clip), {out / 'stats.json'}")
    print(json.dumps({"clips": st["clips"], "contact_ratio": st["contact_ratio"],
                      "unique_level4": st["unique_caption_fraction"].get(str(len(t['left']) - 1))}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
