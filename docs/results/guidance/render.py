"""The before/after figure of docs/results/guidance: one prompt of the ablation, guidance off and on.

    python docs/results/guidance/render.py --abl OUT --data DATA --clip ID --on s16 --dest docs/results/guidance

Writes before_after.png (a still at the frame where the guided clip's requested inter-hand pair is closest,
both conditions, and the requested pairs' distance over time) and before.gif / after.gif (the two clips;
fingertips in contact highlighted).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from handx_jax import metrics as M
from handx_jax import skeleton as sk
from handx_jax.dataset.format import Dataset
from handx_jax.interop.handx_npz import read_handx_npz
from handx_jax.dataset.render import HAND_COLORS, render_gif

N_INTRA = 8


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--abl", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--clip", required=True)
    ap.add_argument("--on", default="s16")
    ap.add_argument("--dest", required=True)
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ds = Dataset.open(args.data)
    c = ds.ids.index(args.clip)
    named = M.named_contacts([ds.events[c]])
    inter = named.channel_E >= N_INTRA
    clips = {}
    for name in ("off", args.on):
        entries = read_handx_npz(Path(args.abl) / f"{name}.npz")
        e = next(e for e in entries if e.source_clip == args.clip and e.group == 0)
        clips[name] = e.motion
    W = M.palm_barycentric()
    d = {k: np.asarray(M.contact_channel_distances(v[None], W))[0] for k, v in clips.items()}  # (T, 43)
    chans = sorted(set(named.channel_E[inter].tolist()))
    names = {v: k[1] for k, v in M.CONTACT_CHANNELS.items()}
    req = np.zeros((60, 43), bool)
    for ch, s, e in zip(named.channel_E, named.start_E, named.end_E):
        req[s:e, ch] = True
    frame = int(np.argmin(np.where(req[:, chans].any(1), d[args.on][:, chans].min(1), np.inf)))
    fig = plt.figure(figsize=(11, 4))
    for i, (name, x) in enumerate(clips.items()):
        ax = fig.add_subplot(1, 3, i + 1, projection="3d")
        for h in (0, 1):
            for a, b in sk.BONES:
                ax.plot(*x[frame, h, [a, b]].T, color=HAND_COLORS[h], lw=1.6)
        lo, hi = x[frame].reshape(-1, 3).min(0), x[frame].reshape(-1, 3).max(0)
        ctr, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 0.05)
        for set_lim, k in ((ax.set_xlim, 0), (ax.set_ylim, 1), (ax.set_zlim, 2)):
            set_lim(ctr[k] - half, ctr[k] + half)
        ax.set_box_aspect((1, 1, 1))
        ax.tick_params(labelsize=5)
        ax.set_title(f"{'guidance off' if name == 'off' else 'contact guidance ' + name}, frame {frame}", fontsize=9)
    ax = fig.add_subplot(1, 3, 3)
    for i, ch in enumerate(chans):
        for name, style in (("off", ":"), (args.on, "-")):
            ax.plot(100 * d[name][:, ch], style, color=f"C{i}", lw=1.2, label=f"{names[ch]} ({name})")
        ax.fill_between(np.arange(60), 0, 100 * req[:, ch].astype(float) * M.contact_thresholds()[ch], color=f"C{i}",
                        alpha=0.15)
    ax.set_xlabel("frame")
    ax.set_ylabel("distance (cm)")
    ax.set_title("requested pairs (shaded: requested frames, up to the contact threshold)", fontsize=7)
    ax.set_ylim(0, 30)
    ax.legend(fontsize=5)
    t = ds.texts[c]["interaction"][-1]
    fig.suptitle(f"{args.clip}: {t[:150]}{'…' if len(t) > 150 else ''}", fontsize=7)
    fig.tight_layout()
    dest = Path(args.dest)
    fig.savefig(dest / "before_after.png", dpi=90)
    texts = tuple(ds.texts[c][f][-1] for f in ("left", "right", "interaction"))
    # every second frame at 15 fps: the same 2 s, half the file
    render_gif(clips["off"][::2], dest / "before.gif", dpi=60, fps=15, title="guidance off", texts=texts)
    render_gif(clips[args.on][::2], dest / "after.gif", dpi=60, fps=15, title=f"contact guidance {args.on}",
               texts=texts)
    print(f"frame {frame}; wrote before_after.png, before.gif, after.gif in {dest}")


if __name__ == "__main__":
    main()
