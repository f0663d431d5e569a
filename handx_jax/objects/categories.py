"""Categories of articulated objects, after ARCTIC's (BimArt §4 "Datasets": box, laptop, scissors, ketchup, ...),
with realistic sizes (metres) and articulation ranges (radians), and seeded instance sampling.

Every category is laid out in ARCTIC's canonical frame (``articulated.py``): the hinge is the z axis through the
origin and the top part opens by rotating about -z; angle 0 is closed. Rotating (x, y) about -z by a takes it to
(x cos a + y sin a, -x sin a + y cos a), so a top part lying along -x from the hinge, on the +y side, swings up
into +y as it opens: lids, screens and flip caps sit that way with +y up. A cabinet door's hinge is vertical,
so there +z is up and the door swings out into +y. Each instance stores its ``up_3``.
"""

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from handx_jax.objects import primitives
from handx_jax.objects.articulated import BOTTOM, NO_PART, TOP, ArticulatedObject

_EYE = np.eye(3)


def _rot_x(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


_Z_TO_Y = _rot_x(-math.pi / 2)  # local z (a cylinder's axis) -> part +y
_Z_TO_X = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float)  # local z -> part +x (rotation about y by 90 deg)


def _prim(kind, part, size, centre, rot=_EYE):
    return (primitives.KINDS[kind], part, np.asarray(size, float), np.asarray(rot, float), np.asarray(centre, float))


def _slab(part, x, y, z):
    """An axis-aligned box from its (lo, hi) extents along x, y and z."""
    lo, hi = np.array([x[0], y[0], z[0]]), np.array([x[1], y[1], z[1]])
    return _prim("box", part, (hi - lo) / 2, (hi + lo) / 2)


# Every category's table is padded to this many rows (part NO_PART, never selected), so instances of all
# categories share one shape: one compile serves them all, and they stack for vmap.
MAX_PRIMITIVES = 8


def _assemble(name, prims, angle_range, up):
    pad = _prim("box", NO_PART, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    prims = list(prims) + [pad] * (MAX_PRIMITIVES - len(prims))
    kind, part, size, rot, trans = (np.stack([p[i] for p in prims]) for i in range(5))
    return ArticulatedObject(
        kind_P=jnp.asarray(kind, jnp.int32), part_P=jnp.asarray(part, jnp.int32),
        size_Px3=jnp.asarray(size, jnp.float32), rot_Px3x3=jnp.asarray(rot, jnp.float32),
        trans_Px3=jnp.asarray(trans, jnp.float32), angle_range_2=jnp.asarray(angle_range, jnp.float32),
        up_3=jnp.asarray(up, jnp.float32), category=name)


@dataclasses.dataclass(frozen=True)
class Category:
    """A generator of instances: ``sizes`` names each size parameter's (lo, hi) range in metres, drawn
    uniformly; ``angle_range`` the articulation range in radians; ``build(sizes) -> ArticulatedObject``."""
    name: str
    description: str
    sizes: dict
    angle_range: tuple
    build: object

    def draw_sizes(self, seed):
        rng = np.random.default_rng(seed)
        return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in sorted(self.sizes.items())}

    def sample(self, seed):
        """The instance of this category drawn from ``seed`` (same seed, same object)."""
        return self.build(self.draw_sizes(seed))


def _box_with_lid(s):
    # A solid box of width W (x, back hinge edge at x = 0), height H (y < 0) and depth D (z), under a lid of
    # thickness t that overhangs the front by a 1 cm lip (the thumb's purchase when opening it).
    W, H, D, t = s["width"], s["height"], s["depth"], s["lid_thickness"]
    return _assemble("box", [
        _slab(TOP, (-W - 0.01, 0.0), (0.0, t), (-D / 2, D / 2)),
        _slab(BOTTOM, (-W, 0.0), (-H, 0.0), (-D / 2, D / 2)),
    ], BOX.angle_range, (0, 1, 0))


def _laptop(s):
    # Base (keyboard) of depth L (x) under a screen of the same footprint; the hinge is the back edge.
    L, W, tb, ts = s["depth"], s["width"], s["base_thickness"], s["screen_thickness"]
    return _assemble("laptop", [
        _slab(TOP, (-L, 0.0), (0.0, ts), (-W / 2, W / 2)),
        _slab(BOTTOM, (-L, 0.0), (-tb, 0.0), (-W / 2, W / 2)),
    ], LAPTOP.angle_range, (0, 1, 0))


def _scissors(s):
    # Two halves stacked along the pivot (z): each a blade along +x and a shank to a finger ring at -x, the
    # top half's ring on +y and the bottom's on -y. Opening turns the top blade to -y and its ring to +y.
    Lb, wb, t = s["blade_length"], s["blade_width"], s["thickness"]
    Ls, R, r = s["handle_length"], s["ring_radius"], s["ring_tube"]
    dy = R + r + 0.002
    prims = []
    for part, sy, z in ((TOP, 1.0, (0.0, t)), (BOTTOM, -1.0, (-t, 0.0))):
        zc = (z[0] + z[1]) / 2
        prims.append(_slab(part, (0.0, Lb), (-wb / 2, wb / 2), z))
        ring = np.array([-Ls, sy * dy, zc])
        direction = ring[:2] / np.linalg.norm(ring[:2])
        shank_len = np.linalg.norm(ring[:2]) - R
        ang = math.atan2(direction[1], direction[0])
        prims.append(_prim("box", part, (shank_len / 2, wb / 4, t / 2),
                           np.r_[direction * shank_len / 2, zc], _rot_z(ang)))
        prims.append(_prim("torus", part, (R, r, 0.0), ring))
    return _assemble("scissors", prims, SCISSORS.angle_range, (0, 0, 1))


def _cabinet(s):
    # A cabinet of width W (x < 0 from the hinge edge), depth D (y < 0) and height H (z, centred), its door of
    # thickness t on the front (y > 0), a round knob near the free edge at mid height.
    W, D, H, t = s["width"], s["depth"], s["height"], s["door_thickness"]
    kr, kl = 0.012, 0.025
    return _assemble("cabinet", [
        _slab(TOP, (-W, 0.0), (0.0, t), (-H / 2, H / 2)),
        _prim("cylinder", TOP, (kr, kl / 2, 0.0), (-W + 0.04, t + kl / 2, 0.0), _Z_TO_Y),
        _slab(BOTTOM, (-W, 0.0), (-D, 0.0), (-H / 2, H / 2)),
    ], CABINET.angle_range, (0, 0, 1))


def _bottle(s):
    # A bottle standing along +y: body (radius rb, height Hb) under a shoulder neck and a cap base (radius rc,
    # height hc); the flip lid (radius rc, thickness tc) is hinged at the back edge of the cap (x = 0).
    rb, Hb, rc, hc, tc = s["body_radius"], s["body_height"], s["cap_radius"], s["cap_height"], s["lid_thickness"]
    cx = -rc
    neck = 0.012
    return _assemble("bottle", [
        _prim("cylinder", TOP, (rc, tc / 2, 0.0), (cx, tc / 2, 0.0), _Z_TO_Y),
        _prim("cylinder", BOTTOM, (rc, hc / 2, 0.0), (cx, -hc / 2, 0.0), _Z_TO_Y),
        _prim("cylinder", BOTTOM, ((rb + rc) / 2, neck / 2, 0.0), (cx, -hc - neck / 2, 0.0), _Z_TO_Y),
        _prim("cylinder", BOTTOM, (rb, Hb / 2, 0.0), (cx, -hc - neck - Hb / 2, 0.0), _Z_TO_Y),
    ], BOTTLE.angle_range, (0, 1, 0))


BOX = Category("box", "a box with a hinged lid (ARCTIC's box)", dict(
    width=(0.12, 0.30), height=(0.05, 0.14), depth=(0.10, 0.24), lid_thickness=(0.008, 0.018)),
    (0.0, math.radians(110)), _box_with_lid)
LAPTOP = Category("laptop", "a laptop whose screen opens 0-180 degrees (ARCTIC's laptop)", dict(
    depth=(0.20, 0.26), width=(0.29, 0.38), base_thickness=(0.012, 0.02), screen_thickness=(0.005, 0.009)),
    (0.0, math.pi), _laptop)
SCISSORS = Category("scissors", "scissors opening 0-40 degrees (ARCTIC's scissors; HOI4D's)", dict(
    blade_length=(0.07, 0.11), blade_width=(0.012, 0.018), thickness=(0.002, 0.003),
    handle_length=(0.05, 0.07), ring_radius=(0.011, 0.015), ring_tube=(0.003, 0.004)),
    (0.0, math.radians(40)), _scissors)
CABINET = Category("cabinet", "a wall cabinet with a hinged door and a knob", dict(
    width=(0.30, 0.50), depth=(0.28, 0.45), height=(0.40, 0.75), door_thickness=(0.015, 0.022)),
    (0.0, math.radians(110)), _cabinet)
BOTTLE = Category("bottle", "a squeeze bottle with a flip cap (ARCTIC's ketchup)", dict(
    body_radius=(0.025, 0.04), body_height=(0.12, 0.20), cap_radius=(0.014, 0.02), cap_height=(0.012, 0.02),
    lid_thickness=(0.004, 0.007)), (0.0, math.radians(170)), _bottle)

CATEGORIES = {c.name: c for c in (BOX, LAPTOP, SCISSORS, CABINET, BOTTLE)}


def sample_instance(category, seed):
    """The instance of ``category`` (a name in ``CATEGORIES``) drawn from ``seed``."""
    if category not in CATEGORIES:
        raise KeyError(f"unknown object category {category!r}; known: {', '.join(CATEGORIES)}")
    return CATEGORIES[category].sample(seed)
