"""Grasp templates per object category: where on a part a hand may take it, and how (issue 52 item 2).

A template is a rule over a part's surface samples (canonical frame, ``objects.surface_samples``): the anchor's
outward normal must lie along one of ``normals`` (cos >= 0.95), its position within ``band`` of the part's
extreme along an axis (an edge grasp takes the part near its free edge) and ``margin`` inside the part's extent
along other axes (the hand does not hang off a side); ``finger`` is the finger direction (made tangent at the
anchor; "around" turns the fingers round the ``around`` axis, for a cylinder), ``shape`` the hand shape
(object_grasp.SHAPES) and ``anchor`` the joints placed at the anchor. Among several ``normals`` a hand takes the
one that faces its own side of the body (left hand: world -x), so the two hands approach from their own sides.

Canonical layouts are the objects' (objects/categories.py): the hinge is the z axis; lids, screens and flip caps
lie along -x from it with +y up; scissors lie flat (+z up) with their rings at -x; a cabinet stands with +z up and
its door on +y, its free edge at -x. ``FRONT`` is the canonical direction turned toward the person.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.objects import BOTTOM, TOP


@dataclass(frozen=True)
class Template:
    name: str                       # a word the captions use ("the lid's front edge")
    part: int
    shape: str
    anchor: str
    normals: tuple                  # candidate outward normals (canonical)
    finger: tuple | str             # finger direction (canonical) or "around"
    band: tuple | None = None       # (axis, side, lo, hi): lo..hi metres in from the part's extreme at side*axis
    margin: tuple = ()              # ((axis, metres), ...): at least this far inside the part's extent
    keep_out: tuple = ()            # ((axis, metres), ...): |coordinate| at least this (a knob's height)
    around: int = 1                 # the cylinder axis for finger="around"
    sided: bool = False             # anchors only on the hand's own half (world x) of the part
    inset: float = 0.0              # a pinch: how far below the anchor point (along -normal) the tips meet
    hand: int | None = None         # the hand that takes this part in a split layout (None: either)


X, Y, Z = 0, 1, 2
# Small top parts: a thumb-index pinch (object_grasp.SHAPES["pinch"]), the two pads on the held part itself, where
# they meet ``inset`` below its top face. Generator version 2 took them with wraps (over the cap; across the
# blade's tip, fingers round it): their pads rested on the part beside (the bottle's neck, the lower blade), so in
# a use clip, where the held part turns away from that one, no pad stayed on it and every bottle and scissors
# use clip failed the filter. Flip cap: the hand comes from above with its fingers toward the hinge (canonical
# +x), so as the cap opens the hand swings up and back over the hinge, away from the body. Scissors: the upper
# blade opens toward canonical -y (the person's right); the left hand, palm down with its fingers toward the tip,
# has its thumb on that leading edge and its index on the blade's top face, so nothing of it trails over the
# lower blade as the blades part (a right hand there would put its thumb on the trailing edge, through the lower
# blade); the right hand takes the lower handle, whose ring is on its side.
_CAP_PINCH = Template("flip cap between thumb and index finger", TOP, "pinch", "pinch", ((0, 1, 0),), (1, 0, 0),
                      band=(X, -1, 0.008, 0.022), margin=((Z, 0.006),), inset=0.0025)
_SCISSORS_PINCH = Template("tip of the upper blade between thumb and index finger", TOP, "pinch", "pinch",
                           ((0, 0, 1),), (1, 0, 0), band=(X, 1, 0.006, 0.02), hand=sk.LEFT)
_LID_EDGE = dict(shape="wrap", anchor="knuckles", normals=((0, 1, 0),), finger=(-1, 0, 0), band=(X, -1, 0.012, 0.03))
TEMPLATES = {
    "box": {
        "top": Template("front edge of the lid", TOP, margin=((Z, 0.035),), sided=True, **_LID_EDGE),
        "bottom": Template("side of the base", BOTTOM, "flat", "palm", ((0, 0, 1), (0, 0, -1)), (1, 0, 0),
                           band=(X, -1, 0.045, 0.07), margin=((Y, 0.02),)),
    },
    "laptop": {
        "top": Template("front edge of the screen", TOP, margin=((Z, 0.05),), sided=True, **_LID_EDGE),
        "bottom": Template("front corner of the base", BOTTOM, "wrap", "knuckles", ((0, 0, 1), (0, 0, -1)),
                           (-1, 0, 0), band=(X, -1, 0.015, 0.08)),
    },
    "scissors": {
        # Two hands cannot share the rings (2-3 cm apart): one takes the lower ring from above with its fingers
        # across the scissors, the other pinches the upper blade near its tip, so the two hands keep to their ends.
        "top": _SCISSORS_PINCH,
        "bottom": Template("lower handle", BOTTOM, "wrap", "knuckles", ((0, 0, 1),), (0, -1, 0),
                           band=(X, -1, 0.0, 0.015)),
    },
    "cabinet": {
        "top": Template("free edge of the door", TOP, margin=((Z, 0.05),), keep_out=((Z, 0.06),), **_LID_EDGE | dict(
            normals=((0, 1, 0),))),
        "bottom": Template("side of the cabinet", BOTTOM, "flat", "palm", ((1, 0, 0),), (0, -1, 0),
                           band=(Y, 1, 0.05, 0.08), margin=((Z, 0.05),)),
    },
    "bottle": {
        "top": _CAP_PINCH,
        "bottom": Template("body of the bottle", BOTTOM, "wrap", "palm", ("radial",), "around",
                           band=(Y, -1, 0.03, 0.08), around=Y),
    },
}
# Where both hands hold one part (grab programs): the part's template, one hand on each side.
PAIRED = {"box": "bottom", "laptop": "bottom"}
# The canonical direction that faces the person (world -y); the others face -x (their free edges and rings).
FRONT = {"cabinet": (0.0, 1.0, 0.0)}
# Angles (radians) a "use" program opens to, at most: beyond these a hand on the outer face of a lid or screen
# would swing under the table (a laptop opens to 180 deg, but nobody holds its back there).
USE_MAX_ANGLE = {"box": math.radians(110), "laptop": math.radians(120), "scissors": math.radians(40),
                 "cabinet": math.radians(100), "bottle": math.radians(100)}
# Programs per category: grab (angle constant: lift, carry, turn) and use (open, close, snip). A cabinet is not
# lifted; scissors snip.
GRAB = ("box", "laptop", "scissors", "bottle")
USE_KINDS = {"scissors": ("open", "close", "snip")}
DEFAULT_USE_KINDS = ("open", "close")


def rest_rotation(category: str, up_3) -> np.ndarray:
    """World-from-canonical rotation (3, 3) of the object standing on the table: ``up`` to world +z and FRONT
    to world -y (toward the person, who looks along +y)."""
    up = np.asarray(up_3, np.float64)
    front = np.asarray(FRONT.get(category, (-1.0, 0.0, 0.0)))
    y_w = -front
    return np.stack([np.cross(y_w, up), y_w, up])


def candidates(tpl: Template, pts_Px3: np.ndarray, nrm_Px3: np.ndarray, R_rest: np.ndarray, side: float,
               rng: np.random.Generator, m: int):
    """``m`` anchors (indices into the samples) and their finger directions (m, 3) for a hand on ``side``
    (-1 left, +1 right, 0 either); fewer when the rule leaves fewer (none: an empty array)."""
    lo, hi = pts_Px3.min(0), pts_Px3.max(0)
    ok = np.zeros(len(pts_Px3), bool)
    if tpl.normals == ("radial",):
        ok |= np.abs(nrm_Px3[:, tpl.around]) < 0.1
    else:
        normals = np.asarray(tpl.normals, np.float64)
        world_x = normals @ R_rest[0]
        # The normal that faces the hand's side, where one does; otherwise all of them.
        own = normals[np.sign(np.round(world_x, 3)) == side] if side else normals
        for n in (own if len(own) else normals):
            ok |= nrm_Px3 @ n >= 0.95
    if tpl.band is not None:
        axis, s, b_lo, b_hi = tpl.band
        depth = (hi[axis] - pts_Px3[:, axis]) if s > 0 else (pts_Px3[:, axis] - lo[axis])
        ok &= (depth >= b_lo) & (depth <= b_hi)
    for axis, mg in tpl.margin:
        ok &= (pts_Px3[:, axis] >= lo[axis] + mg) & (pts_Px3[:, axis] <= hi[axis] - mg)
    for axis, mg in tpl.keep_out:
        ok &= np.abs(pts_Px3[:, axis]) >= mg
    if tpl.normals == ("radial",) or tpl.sided:
        wx = (pts_Px3 - 0.5 * (lo + hi)) @ R_rest[0]   # the anchor's side of the part, in the world
        if side:
            ok &= wx * side > 0.005
    idx = np.flatnonzero(ok)
    idx = rng.permutation(idx)[:m]
    if tpl.finger == "around":
        # Round the axis with the thumb toward +axis (up, for a bottle): the hand's x axis is finger x normal
        # = -axis for this finger direction, and the thumb lies on the right hand's -x (the left's +x).
        axis = np.eye(3)[tpl.around]
        f = (side or 1.0) * np.cross(axis, nrm_Px3[idx])
    else:
        f = np.broadcast_to(np.asarray(tpl.finger, np.float64), (len(idx), 3)).copy()
    return idx, f
