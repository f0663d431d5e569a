"""``handx data show`` for a hand–object corpus: the hands with the object's surface points, upright.

The clips are stored in the hand corpus's canonical frame (fixed by the hands' first frame), in which the table
can stand at any slant; for viewing, the scene is turned so that the object's up direction in frame 0 points
up (+z), the table's normal. Only the picture turns: distances and contacts are the stored ones.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from handx_jax.dataset.format import Dataset
from handx_jax.dataset.render import render_gif
from handx_jax.objects import surface_samples, to_world
from handx_jax.synthesis.object_build import clip_object, open_object_annotations

POINTS_PER_PART = 500


def object_scene(joints_Tx2x21x3: np.ndarray, states_Tx7: np.ndarray, obj):
    """(joints, (points (T, 2P, 3), part (2P,))) turned upright: the object's frame-0 up along +z."""
    pts, part = [], []
    for p in (0, 1):
        s, _ = surface_samples(obj, p, POINTS_PER_PART, p)
        pts.append(np.asarray(jax.vmap(lambda st: to_world(obj, p, st, s))(jnp.asarray(states_Tx7, jnp.float32))))
        part.append(np.full(POINTS_PER_PART, p))
    up = Rotation.from_rotvec(np.asarray(states_Tx7[0, 1:4], np.float64)).as_matrix() @ np.asarray(obj.up_3)
    R = Rotation.align_vectors([[0.0, 0.0, 1.0]], [up])[0].as_matrix()
    return np.asarray(joints_Tx2x21x3) @ R.T, (np.concatenate(pts, 1) @ R.T, np.concatenate(part))


def render_object_clip(root: str | os.PathLike, i: int, out: str | os.PathLike, **kw) -> Path:
    ds = Dataset.open(root)
    ann = open_object_annotations(root)
    joints, obj_pts = object_scene(np.asarray(ds.motion[i]), np.asarray(ann["object_state"][i]),
                                   clip_object(ann["objects"][i]))
    return render_gif(joints, out, object_points=obj_pts, **kw)
