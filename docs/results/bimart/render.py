"""GIFs and PNG stills of generated hands (the full pipeline: contact map, guidance, refinement) on given clips.

    JAX_PLATFORMS=cpu .venv/bin/python docs/results/bimart/render.py --run RUN --data OBJ --clips 27,2,130 --out DIR

Each GIF shows the generated hands with the clip's object (synthesis/object_render.py's scene, as ``handx data
show`` draws a corpus clip), beside the ground truth's stills for comparison.
"""

import argparse
from pathlib import Path

import numpy as np

from handx_jax.dataset.render import render_gif, stills_sheet
from handx_jax.families.bimart import GenerateOptions, load
from handx_jax.families.bimart import common as C
from handx_jax.synthesis.object_build import clip_object
from handx_jax.synthesis.object_render import object_scene

STILLS = (0, 15, 30, 45)


def _stills(gif: Path):
    return stills_sheet(gif, STILLS)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--clips", required=True, help="comma-separated clip indices")
    ap.add_argument("--out", required=True)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override the run's sample config (repeatable)")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    run = load(a.run, overrides=a.set)
    clips = np.asarray([int(c) for c in a.clips.split(",")])
    data = C.prepare(a.data, clips, run.cfg.model, motion=False)
    gen = run.generate_clips(data, GenerateOptions(batch_size=len(clips)), samples=1)["joints"][:, 0]
    for i, c in enumerate(clips):
        r = data.records[i]
        obj = clip_object(r)
        name = f"{r['category']}_{r['program']}_clip{c}"
        for who, J in (("generated", gen[i]), ("ground_truth", data.joints[i])):
            joints, pts = object_scene(J, data.states[i], obj)
            gif = out / f"{name}_{who}.gif"
            render_gif(joints, gif, object_points=pts, title=f"{who} clip {c}", dpi=60)
            _stills(gif).save(out / f"{name}_{who}_frames.png")
            print(gif)


if __name__ == "__main__":
    main()
