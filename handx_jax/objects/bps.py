"""BimArt's normalised part-based basis point set (§3.1, Eq. 1-3; App. B) and the points it maps to on each part.

One fixed set of K basis points, uniform in the unit ball, is mapped separately to each part: the object is scaled
into the ball by s_o = (1 - d_margin) / max ||v|| over its surface at an open angle (Eq. 1; d_margin = 0.15, §4
"Implementation"; the angle by App. B's heuristic: pi for lids and screens, 0 for scissors), and each basis point
goes to its nearest point of the part's surface samples (Eq. 2). Those K points per part, in the part's canonical
frame and in metres, are where a contact map (§3.2, Eq. 4) reads the distance to each hand.

Each part is mapped at its canonical pose (angle 0), so a map's K entries per part are fixed material points that
move with the part: BimArt maps the basis anew at each frame's angle, which for the top part gives other points
as the lid turns; fixed points keep one meaning per entry over a clip. Pure functions of (object, seed);
vectorised and jittable. The samples stand in for ARCTIC's mesh vertices
(a dense area-uniform set, so a basis point's nearest sample is within about the sample spacing of its nearest
surface point).
"""

import jax
import jax.numpy as jnp

from handx_jax.objects.articulated import BOTTOM, TOP, part_pose, surface_samples

D_MARGIN = 0.15
# App. B: the articulation angle at which the object is farthest from the origin (scissors closed, lids open), per
# category, procedural or ARCTIC's (pi/2 for the mixer and the capsule machine, 0 for the espresso machine).
SCALE_ANGLE = {"scissors": 0.0, "mixer": jnp.pi / 2, "capsulemachine": jnp.pi / 2, "espressomachine": 0.0}
DEFAULT_SCALE_ANGLE = jnp.pi


def category_scale_angle(category: str) -> float:
    """The open angle of Eq. 1's scale for a category (App. B)."""
    return float(SCALE_ANGLE.get(category, DEFAULT_SCALE_ANGLE))


def basis_points(k, seed=0):
    """K points uniform in the unit ball, (K, 3): the same set for every object (a fixed seed)."""
    kd, kr = jax.random.split(jax.random.PRNGKey(seed))
    d = jax.random.normal(kd, (k, 3))
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    return d * jax.random.uniform(kr, (k, 1)) ** (1.0 / 3.0)


def object_scale(obj, samples_2xNx3, angle):
    """s_o (Eq. 1) from both parts' canonical samples, the top part opened to ``angle``."""
    state = jnp.zeros(7).at[0].set(angle)
    R, _ = part_pose(obj, state)
    top = samples_2xNx3[TOP] @ R[TOP].T
    r = jnp.maximum(jnp.max(jnp.linalg.norm(top, axis=-1)), jnp.max(jnp.linalg.norm(samples_2xNx3[BOTTOM], axis=-1)))
    return (1.0 - D_MARGIN) / r


def part_bps_points(obj, basis_Kx3, n_samples=2048, seed=0, scale_angle=None):
    """The points (2, K, 3) each basis point maps to on the TOP and BOTTOM parts (canonical part frames, metres),
    and s_o. ``scale_angle`` (Eq. 1's open angle) defaults to App. B's heuristic for the object's category."""
    pts = jnp.stack([surface_samples(obj, p, n_samples, seed + p)[0] for p in (TOP, BOTTOM)])   # (2, N, 3)
    a = category_scale_angle(obj.category) if scale_angle is None else scale_angle
    s_o = object_scale(obj, pts, a)
    return map_basis(pts, basis_Kx3, s_o), s_o


def map_basis(samples_2xNx3, basis_Kx3, s_o):
    """Eq. 2: the nearest sample of each part to each basis point, the object scaled by s_o into the unit ball;
    (2, K, 3) in metres. Plain array arithmetic: numpy in, numpy out (no compile), or jnp under jit."""
    xp = jnp if isinstance(samples_2xNx3, jax.Array) else __import__("numpy")
    d2 = xp.sum((samples_2xNx3[:, None, :, :] * s_o - basis_Kx3[None, :, None, :]) ** 2, -1)      # (2, K, N)
    nearest = xp.argmin(d2, axis=-1)
    return xp.take_along_axis(samples_2xNx3, nearest[..., None], axis=1)
