"""The HandX 21-joint bimanual skeleton: one source of truth for joint order, chains and frames.

Reference: handx-reference.md §1.5 (joint order, chains), §1.6 (units/fps/length), §1.7 and paper
A.2 (canonical frame). Arrays of joints are laid out ``(..., 2, 21, 3)`` with hand 0 = LEFT and
hand 1 = RIGHT, in metres, at 30 fps; clips are 60 frames. Flattened 42-joint layouts put the left
hand in rows 0–20 and the right hand in rows 21–41 (wrists at rows 0 and 21).
"""

from __future__ import annotations

import numpy as np

FPS = 30
CLIP_LEN = 60
NUM_JOINTS = 21
NUM_HANDS = 2
LEFT, RIGHT = 0, 1
HAND_NAMES = ("left", "right")

# MANO's 16-joint order with the five fingertips appended (reference §1.5).
JOINT_NAMES = (
    "wrist",
    "index_mcp", "index_pip", "index_dip",
    "middle_mcp", "middle_pip", "middle_dip",
    "pinky_mcp", "pinky_pip", "pinky_dip",
    "ring_mcp", "ring_pip", "ring_dip",
    "thumb_cmc", "thumb_mcp", "thumb_ip",
    "thumb_tip", "index_tip", "middle_tip", "ring_tip", "pinky_tip",
)
JOINT_INDEX = {name: i for i, name in enumerate(JOINT_NAMES)}

FINGER_NAMES = ("thumb", "index", "middle", "ring", "pinky")
# Each chain runs wrist → proximal → middle → distal → tip, in this fixed finger order.
CHAINS = {
    "thumb": (0, 13, 14, 15, 16),
    "index": (0, 1, 2, 3, 17),
    "middle": (0, 4, 5, 6, 18),
    "ring": (0, 10, 11, 12, 19),
    "pinky": (0, 7, 8, 9, 20),
}
CHAINS_5x5 = np.array([CHAINS[f] for f in FINGER_NAMES], dtype=np.int64)

TIPS = tuple(CHAINS[f][4] for f in FINGER_NAMES)  # (16, 17, 18, 19, 20): thumb..pinky
# Finger "base" joints: thumb CMC and the four MCPs, in finger order.
BASES = tuple(CHAINS[f][1] for f in FINGER_NAMES)  # (13, 1, 4, 10, 7)
MCPS = {f: CHAINS[f][1] for f in FINGER_NAMES if f != "thumb"}

# Parent of every joint along its chain (wrist is the root, parent -1).
PARENTS = np.full(NUM_JOINTS, -1, dtype=np.int64)
for _chain in CHAINS.values():
    for _a, _b in zip(_chain[:-1], _chain[1:]):
        PARENTS[_b] = _a
BONES = tuple((int(PARENTS[j]), j) for j in range(1, NUM_JOINTS))  # 20 bones per hand

# Interior joints (proximal, middle, distal) per finger, with (predecessor, joint, successor).
# Used by the rotation scalar (§2.2), the intensity metric (§7) and flexion (§6.1).
INTERIOR_TRIPLES = tuple(
    (CHAINS[f][s - 1], CHAINS[f][s], CHAINS[f][s + 1]) for f in FINGER_NAMES for s in (1, 2, 3)
)

# OpenPose hand order (wrist, thumb 1-4, index 1-4, middle, ring, pinky) → HandX index (§1.5).
OPENPOSE_TO_HANDX = (0, 13, 14, 15, 16, 1, 2, 3, 17, 4, 5, 6, 18, 10, 11, 12, 19, 7, 8, 9, 20)

# Palm triangles whose union is the palm region used for palm point clouds (§5.4 contact metrics):
# (wrist, thumb CMC, index MCP), (wrist, index MCP, middle MCP), (wrist, middle MCP, ring MCP),
# (wrist, ring MCP, pinky MCP).
PALM_TRIANGLES = ((0, 13, 1), (0, 1, 4), (0, 4, 10), (0, 10, 7))


def flat_index(hand: int, joint: int) -> int:
    """Row of (hand, joint) in the flattened 42-joint layout."""
    return hand * NUM_JOINTS + joint


def canonical_rotation(joints_Tx2x21x3: np.ndarray, ref_frame: int = 0) -> np.ndarray:
    """Rotation R (3x3, rows = new axes) of the paper's canonical frame (A.2), from ``ref_frame``.

    +x points from the left wrist to the right wrist; +y from the wrists toward the fingertips
    (the mean fingertip direction, made orthogonal to x); +z = x × y, which points up for hands
    held palm-down in front of the body, and keeps the frame right-handed.
    """
    f0 = np.asarray(joints_Tx2x21x3[ref_frame], dtype=np.float64)
    lw, rw = f0[LEFT, 0], f0[RIGHT, 0]
    x = rw - lw
    tips = f0[:, list(TIPS)].reshape(-1, 3).mean(0)
    y = tips - 0.5 * (lw + rw)
    nx = np.linalg.norm(x)
    if nx < 1e-9:
        raise ValueError("canonicalisation failed: the two wrists coincide in the first frame")
    x = x / nx
    y = y - x * (y @ x)
    ny = np.linalg.norm(y)
    if ny < 1e-9:
        raise ValueError(
            "canonicalisation failed: the fingertip direction is parallel to the wrist axis in frame 0"
        )
    y = y / ny
    z = np.cross(x, y)
    return np.stack([x, y, z])


def canonicalize(joints_Tx2x21x3: np.ndarray, ref_frame: int = 0) -> np.ndarray:
    """Rotate a whole sequence into the canonical frame and put the reference right wrist at the origin.

    The rotation is fixed by the first frame (paper A.2; ``ref_frame`` lets a caller skip leading
    defective frames) and applied to every frame. The translation follows the released clips
    (reference §1.7): the right wrist sits at the origin in the reference frame.
    """
    x = np.asarray(joints_Tx2x21x3)
    R = canonical_rotation(x, ref_frame)
    out = (x.astype(np.float64) - x[ref_frame, RIGHT, 0].astype(np.float64)) @ R.T
    return out.astype(x.dtype if np.issubdtype(x.dtype, np.floating) else np.float32)


def bone_lengths(joints_Tx2x21x3: np.ndarray) -> np.ndarray:
    """Lengths of the 20 bones per hand, shape (..., 2, 20)."""
    x = np.asarray(joints_Tx2x21x3)
    child = np.arange(1, NUM_JOINTS)
    return np.linalg.norm(x[..., child, :] - x[..., PARENTS[child], :], axis=-1)
