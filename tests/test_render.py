"""render_gif draws the static axes once and blits the moving hands onto them (issue 15): every frame must
still show both hands where the clip puts them, on the same background, with its own frame counter."""

import numpy as np
from PIL import Image, ImageSequence

from handx_jax import skeleton as sk
from handx_jax.dataset.render import HAND_COLORS, render_gif


def _near(frame: np.ndarray, hex_colour: str, tol: int = 40) -> np.ndarray:
    rgb = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)])
    return np.abs(frame.astype(int) - rgb).max(-1) < tol


def test_frames_move_the_hands_over_one_background(tmp_path):
    T = 6
    rng = np.random.default_rng(0)
    hand = rng.normal(scale=0.02, size=(sk.NUM_JOINTS, 3))
    x = np.zeros((T, 2, sk.NUM_JOINTS, 3), np.float32)
    for t in range(T):  # the left hand slides along x; the right one stays put
        x[t, 0] = hand + [-0.08 + 0.03 * t, 0.0, 0.0]
        x[t, 1] = hand + [0.08, 0.0, 0.0]
    out = render_gif(x, tmp_path / "c.gif", texts=("left text", "right text", "both text"), fps=10)
    frames = [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(Image.open(out))]
    assert len(frames) == T
    left = [np.argwhere(_near(f, HAND_COLORS[0])) for f in frames]
    right = [np.argwhere(_near(f, HAND_COLORS[1])) for f in frames]
    assert all(len(a) > 30 for a in left) and all(len(a) > 30 for a in right)  # both hands in every frame
    cols = [a[:, 1].mean() for a in left]
    assert all(b > a for a, b in zip(cols, cols[1:]))  # the left hand moves right, frame after frame
    assert max(a[:, 1].mean() for a in right) - min(a[:, 1].mean() for a in right) < 2.0  # the right one stays
    # Each GIF frame gets its own palette, so equal canvas pixels may come back a few levels apart; a real
    # difference (another glyph, a bone) changes a pixel by more than 50 levels.
    h = frames[0].shape[0]
    changed = lambda a, b: int((np.abs(a.astype(int) - b.astype(int)).max(-1) > 50).sum())  # noqa: E731
    bottom = [f[int(0.93 * h):] for f in frames]  # the caption band: drawn once, the same in every frame
    assert all(changed(bottom[0], b) == 0 for b in bottom[1:])
    top = [f[: int(0.05 * h)] for f in frames]  # the frame counter ("frame t/T") changes with every frame
    assert all(changed(a, b) > 3 for a, b in zip(top, top[1:]))


def test_stills_sheet_puts_the_chosen_frames_side_by_side(tmp_path):
    """Each still is its own frame of the GIF (a known answer: frame f painted grey level 5·f), in order."""
    from handx_jax.dataset.render import stills_sheet

    frames = [Image.new("RGB", (6, 4), (5 * f, 5 * f, 5 * f)) for f in range(50)]
    frames[0].save(tmp_path / "c.gif", save_all=True, append_images=frames[1:], duration=40)
    sheet = stills_sheet(tmp_path / "c.gif", (0, 15, 45))
    assert sheet.size == (18, 4)
    assert [sheet.getpixel((6 * k + 3, 2))[0] for k in range(3)] == [0, 75, 225]
