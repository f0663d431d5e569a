"""THE hand surface and collision check, shared by every synthesizer and metric (issues 52, 55).

A hand is a union of capsules (segment + radius) placed on its 21 joints: one per bone of sk.BONES plus
two across the palm. Everything here is a pure, differentiable JAX function of the joints (metres),
broadcasting over leading axes (frames, clips, hands), so a synthesizer can resolve contacts against it,
a guidance step can take its gradient, and a metric can count its overlaps with the same numbers.

- :func:`capsules` — the capsule segments of one hand; radii :data:`CAPSULE_RADII_M`.
- :func:`surface_points` — a fixed set of points on the capsules, with outward normals (rings per capsule,
  and a cap on each fingertip: the tip keypoint lies on the skin).
- :func:`interhand_separation` — the same with the separating direction (synthesizers push along it).
- :func:`interhand_signed_distance` — min over capsule pairs of (axis distance − r1 − r2) between the two
  hands of a frame: > 0 a gap, 0 contact, < 0 penetration depth.
- :func:`hand_sdf` — the signed distance of any points to one hand's surface (contact maps, BimArt §3.2).
- :func:`surface_sdf` / :func:`object_penetration` — the surface points against any object SDF
  ``sdf(points_Nx3) -> N`` (BimArt §4's hand→object Pen counts hand points inside the object).

Radii (the why). MANO (Romero et al. 2017), which the datasets' hands come from, is not carried here, so the
surface is capsules of round radii that fit adult hand anthropometry: for each segment r ≈ (breadth + depth)
/ 4, the radius of a circle of the segment's mean diameter, with breadths and depths from hand surveys
(Greiner 1991, US Army Natick TR-92/011, "Hand anthropometry of U.S. Army personnel"; Vergara et al. 2018,
"Dorsal and palmar aspect dimensions of hand anthropometry", which lists depths beside breadths; Buchholz &
Armstrong 1992 fit ellipsoids of the same segments), averaged over men and women and rounded to 0.5 mm.
Approximately: index and middle breadth at the PIP ~20 mm and depth ~18 mm (r 9.5 mm), at the DIP ~17 and
~15 mm (r 8–8.5), the distal pad ~15 × 12.5 mm (r 7–7.5); the ring finger ~0.5 mm thinner, the little
finger ~1.5 mm thinner; the thumb the thickest digit (IP breadth ~20 mm: proximal r 10, distal 8.5, and its
metacarpal buried in the thenar eminence, r 12). The palm's thickness at the third metacarpal is ~26–30 mm
and its breadth at the metacarpal heads ~76–87 mm. A slab would model that box exactly but bends badly with
the metacarpal arch; instead the palm is the fan of wrist → MCP / thumb-CMC capsules (r 13 mm: half the
palm's thickness), closed by two cross capsules: index MCP → little MCP along the knuckles (the MCP centres
are ~55 mm apart, so the palm is ~55 + 2·13 ≈ 81 mm broad, as measured), and thumb CMC → index MCP over the
thenar eminence, which the fan leaves open where the thumb abducts. Two palms pressed together then hold
their MCP joints 26 mm apart, the "about 2 cm or more" of real palms (issue 55).

The capsules before this module (metrics/hand_papers.py, issue 33: palm 12, thumb metacarpal 11, every
finger's proximal / middle / distal 9 / 8 / 7 mm, no cross capsules) were thinner at the palm and thumb and
the same for all fingers: inter-hand Pen 1cm and penetration depth measured with these radii are not
comparable with figures published before (docs/results/validity/corpus-v5 gives both for corpus v4).
They are not fitted to meshes; a MANO mesh would give the real surface (BimArt §4 counts vertices).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import skeleton as sk

# Radii (m) per finger of its capsules from the wrist outward: (wrist → base, then the three phalanges; for
# the thumb wrist → CMC, metacarpal, proximal, distal). Why these values: the module docstring.
FINGER_RADII_M = {
    "thumb": (0.013, 0.012, 0.010, 0.0085),
    "index": (0.013, 0.0095, 0.008, 0.007),
    "middle": (0.013, 0.0095, 0.0085, 0.0075),
    "ring": (0.013, 0.009, 0.008, 0.007),
    "pinky": (0.013, 0.008, 0.007, 0.0065),
}
PALM_RADIUS_M = 0.013
# The two capsules that close the palm (joint a, joint b, radius): the knuckle line and the thenar eminence.
CROSS_CAPSULES = ((sk.JOINT_INDEX["index_mcp"], sk.JOINT_INDEX["pinky_mcp"], PALM_RADIUS_M),
                  (sk.JOINT_INDEX["thumb_cmc"], sk.JOINT_INDEX["index_mcp"], 0.012))


def _bone_radius(child: int) -> float:
    finger = next(f for f, c in sk.CHAINS.items() if child in c)
    return FINGER_RADII_M[finger][sk.CHAINS[finger].index(child) - 1]


CAPSULE_A = np.array([p for p, _ in sk.BONES] + [a for a, _, _ in CROSS_CAPSULES], np.int32)  # (C,) = (22,)
CAPSULE_B = np.array([c for _, c in sk.BONES] + [b for _, b, _ in CROSS_CAPSULES], np.int32)
CAPSULE_RADII_M = np.array([_bone_radius(c) for _, c in sk.BONES] + [r for _, _, r in CROSS_CAPSULES], np.float32)
N_CAPSULES = len(CAPSULE_A)
CAPSULE_IS_TIP = np.isin(CAPSULE_B, sk.TIPS) & (np.arange(N_CAPSULES) < len(sk.BONES))

# The palm's capsules (both ends on the wrist, a finger base or the other cross-capsule end: the fan and the
# two cross capsules) and each finger's distal capsule (sk.FINGER_NAMES order): where "palms touch" and
# "fingertips touch" are read from (events.py's surface reading).
_PALM_JOINTS = (0,) + sk.BASES
PALM_CAPSULES = np.flatnonzero(np.isin(CAPSULE_A, _PALM_JOINTS) & np.isin(CAPSULE_B, _PALM_JOINTS)).astype(np.int32)
TIP_CAPSULES = np.array([int(np.flatnonzero(CAPSULE_B == sk.CHAINS[f][4])[0]) for f in sk.FINGER_NAMES], np.int32)

# Surface sampling: RINGS rings of RING_POINTS points around every capsule's cylinder, and on each fingertip
# capsule's rounded end the tip itself plus one ring at 45°. 22·3·8 + 5·9 = 573 points per hand: a point
# every ~7 mm along a finger and ~60% of the pad arc, dense enough that a finger 5 mm from an object surface
# has a point within ~3 mm of its closest point.
RINGS = (1 / 6, 1 / 2, 5 / 6)
RING_POINTS = 8
_TIP_CAPSULES = np.flatnonzero(CAPSULE_IS_TIP).astype(np.int32)
SURFACE_CAPSULE = np.concatenate([np.repeat(np.arange(N_CAPSULES), len(RINGS) * RING_POINTS),
                                  np.repeat(_TIP_CAPSULES, 1 + RING_POINTS)])  # (P,) the capsule of each point
N_SURFACE_POINTS = len(SURFACE_CAPSULE)


def capsules(joints_Mx21x3: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Capsule segments (M, C, 3) × 2 of one hand (any leading axes M), radii :data:`CAPSULE_RADII_M`.

    A fingertip joint lies on the skin (MANO's tip vertices), so a distal capsule ends its radius short of
    the tip: its rounded end touches the tip (a distal bone shorter than its radius shrinks to a point)."""
    x = jnp.asarray(joints_Mx21x3)
    p, q = x[..., CAPSULE_A, :], x[..., CAPSULE_B, :]
    d = q - p
    length = jnp.sqrt(jnp.maximum(jnp.sum(d * d, -1, keepdims=True), 1e-18))
    r = jnp.asarray(CAPSULE_RADII_M)[:, None]
    keep = jnp.clip(length - r, 0.0, None) / length
    q = jnp.where(jnp.asarray(CAPSULE_IS_TIP)[:, None], p + d * keep, q)
    return p, q


def _safe_norm_cm(g) -> jax.Array:
    """‖g‖ over the FIRST axis (3, …) with a finite gradient at 0 (the double-where: the value is exact)."""
    n2 = g[0] * g[0] + g[1] * g[1] + g[2] * g[2]
    pos = n2 > 1e-20
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, n2, 1.0)), 0.0)


def _segment_closest_cm(p1, q1, p2, q2) -> tuple[jax.Array, jax.Array]:
    """The closest points (3, …) × 2 of segments [p1, q1] and [p2, q2], coordinates on the FIRST axis: the dot
    products are then sums of three whole arrays, not reductions over a trailing axis of length 3 (~5x faster
    on CPU). Ericson, Real-Time Collision Detection §5.1.9 (see :func:`segment_distance`)."""
    dot = lambda u, v: u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = dot(d1, d1), dot(d2, d2)
    b, c, f = dot(d1, d2), dot(d1, r), dot(d2, r)
    eps = 1e-12
    safe = lambda x: jnp.where(x > eps, x, 1.0)
    denom = a * e - b * b
    s = jnp.where(denom > eps * jnp.maximum(a * e, eps), jnp.clip((b * f - c * e) / safe(denom), 0.0, 1.0), 0.0)
    s = jnp.where(a > eps, s, 0.0)
    t = jnp.where(e > eps, (b * s + f) / safe(e), 0.0)
    s = jnp.where(t < 0.0, jnp.where(a > eps, jnp.clip(-c / safe(a), 0.0, 1.0), 0.0), s)
    s = jnp.where(t > 1.0, jnp.where(a > eps, jnp.clip((b - c) / safe(a), 0.0, 1.0), 0.0), s)
    t = jnp.clip(t, 0.0, 1.0)
    return p1 + d1 * s, p2 + d2 * t


def _segment_distance_cm(p1, q1, p2, q2) -> jax.Array:
    """:func:`segment_distance` with the xyz coordinates on the first axis (3, …)."""
    c1, c2 = _segment_closest_cm(p1, q1, p2, q2)
    return _safe_norm_cm(c1 - c2)


def _cm(v):
    return jnp.moveaxis(v, -1, 0)


@jax.jit
def segment_distance(p1: jax.Array, q1: jax.Array, p2: jax.Array, q2: jax.Array) -> jax.Array:
    """Closest distance between segments [p1, q1] and [p2, q2] (…, 3) → (…), broadcasting.

    Ericson, Real-Time Collision Detection §5.1.9: the closest points minimise over (s, t) ∈ [0, 1]²;
    s is clamped from the unconstrained solution, t follows from s and is clamped, then s is recomputed
    for a clamped t. Parallel segments (a·e − b² = 0) start from s = 0; degenerate segments (points)
    are handled by the same clamps."""
    shape = jnp.broadcast_shapes(p1.shape, q1.shape, p2.shape, q2.shape)
    return _segment_distance_cm(*(_cm(jnp.broadcast_to(v, shape)) for v in (p1, q1, p2, q2)))


@jax.jit
def capsule_signed_distance(p1, q1, r1, p2, q2, r2) -> jax.Array:
    """Signed distance between two capsules' surfaces: dist(segments) − r1 − r2 (< 0: overlap depth)."""
    return segment_distance(p1, q1, p2, q2) - r1 - r2


@jax.jit
def capsule_penetration(p1, q1, r1, p2, q2, r2) -> jax.Array:
    """Overlap depth of two capsules, 0 when apart: max(0, r1 + r2 − dist(segments))."""
    return jnp.maximum(-capsule_signed_distance(p1, q1, r1, p2, q2, r2), 0.0)


@jax.jit
def interhand_capsule_distances(joints_Mx2x21x3: jax.Array) -> jax.Array:
    """(M, C, C): signed surface distance of left capsule i to right capsule j (hand 0 = left, sk.LEFT)."""
    r = jnp.asarray(CAPSULE_RADII_M)
    pl, ql = map(_cm, capsules(joints_Mx2x21x3[..., sk.LEFT, :, :]))
    pr, qr = map(_cm, capsules(joints_Mx2x21x3[..., sk.RIGHT, :, :]))
    dist = _segment_distance_cm(pl[..., :, None], ql[..., :, None], pr[..., None, :], qr[..., None, :])
    return dist - r[:, None] - r[None, :]


@jax.jit
def interhand_signed_distance(joints_Mx2x21x3: jax.Array) -> jax.Array:
    """(M,): the two hands' signed surface distance per frame: min over capsule pairs of dist − r1 − r2,
    > 0 the gap between the surfaces, < 0 the depth of the deepest overlap (the collision check).

    The closest pair is found without gradients, then its distance is computed again from the joints: the
    same value, with a backward pass through one pair instead of all C² (jax.grad compiles ~10x faster)."""
    x = jnp.asarray(joints_Mx2x21x3)
    d = interhand_capsule_distances(jax.lax.stop_gradient(x))
    k = jnp.argmin(d.reshape(*d.shape[:-2], -1), axis=-1)
    i, j = k // N_CAPSULES, k % N_CAPSULES
    pick = lambda a, c: jnp.take_along_axis(a, c[..., None, None], axis=-2)[..., 0, :]
    pl, ql = capsules(x[..., sk.LEFT, :, :])
    pr, qr = capsules(x[..., sk.RIGHT, :, :])
    r = jnp.asarray(CAPSULE_RADII_M)
    return segment_distance(pick(pl, i), pick(ql, i), pick(pr, j), pick(qr, j)) - r[i] - r[j]


@jax.jit
def interhand_separation(joints_Mx2x21x3: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(signed distance (M,), separating direction (M, 3)) per frame: the direction from the left hand's
    closest surface point to the right hand's, i.e. the gradient of the signed distance with respect to a
    translation of the right hand (the left's is its negative). Moving the right hand by +δ/2 along it and
    the left by −δ/2 changes the distance by δ while the closest pair stays the closest. Where the two
    closest axis points coincide (axes crossing) it is the direction between the two palms' centres."""
    x = jnp.asarray(joints_Mx2x21x3)
    r = jnp.asarray(CAPSULE_RADII_M)
    pl, ql = map(_cm, capsules(x[..., sk.LEFT, :, :]))
    pr, qr = map(_cm, capsules(x[..., sk.RIGHT, :, :]))
    cl, cr = _segment_closest_cm(pl[..., :, None], ql[..., :, None], pr[..., None, :], qr[..., None, :])
    g_all = (cr - cl).reshape(3, *cl.shape[1:-2], -1)  # (3, M, C·C)
    d = _safe_norm_cm(g_all) - (r[:, None] + r[None, :]).reshape(-1)
    k = jnp.argmin(d, axis=-1)
    g = jnp.moveaxis(jnp.take_along_axis(g_all, k[None, ..., None], axis=-1)[..., 0], 0, -1)  # (M, 3)
    palm = list(sk.BASES) + [0]
    fallback = x[..., sk.RIGHT, palm, :].mean(-2) - x[..., sk.LEFT, palm, :].mean(-2)
    g = jnp.where(jnp.linalg.norm(g, axis=-1, keepdims=True) > 1e-7, g, fallback)
    return jnp.min(d, axis=-1), g / jnp.maximum(jnp.linalg.norm(g, axis=-1, keepdims=True), 1e-12)


def _ring_frame(joints_Mx21x3, p, q):
    """Unit axis and two unit vectors normal to it (each (M, C, 3)) per capsule. The reference direction is
    the palm normal, or across the knuckles where the bone points along the palm normal (a finger flexed
    90°), so the frame is defined, and smooth, in every pose."""
    x = joints_Mx21x3
    unit = lambda v: v / jnp.sqrt(jnp.maximum(jnp.sum(v * v, -1, keepdims=True), 1e-18))
    w, i, k = x[..., 0, :], x[..., sk.JOINT_INDEX["index_mcp"], :], x[..., sk.JOINT_INDEX["pinky_mcp"], :]
    across = unit(k - i)[..., None, :]
    normal = unit(jnp.cross(i - w, k - w))[..., None, :]
    axis = unit(q - p)
    ref = jnp.where(jnp.abs(jnp.sum(normal * axis, -1, keepdims=True)) < 0.8, normal, across)
    u = unit(ref - jnp.sum(ref * axis, -1, keepdims=True) * axis)
    return axis, u, jnp.cross(axis, u)


_ANGLES = 2 * np.pi * np.arange(RING_POINTS) / RING_POINTS
_COS, _SIN = np.cos(_ANGLES).astype(np.float32), np.sin(_ANGLES).astype(np.float32)


@jax.jit
def surface_points(joints_Mx21x3: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Points (M, P, 3) on one hand's capsule surfaces and their outward unit normals (M, P, 3); point k
    lies on capsule :data:`SURFACE_CAPSULE` [k]. Rings of RING_POINTS points at RINGS along every capsule's
    axis, then per fingertip capsule its rounded end: the tip keypoint (normal along the bone) and a ring at
    45° from it. Points near a joint may lie inside the neighbouring capsule: still inside the hand."""
    x = jnp.asarray(joints_Mx21x3)
    p, q = capsules(x)
    axis, u, v = _ring_frame(x, p, q)
    r = jnp.asarray(CAPSULE_RADII_M)[:, None, None]
    radial = _COS[:, None] * u[..., None, :] + _SIN[:, None] * v[..., None, :]  # (M, C, K, 3)
    centres = jnp.stack([p + s * (q - p) for s in RINGS], -2)  # (M, C, R, 3)
    ring_pts = centres[..., :, None, :] + (r[..., None] * radial[..., None, :, :])  # (M, C, R, K, 3)
    ring_nrm = jnp.broadcast_to(radial[..., None, :, :], ring_pts.shape)
    lead = x.shape[:-2]
    ring_pts, ring_nrm = (a.reshape(*lead, -1, 3) for a in (ring_pts, ring_nrm))
    t = _TIP_CAPSULES
    ax, rad, rt = axis[..., t, :], radial[..., t, :, :], jnp.asarray(CAPSULE_RADII_M[t])[:, None, None]
    cap_nrm = jnp.concatenate([ax[..., None, :], np.float32(np.sqrt(0.5)) * (rad + ax[..., None, :])], -2)
    cap_pts = q[..., t, None, :] + rt * cap_nrm  # (M, 5, 1 + K, 3)
    pts = jnp.concatenate([ring_pts, cap_pts.reshape(*lead, -1, 3)], -2)
    nrm = jnp.concatenate([ring_nrm, cap_nrm.reshape(*lead, -1, 3)], -2)
    return pts, nrm


@jax.jit
def hand_sdf(points_MxNx3: jax.Array, joints_Mx21x3: jax.Array) -> jax.Array:
    """(M, N): signed distance of points to one hand's surface (the union of its capsules): min over
    capsules of dist(point, axis) − r; < 0 inside the hand. BimArt's contact map (§3.2) is this at the
    object's points. As in :func:`interhand_signed_distance`, the nearest capsule is found without
    gradients and its distance computed again, so the backward pass runs through one capsule per point."""
    pts, x = jnp.asarray(points_MxNx3), jnp.asarray(joints_Mx21x3)
    r = jnp.asarray(CAPSULE_RADII_M)

    def all_capsules(pts, x):
        p, q = map(_cm, capsules(x))  # (3, M, C)
        pt = _cm(pts)[..., None]  # (3, M, N, 1)
        return _segment_distance_cm(pt, pt, p[..., None, :], q[..., None, :]) - r  # (M, N, C)

    c = jnp.argmin(all_capsules(jax.lax.stop_gradient(pts), jax.lax.stop_gradient(x)), axis=-1)  # (M, N)
    p, q = capsules(x)
    pick = lambda a: jnp.take_along_axis(a, c[..., None], axis=-2)  # (M, N, 3)
    return segment_distance(pts, pts, pick(p), pick(q)) - r[c]


def surface_sdf(joints_Mx21x3: jax.Array, sdf) -> jax.Array:
    """(M, P): an object's signed distance ``sdf(points_Nx3) -> N`` at one hand's surface points (< 0: the
    point is inside the object). Differentiable in the joints wherever ``sdf`` is (jit it around the call)."""
    pts, _ = surface_points(joints_Mx21x3)
    return sdf(pts.reshape(-1, 3)).reshape(pts.shape[:-1])


def object_penetration(joints_Mx21x3: jax.Array, sdf) -> jax.Array:
    """(M,): the depth of one hand's deepest surface point inside the object, 0 when none is inside
    (BimArt §4's hand→object penetration per frame)."""
    return jnp.maximum(-jnp.min(surface_sdf(joints_Mx21x3, sdf), axis=-1), 0.0)


@jax.jit
def interhand_penetration_depth(joints_Mx2x21x3: jax.Array) -> jax.Array:
    """(M,): the deepest inter-hand overlap per frame, m, 0 where the surfaces do not touch."""
    return jnp.maximum(-interhand_signed_distance(joints_Mx2x21x3), 0.0)


BATCH_FRAMES = 512


def in_batches(fn, x_Kx_: np.ndarray, batch: int = BATCH_FRAMES):
    """``fn`` (one of the functions above) over K frames in padded batches of ``batch``, as numpy: one compiled
    shape whatever K is, for host-side loops (synthesis, annotation) whose frame counts vary call to call."""
    x = np.asarray(x_Kx_, np.float32)
    K = x.shape[0]
    if K == 0:
        return jax.tree_util.tree_map(lambda o: np.asarray(o)[:0], fn(np.zeros((batch, *x.shape[1:]), np.float32)))
    pad = -K % batch
    if pad:
        x = np.concatenate([x, np.repeat(x[:1], pad, 0)])
    outs = [jax.tree_util.tree_map(np.asarray, fn(x[b:b + batch])) for b in range(0, K + pad, batch)]
    return jax.tree_util.tree_map(lambda *o: np.concatenate(o)[:K], *outs)
