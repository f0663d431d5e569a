"""Hand-made joint arrays with known geometry for the annotation-pipeline tests.

A straight RIGHT hand in its own frame: wrist at the origin, fingers along +y, palm facing −z, thumb
on the −x side. The left hand is its mirror image (x → −x). Bends rotate every bone after a joint
about the finger's lateral axis (+x for the right hand), toward the palm for positive angles.
"""

from __future__ import annotations

import numpy as np

from handx_jax import skeleton as sk

MCP_X = {"index": -0.025, "middle": -0.005, "ring": 0.015, "pinky": 0.032}
BONES = {"index": (0.045, 0.027, 0.024), "middle": (0.048, 0.030, 0.024),
         "ring": (0.045, 0.029, 0.024), "pinky": (0.036, 0.021, 0.022)}
THUMB_CMC = np.array([-0.02, 0.025, -0.01])
THUMB_DIR = np.array([-0.6, 0.8, 0.0]) / 1.0
THUMB_BONES = (0.046, 0.032, 0.029)


def _rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    # Positive angle turns +y toward −z (toward the palm of a palm-down right hand).
    return np.array([[1, 0, 0], [0, np.cos(a), np.sin(a)], [0, -np.sin(a), np.cos(a)]])


def right_hand(bends: dict | None = None, spread_deg: dict | None = None) -> np.ndarray:
    """(21, 3) right hand. ``bends[(finger, level)]`` in degrees, level 1 = MCP, 2 = PIP, 3 = DIP;
    ``spread_deg[finger]`` turns the whole finger about z (+ toward the thumb side, −x)."""
    bends = bends or {}
    spread_deg = spread_deg or {}
    x = np.zeros((sk.NUM_JOINTS, 3))
    for f in ("index", "middle", "ring", "pinky"):
        chain = sk.CHAINS[f]
        p = np.array([MCP_X[f], 0.09, 0.0])
        a = np.radians(spread_deg.get(f, 0.0))
        d = np.array([-np.sin(a), np.cos(a), 0.0])
        R = np.eye(3)
        x[chain[1]] = p
        for lvl, length in zip((1, 2, 3), BONES[f]):
            R = R @ _rot_x(bends.get((f, lvl), 0.0))
            p = p + length * (R @ d)
            x[chain[lvl + 1]] = p
    d = THUMB_DIR / np.linalg.norm(THUMB_DIR)
    p = THUMB_CMC.copy()
    x[13] = p
    for j, length in zip((14, 15, 16), THUMB_BONES):
        p = p + length * d
        x[j] = p
    return x


def mirror(hand_21x3: np.ndarray) -> np.ndarray:
    return hand_21x3 * np.array([-1.0, 1.0, 1.0])


def pair(left_21x3: np.ndarray, right_21x3: np.ndarray, gap: float = 0.15) -> np.ndarray:
    """(2, 21, 3): the left hand at x = −gap, the right at x = +gap."""
    return np.stack([left_21x3 + [-gap, 0, 0], right_21x3 + [gap, 0, 0]])


def clip(frames_Tx2x21x3) -> np.ndarray:
    """(1, T, 2, 21, 3) float32 batch of one clip."""
    return np.asarray(frames_Tx2x21x3, dtype=np.float32)[None]


def still(T: int = 60, **kw) -> np.ndarray:
    h = right_hand(**kw)
    return clip(np.repeat(pair(mirror(h), h)[None], T, 0))
