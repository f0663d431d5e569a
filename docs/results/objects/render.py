"""GIFs (and a few PNG stills) of one clip per category and program of a hand–object corpus, for the README.

    JAX_PLATFORMS=cpu .venv/bin/python docs/results/objects/render.py DATASET OUT_DIR

Each GIF is what ``handx data show --data DATASET --clip ID --out X.gif`` writes (synthesis/object_render.py).
"""

import sys
from pathlib import Path

from handx_jax.dataset.format import Dataset
from handx_jax.dataset.render import stills_sheet
from handx_jax.synthesis.object_build import open_object_annotations
from handx_jax.synthesis.object_render import render_object_clip

STILLS = (0, 15, 30, 45)


def main(data, out_dir):
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ds = Dataset.open(data)
    recs = open_object_annotations(data)["objects"]
    seen = set()
    for i, r in enumerate(recs):
        key = (r["category"], r["program"])
        if key in seen:
            continue
        seen.add(key)
        t = ds.texts[i]
        gif = out / f"{r['category']}_{r['program']}.gif"
        render_object_clip(data, i, gif, texts=(t["left"][0], t["right"][0], t["interaction"][0]), title=t["id"],
                           dpi=60)
        sheet = stills_sheet(gif, STILLS)
        sheet.save(out / f"{r['category']}_{r['program']}_frames.png")
        print(gif, r["id"], r.get("use"), [h["template"] for h in r["hands"]])


if __name__ == "__main__":
    main(*sys.argv[1:3])
