"""Grasps of an articulated object's part: templates in the part's frame, fingers closed against its signed distance.

A grasp template (issue 52 item 2) is an anchor on the part's surface, the approach normal there (the surface's
outward normal: the back of the hand points along it, the palm faces the part) and a palm roll about that normal
(which turns the finger direction in the tangent plane). The hand is placed with its anchor joint (palm centre or
knuckle line) one palm radius plus a gap out along the normal, pushed further out until no surface point of the
open hand is within the gap of either part, and then each finger closes from the template's open pose toward its
closed pose until its surface touches the object: a coarse scan over the finger's curl finds the first bracket
where the finger's closest surface point comes within ``CONTACT_GAP_M`` of the object, and bisection narrows it.
Fingers are independent (no neighbour coupling here), so the five closings run as one vectorised search. A
small part (a flip cap, a blade near its tip) is taken with a pinch instead: the point where the closed pose's
thumb and index tips meet is put at the anchor, inside the part, and the same search closes the two tips onto it
from both sides (SHAPES["pinch"]).

Everything is solved once per hand in the held part's canonical frame, against the object at several angles of
the clip (the other part moves relative to the held one when the angle changes): while the part is held, the
hand is rigid in that frame (the corpus composes world pose = part pose x this local pose), so contacts cannot
slide. Pure JAX under jit/vmap; the forward kinematics are synthesis.hand (``hand_fk(xp=jnp)``).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import hand_surface as hs
from handx_jax import skeleton as sk
from handx_jax.synthesis import hand as H
from handx_jax.objects import canonical_part_sdf, object_sdf, part_pose

# A finger stops when its closest surface point is this far from the object: touching, with the points' spacing
# (a ring of 8 points misses the capsule's surface by r(1 - cos 22.5 deg) <= 0.7 mm between points) kept outside.
CONTACT_GAP_M = 0.0007
# The open hand is pushed out until every surface point is at least this far from the object.
CLEARANCE_M = 0.0015
# The closing search is most of a chunk's CPU (two stages x (SCAN_STEPS + 1 + BISECT_STEPS) SDF passes per
# candidate). Generator version 3 takes 5 + 6 (version 2: 6 + 8, ~0.1 mm): the last bracket is then 1/5/2^6 of the
# curl range, <= 0.3 mm of fingertip travel, inside the 2.3 mm a pad may sit from the part (object_motion) and the
# filter's 3 mm. Measured with object_motion.ANGLE_FRACTIONS on 6 chunks of seed 0 (3 candidates per hand): 9 % less
# CPU per kept clip, 147 clips kept of 192 where 6 + 8 with even angles kept 145.
SCAN_STEPS = 5      # coarse samples of the curl in [0, 1] (the first bracket that meets the object)
BISECT_STEPS = 6    # then bisection

# Hand shapes (16-channel poses, degrees): the pose a template approaches with and the pose its fingers close toward.
# "wrap": a power grasp around an edge, a handle or a cylinder (thumb abducted, then opposed);
# "flat": a supporting palm on a face (fingers straight, closing only a little).
SHAPES = {
    "wrap": (H.base_pose(0, 0, 0.25, (-5, 45, 0, 0)), H.base_pose(90, 105, 0.0, (50, 60, 45, 60))),
    "flat": (H.base_pose(0, 0, 0.15, (0, 15, 0, 0)), H.base_pose(50, 60, 0.1, (25, 30, 30, 40))),
}


def _pinch_shapes():
    """"pinch": a thumb-index precision grasp for a small part (a flip cap's lid, a blade near its tip), where a
    wrap's palm and four fingers cannot all reach the part and their pads end on the part beside it. The thumb
    and index close from a wide aperture (~10 cm tip to tip) toward hand.pinch_pose(0), where their tips meet; the
    middle, ring and little fingers are curled into the palm in both poses (they do not move, and stay ~2 cm
    above the pinch point, clear of the part). Why it matters for BimArt: its part-based BPS (§3.1) maps as many
    points onto "a small articulating part (e.g., the lid of a bottle)" as onto the base, so the contact map
    (§3.2, Eq. 4) of a hand turning the lid says where on the lid it holds only if its pads are on the lid."""
    pinch = np.asarray(H.pinch_pose(0), np.float64)
    closed = H.base_pose(75, 105, 0.0, tuple(pinch[H.T_CMC_FLEX:]))
    opened = H.base_pose(75, 105, 0.0, (-10, 45, 0, 0))
    closed[[H.MCP.start, H.PIP.start, H.ABD.start]] = pinch[[H.MCP.start, H.PIP.start, H.ABD.start]]
    opened[[H.MCP.start, H.PIP.start, H.ABD.start]] = (5.0, 5.0, pinch[H.ABD.start])
    return opened, closed


SHAPES["pinch"] = _pinch_shapes()
SHAPE_NAMES = tuple(SHAPES)

# Channels each finger's curl moves (thumb: its four channels; a finger: its MCP and PIP, the DIP follows the PIP).
_CURL_MASK_5x16 = np.zeros((5, H.NUM_CHANNELS), np.float32)
_CURL_MASK_5x16[0, H.T_CMC_FLEX:] = 1.0
for _i in range(4):
    _CURL_MASK_5x16[1 + _i, H.MCP.start + _i] = 1.0
    _CURL_MASK_5x16[1 + _i, H.PIP.start + _i] = 1.0

# Stage 2 of the closing (solve_grasp): the distal channels, a finger's PIP (the DIP follows) and the thumb's MCP, IP.
_DISTAL_MASK_5x16 = np.zeros((5, H.NUM_CHANNELS), np.float32)
_DISTAL_MASK_5x16[0, [H.T_MCP, H.T_IP]] = 1.0
for _i in range(4):
    _DISTAL_MASK_5x16[1 + _i, H.PIP.start + _i] = 1.0

# The capsules that move with each finger's curl: those past its base (the thumb's metacarpal turns at the CMC, a
# finger's proximal phalanx at the MCP), in skeleton.FINGER_NAMES order; -1: the palm's.
CAPSULE_FINGER = np.array([next((k for k, f in enumerate(sk.FINGER_NAMES) if b in sk.CHAINS[f][2:]), -1)
                           for b in hs.CAPSULE_B[:len(sk.BONES)]] + [-1] * (hs.N_CAPSULES - len(sk.BONES)))
FINGER_CAPSULES_5x3 = np.stack([np.flatnonzero(CAPSULE_FINGER == k) for k in range(5)])
TIP_CAPSULES_5 = np.array([np.flatnonzero(hs.CAPSULE_IS_TIP & (CAPSULE_FINGER == k))[0] for k in range(5)])
POINT_FINGER = CAPSULE_FINGER[hs.SURFACE_CAPSULE]                        # (P,) finger of each surface point
PAD_POINTS = [np.flatnonzero(hs.CAPSULE_IS_TIP[hs.SURFACE_CAPSULE] & (POINT_FINGER == k)) for k in range(5)]
# The search runs on spheres along each capsule's axis (its radius around AXIS_SAMPLES points from end to end):
# the object's exact SDF at a sphere's centre minus its radius is that sphere's exact distance, 13 to 1000 times
# fewer evaluations than the surface points, and between samples 6 mm apart a capsule of radius >= 6.5 mm
# bulges past its spheres by <= 0.7 mm (the final check, on the surface points, is what the corpus keeps).
AXIS_SAMPLES = np.linspace(0.0, 1.0, 5, dtype=np.float32)


def _axis_spheres(joints_21x3, capsules_C):
    """Centres (C * S, 3) and radii (C * S,) of the spheres along the given capsules' axes."""
    p, q = hs.capsules(joints_21x3)
    p, q = p[capsules_C], q[capsules_C]
    c = p[:, None] + AXIS_SAMPLES[:, None] * (q - p)[:, None]
    r = jnp.broadcast_to(jnp.asarray(hs.CAPSULE_RADII_M)[capsules_C][:, None], c.shape[:2])
    return c.reshape(-1, 3), r.reshape(-1)


# What sits at the anchor: the palm centre (wrist and the four MCPs) or the knuckle line (the four MCPs).
# A palm or knuckle anchor sits one palm radius plus the clearance out along the normal from the anchor point (the
# palm rests on the surface); a "pinch" anchor is the point where the CLOSED pose's thumb and index tips meet, put
# at the anchor point itself (the template's ``inset`` lowers it into the part), so the two tips close onto the
# part from its two sides.
ANCHORS = {"palm": (0, 1, 4, 10, 7), "knuckles": (1, 4, 10, 7), "pinch": (sk.TIPS[0], sk.TIPS[1])}
CLOSED_ANCHORS = ("pinch",)


def anchor_weights(name: str) -> np.ndarray:
    """(2, 21): the anchor's joint weights on the open pose (row 0) and on the closed pose (row 1)."""
    w = np.zeros((2, sk.NUM_JOINTS), np.float32)
    w[int(name in CLOSED_ANCHORS), list(ANCHORS[name])] = 1.0 / len(ANCHORS[name])
    return w


def anchor_offset(name: str, inset: float = 0.0) -> float:
    """How far out along the normal from the anchor point the anchor's joints are placed (metres)."""
    return -inset if name in CLOSED_ANCHORS else hs.PALM_RADIUS_M + CLEARANCE_M


def hand_frame(normal_3, finger_3, roll):
    """Rotation (3, 3) whose columns are the hand's x, y (fingers) and z (back of the hand) axes in the part frame:
    z along the outward normal, y the finger direction made tangent and turned by ``roll`` (radians) about z."""
    z = normal_3 / jnp.linalg.norm(normal_3)
    y = finger_3 - jnp.dot(finger_3, z) * z
    y = y / jnp.maximum(jnp.linalg.norm(y), 1e-9)
    x0 = jnp.cross(y, z)
    y = jnp.cos(roll) * y + jnp.sin(roll) * x0
    return jnp.stack([jnp.cross(y, z), y, z], -1)


def _close(finger_sdf_of_curl):
    """Per finger the largest curl in [0, 1] that stays ``CONTACT_GAP_M`` clear of the object before first meeting
    it, whether it met it, and whether it met it already at curl 0. One loop, so the search is traced once: steps
    0..SCAN_STEPS walk the curl grid and keep the first bracket [grid[k-1], grid[k]] that meets the object; the
    later steps bisect it."""
    grid = jnp.linspace(0.0, 1.0, SCAN_STEPS + 1)

    def step(carry, i):
        lo, hi, found, at_open = carry
        scanning = i <= SCAN_STEPS
        c = jnp.where(scanning, grid[jnp.minimum(i, SCAN_STEPS)], 0.5 * (lo + hi))
        meets = finger_sdf_of_curl(c) < CONTACT_GAP_M
        new = scanning & ~found & meets
        lo = jnp.where(new, grid[jnp.maximum(i - 1, 0)], jnp.where(~scanning & ~meets & found, c, lo))
        hi = jnp.where(new, c, jnp.where(~scanning & meets & found, c, hi))
        return (lo, hi, found | new, at_open | (new & (i == 0))), None

    ones = jnp.ones(5)
    init = (ones, ones, jnp.zeros(5, bool), jnp.zeros(5, bool))
    (lo, hi, found, at_open), _ = jax.lax.scan(step, init, jnp.arange(SCAN_STEPS + 1 + BISECT_STEPS))
    return jnp.where(at_open, 0.0, lo), found, at_open


def _object_sdf_in_part(obj, part, angles_K, points_Nx3):
    """Signed distance to the whole object of points given in ``part``'s canonical frame, the least over the
    object at each of the angles (the other part moves relative to this one as the angle changes)."""
    def at(angle):
        state = jnp.zeros(7).at[0].set(angle)
        R, t = part_pose(obj, state)
        return object_sdf(obj, state, points_Nx3 @ R[part].T + t[part])[0]
    return jnp.min(jax.vmap(at)(angles_K), axis=0)


def _fk_local(pose_16, geom, mirror):
    """Joints (21, 3) in the hand's own frame; the left hand is the right one mirrored in x (synth.py's rule)."""
    j = H.hand_fk(pose_16, geom, xp=jnp)
    return j * jnp.array([mirror, 1.0, 1.0])


def solve_grasp(obj, part, angles_K, geom, mirror, anchor_3, normal_3, finger_3, roll, open_16, closed_16,
                anchor_w_2x21, anchor_out):
    """One hand's grasp of ``part`` (objects.TOP / BOTTOM, may be traced), in that part's canonical frame. Jit and
    vmap it over the candidates (object_motion does).

    ``anchor_w_2x21`` weighs the joints of the open pose (row 0) and of the closed pose (row 1) into the point put
    ``anchor_out`` metres out along ``normal_3`` from ``anchor_3`` (anchor_weights, anchor_offset).

    Returns a dict: ``R`` (3, 3) hand-to-part rotation, ``wrist`` (3,) the wrist's position, ``curl`` (5,) per
    finger (thumb..pinky) in [0, 1] from ``open_16`` toward ``closed_16``, ``contact`` (5,) bool (the finger met
    the object), ``pose`` (16,) the closed pose, ``clear`` the grasping hand's least distance to the object (its
    axis spheres; negative: inside), ``pad`` (5,) each distal phalanx's least distance to the held part (its axis spheres). The surface points are checked later, on every frame of the clip
    (synthesis/object_physics.py).
    """
    R = hand_frame(normal_3, finger_3, roll)
    sdf = partial(_object_sdf_in_part, obj, part, angles_K)
    j_open = _fk_local(open_16, geom, mirror)
    at = anchor_w_2x21[0] @ j_open + anchor_w_2x21[1] @ _fk_local(closed_16, geom, mirror)
    wrist = anchor_3 + normal_3 * anchor_out - R @ at

    def world(j_local, w):
        return j_local @ R.T + w

    all_caps = np.arange(hs.N_CAPSULES)

    def push(w, _):
        c, r = _axis_spheres(world(j_open, w), all_caps)
        return w + normal_3 * jnp.maximum(CLEARANCE_M - jnp.min(sdf(c) - r), 0.0), None

    wrist, _ = jax.lax.scan(push, wrist, None, length=3)
    finger_caps = FINGER_CAPSULES_5x3.reshape(-1)

    def finger_sdf(pose):
        c, r = _axis_spheres(world(_fk_local(pose, geom, mirror), wrist), finger_caps)
        return jnp.min((sdf(c) - r).reshape(5, -1), axis=-1)

    # Stage 1: the whole finger curls (MCP and PIP) until it meets the object; stage 2: the MCP stays and the
    # PIP (DIP) and the thumb's MCP and IP go on curling toward their limits until the finger meets it again, so
    # a finger whose proximal phalanx met an edge first wraps its pad round it (a power grasp's closing order).
    curl1, found1, _ = _close(lambda c: finger_sdf(open_16 + (c @ _CURL_MASK_5x16) * (closed_16 - open_16)))
    pose1 = open_16 + (curl1 @ _CURL_MASK_5x16) * (closed_16 - open_16)
    reach = (found1 @ _DISTAL_MASK_5x16) * (jnp.asarray(H.LIMITS_HI_16, jnp.float32) - pose1)
    curl2, found2, _ = _close(lambda c: finger_sdf(pose1 + (c @ _DISTAL_MASK_5x16) * reach))
    pose = pose1 + (curl2 @ _DISTAL_MASK_5x16) * reach
    found = found1 | found2
    curl = curl1
    c, r = _axis_spheres(world(_fk_local(pose, geom, mirror), wrist), all_caps)
    d_CxS = (sdf(c) - r).reshape(hs.N_CAPSULES, -1)
    return {"R": R, "wrist": wrist, "curl": curl, "contact": found, "pose": pose, "clear": jnp.min(d_CxS),
            "pad": jnp.min(pad_distance(obj, part, c, r), -1)}


def pad_distance(obj, part, centres, radii):
    """Each distal phalanx's axis spheres' distance (5, S) to the HELD part alone (a pad on the other part does
    not hold this one, and in a use program it leaves it as the angle changes)."""
    sel = (TIP_CAPSULES_5[:, None] * len(AXIS_SAMPLES) + np.arange(len(AXIS_SAMPLES))).reshape(-1)
    return (canonical_part_sdf(obj, part, centres[sel]) - radii[sel]).reshape(5, -1)
