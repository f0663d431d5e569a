"""Render a bimanual clip as an animated GIF: bones, joints, contacts highlighted, three texts below.

Contacts use the thresholds of the contact metrics (reference §5.4): a fingertip within 2.0 cm of a
tip of the same hand's thumb (intra) or within 2.5 cm of any joint 0–15 of the other hand (inter) is
drawn in red for that frame.
"""

from __future__ import annotations

import io
import os
import textwrap
from pathlib import Path

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.infra.atomic import atomic_write_bytes

HAND_COLORS = ("#1f77b4", "#d95f02")  # left blue, right orange (colour-blind safe pair)
CONTACT_COLOR = "#e7298a"


def contact_tips(joints_Tx2x21x3: np.ndarray, intra_m: float = 0.020, inter_m: float = 0.025) -> np.ndarray:
    """Boolean (T, 2, 5): is each fingertip in contact in that frame (intra- or inter-hand)."""
    x = np.asarray(joints_Tx2x21x3, dtype=np.float32)
    tips = x[:, :, list(sk.TIPS)]  # (T, 2, 5, 3)
    out = np.zeros(tips.shape[:3], bool)
    # Intra: thumb tip against the other four tips (both tips marked).
    d_intra = np.linalg.norm(tips[:, :, 1:] - tips[:, :, :1], axis=-1) < intra_m  # (T, 2, 4)
    out[:, :, 1:] |= d_intra
    out[:, :, 0] |= d_intra.any(-1)
    # Inter: each tip against the other hand's joints 0–15.
    for h in (0, 1):
        other = x[:, 1 - h, :16]  # (T, 16, 3)
        d = np.linalg.norm(tips[:, h, :, None] - other[:, None], axis=-1).min(-1)  # (T, 5)
        out[:, h] |= d < inter_m
    return out


OBJECT_COLORS = ("#1b9e77", "#7f7f7f")  # an object's top part green, its bottom part grey


def render_gif(joints_Tx2x21x3: np.ndarray, out: str | os.PathLike, *, texts: tuple[str, str, str] | None = None,
               fps: int = sk.FPS, title: str | None = None, dpi: int = 90,
               object_points: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Write an animated GIF of both hands. ``texts`` = (left, right, interaction). ``object_points`` =
    (points (T, P, 3) of an object's surface per frame, part (P,) of each point: 0 top, 1 bottom) draws the object
    as points beside the hands (the hand–object corpus, synthesis/object_motion.py)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    x = np.asarray(joints_Tx2x21x3, dtype=np.float32)
    if x.ndim != 4 or x.shape[1:] != (2, sk.NUM_JOINTS, 3):
        raise ValueError(f"expected joints of shape (T, 2, 21, 3), got {x.shape}")
    T = x.shape[0]
    contacts = contact_tips(x)
    wrapped = []
    if texts:
        for name, t in zip(("Left", "Right", "Both"), texts):
            t = t if len(t) <= 600 else t[:600].rsplit(" ", 1)[0] + " …"
            wrapped.append(textwrap.fill(f"{name}: {t}", width=95, subsequent_indent="    "))
    n_lines = sum(w.count("\n") + 1 for w in wrapped)
    text_h = 0.14 * n_lines + 0.2 if texts else 0.0  # inches
    fig = plt.figure(figsize=(6.0, 5.4 + text_h))
    frac = text_h / (5.4 + text_h)
    ax = fig.add_axes([0.0, frac, 1.0, 1.0 - frac], projection="3d")
    extent = x.reshape(-1, 3) if object_points is None else np.concatenate([x.reshape(-1, 3),
                                                                            object_points[0].reshape(-1, 3)])
    lo, hi = np.nanmin(extent, 0), np.nanmax(extent, 0)
    centre, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 0.05) * 0.8  # equal axes, tight
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=30, azim=-60)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.tick_params(labelsize=6)
    if texts:
        fig.text(0.03, frac - 0.01, "\n".join(wrapped), va="top", ha="left", fontsize=7, family="sans-serif")
    lines = [[ax.plot([], [], [], color=HAND_COLORS[h], lw=1.6)[0] for _ in sk.BONES] for h in (0, 1)]
    joints_art = [ax.plot([], [], [], "o", color=HAND_COLORS[h], ms=2.5)[0] for h in (0, 1)]
    contact_art = ax.plot([], [], [], "o", color=CONTACT_COLOR, ms=6)[0]
    object_art = [ax.plot([], [], [], ".", color=c, ms=1.5, alpha=0.6)[0] for c in OBJECT_COLORS] \
        if object_points is not None else []
    label = ax.set_title(title or "", fontsize=9)

    def draw(t: int):
        for h in (0, 1):
            for art, (a, b) in zip(lines[h], sk.BONES):
                seg = x[t, h, [a, b]]
                art.set_data(seg[:, 0], seg[:, 1])
                art.set_3d_properties(seg[:, 2])
            joints_art[h].set_data(x[t, h, :, 0], x[t, h, :, 1])
            joints_art[h].set_3d_properties(x[t, h, :, 2])
        c = x[t][:, list(sk.TIPS)][contacts[t]]
        contact_art.set_data(c[:, 0], c[:, 1])
        contact_art.set_3d_properties(c[:, 2])
        for part, art in enumerate(object_art):
            pts = object_points[0][t][object_points[1] == part]
            art.set_data(pts[:, 0], pts[:, 1])
            art.set_3d_properties(pts[:, 2])
        label.set_text(f"{title + '  ' if title else ''}frame {t + 1}/{T}  ({(t + 1) / fps:.2f} s)")
        return [*object_art, *lines[0], *lines[1], *joints_art, contact_art, label]

    # The axes, panes, ticks and texts are the same in every frame (fixed view and limits), so they are drawn
    # once and each frame restores that background and draws only the moving artists (blitting by hand;
    # FuncAnimation.save redraws the whole 3D figure per frame: 30 frames 6.0 -> 1.5 s here).
    fig.set_dpi(dpi)
    canvas = fig.canvas
    canvas.draw()  # the moving artists are still empty: this is the static background
    background = canvas.copy_from_bbox(fig.bbox)
    frames = []
    for t in range(T):
        canvas.restore_region(background)
        for art in draw(t):
            ax.draw_artist(art)
        # opaque RGB, as matplotlib's PillowWriter converts opaque frames (GIF's palette quantises it better)
        frames.append(Image.fromarray(np.asarray(canvas.buffer_rgba())[..., :3].copy(), "RGB"))
    plt.close(fig)
    buf = io.BytesIO()
    # as matplotlib's PillowWriter writes it: every frame, one duration, looping
    frames[0].save(buf, format="GIF", save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
    return atomic_write_bytes(Path(out), buf.getvalue())


def render_frame_png(joints_Tx2x21x3: np.ndarray, frame: int, out: str | os.PathLike, **kw) -> Path:
    """A single still (for notebooks and docs)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.asarray(joints_Tx2x21x3)[frame]
    fig = plt.figure(figsize=(4, 4))
    ax = fig.add_subplot(projection="3d")
    for h in (0, 1):
        for a, b in sk.BONES:
            ax.plot(*x[h, [a, b]].T, color=HAND_COLORS[h], lw=1.6)
    ax.set_box_aspect((1, 1, 1))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=kw.get("dpi", 100), bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(out, buf.getvalue())


def stills_sheet(gif: str | os.PathLike, frames: tuple[int, ...] = (0, 15, 30, 45)):
    """The GIF's ``frames`` side by side on one white sheet (a PIL image): a rendered clip read at a glance, as
    the results folders show theirs (docs/results/objects/, docs/results/bimart/)."""
    from PIL import Image

    im = Image.open(gif)
    stills = []
    for f in frames:
        im.seek(f)
        stills.append(im.convert("RGB").copy())
    w, h = stills[0].size
    sheet = Image.new("RGB", (w * len(stills), h), "white")
    for k, still in enumerate(stills):
        sheet.paste(still, (k * w, 0))
    return sheet
