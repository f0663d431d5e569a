"""Solid primitives with exact analytic signed distances and area-uniform surface samples.

Every primitive lives in its own local frame (the part frame maps to it by a rotation and a translation):
box (half extents a, b, c), cylinder about local z (radius, half height), capsule about local z (radius, half
length of its segment) and torus about local z (major radius R, tube radius r). Kinds are data (an int per
primitive), not Python branches, so one jitted function serves every object and vmaps over instances.
Signed distances are negative inside. ``_safe_norm`` keeps gradients finite where a norm is 0 (points on a
face, whose outside part is exactly zero); distances stay exact there.
"""

import math

import jax
import jax.numpy as jnp

BOX, CYLINDER, CAPSULE, TORUS = 0, 1, 2, 3
KINDS = {"box": BOX, "cylinder": CYLINDER, "capsule": CAPSULE, "torus": TORUS}


def _safe_norm(v_x, axis=-1):
    s = jnp.sum(v_x * v_x, axis=axis)
    pos = s > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, s, 1.0)), 0.0)


def _sdf_box(q_x3, size_3):
    d = jnp.abs(q_x3) - size_3
    return _safe_norm(jnp.maximum(d, 0.0)) + jnp.minimum(jnp.max(d, axis=-1), 0.0)


def _sdf_cylinder(q_x3, size_3):
    rho = _safe_norm(q_x3[..., :2])
    d = jnp.stack([rho - size_3[0], jnp.abs(q_x3[..., 2]) - size_3[1]], -1)
    return _safe_norm(jnp.maximum(d, 0.0)) + jnp.minimum(jnp.max(d, axis=-1), 0.0)


def _sdf_capsule(q_x3, size_3):
    nearest_z = jnp.clip(q_x3[..., 2], -size_3[1], size_3[1])
    return _safe_norm(q_x3 - jnp.stack([jnp.zeros_like(nearest_z)] * 2 + [nearest_z], -1)) - size_3[0]


def _sdf_torus(q_x3, size_3):
    rho = _safe_norm(q_x3[..., :2])
    return _safe_norm(jnp.stack([rho - size_3[0], q_x3[..., 2]], -1)) - size_3[1]


def local_sdf(kind, size_3, q_Nx3):
    """Signed distance of local points to one primitive (kind is a traced int): (N,)."""
    fns = (_sdf_box, _sdf_cylinder, _sdf_capsule, _sdf_torus)
    return _select(kind, [f(q_Nx3, size_3) for f in fns])


def _select(kind, values):
    """values[kind] by elementwise selects (a traced kind; no gather in the compiled program)."""
    out = values[0]
    for i, v in enumerate(values[1:], start=1):
        out = jnp.where(kind == i, v, out)
    return out


def primitive_sdf(kind_P, size_Px3, rot_Px3x3, trans_Px3, p_Nx3):
    """Signed distance of part-frame points to each primitive: (P, N). rot/trans map local -> part frame.
    ``p`` may also be (P, N, 3): each primitive's own points (its part's frame)."""
    def one(kind, size, R, t, p):
        return local_sdf(kind, size, (p - t) @ R)
    if p_Nx3.ndim == 2:
        return jax.vmap(one, (0, 0, 0, 0, None))(kind_P, size_Px3, rot_Px3x3, trans_Px3, p_Nx3)
    return jax.vmap(one)(kind_P, size_Px3, rot_Px3x3, trans_Px3, p_Nx3)


def surface_area(kind, size_3):
    """Exact area of one primitive (kind a Python or traced int)."""
    a, b, c = size_3[0], size_3[1], size_3[2]
    box = 8.0 * (a * b + b * c + a * c)
    cyl = 2.0 * math.pi * a * (2.0 * b) + 2.0 * math.pi * a * a
    cap = 2.0 * math.pi * a * (2.0 * b) + 4.0 * math.pi * a * a
    tor = 4.0 * math.pi ** 2 * a * b
    return _select(kind, [box, cyl, cap, tor])


def _box_sample(size_3, u_4):
    a, b, c = size_3[0], size_3[1], size_3[2]
    # Face pairs normal to x, y, z have areas 4bc, 4ac, 4ab; pick a pair by area, a side by a coin. One-hot
    # arithmetic instead of indexing by the traced axis keeps the program free of gathers (XLA compiles it fast).
    w = jnp.stack([b * c, a * c, a * b])
    cum = jnp.cumsum(w) / jnp.sum(w)
    axis = (u_4[0] >= cum[0]).astype(jnp.int32) + (u_4[0] >= cum[1]).astype(jnp.int32)
    k = jnp.arange(3)
    e = (k == axis).astype(size_3.dtype)
    o1 = (k == (axis + 1) % 3).astype(size_3.dtype)  # the two in-face axes, in cyclic order after ``axis``
    o2 = (k == (axis + 2) % 3).astype(size_3.dtype)
    sign = jnp.where(u_4[1] < 0.5, -1.0, 1.0)
    coords = e * sign + o1 * (2.0 * u_4[2] - 1.0) + o2 * (2.0 * u_4[3] - 1.0)
    return coords * size_3, e * sign, True


def _cylinder_sample(size_3, u_4):
    r, h = size_3[0], size_3[1]
    side, cap = 4.0 * math.pi * r * h, 2.0 * math.pi * r * r
    phi = 2.0 * math.pi * u_4[1]
    on_side = u_4[0] * (side + cap) < side
    zs = (2.0 * u_4[2] - 1.0) * h
    rad = r * jnp.sqrt(u_4[2])
    sign = jnp.where(u_4[3] < 0.5, -1.0, 1.0)
    p_side = jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi), zs])
    p_cap = jnp.stack([rad * jnp.cos(phi), rad * jnp.sin(phi), sign * h])
    n_side = jnp.stack([jnp.cos(phi), jnp.sin(phi), 0.0])
    n_cap = jnp.stack([0.0, 0.0, sign])
    return jnp.where(on_side, p_side, p_cap), jnp.where(on_side, n_side, n_cap), True


def _capsule_sample(size_3, u_4):
    r, h = size_3[0], size_3[1]
    side, caps = 4.0 * math.pi * r * h, 4.0 * math.pi * r * r
    phi = 2.0 * math.pi * u_4[1]
    on_side = u_4[0] * (side + caps) < side
    # A uniform direction on the sphere (Archimedes: z uniform in [-1, 1]) lands on the hemisphere its z sign
    # picks: the two caps' union.
    z = 2.0 * u_4[2] - 1.0
    ring = jnp.sqrt(jnp.maximum(1.0 - z * z, 0.0))
    n_sph = jnp.stack([ring * jnp.cos(phi), ring * jnp.sin(phi), z])
    p_sph = n_sph * r + jnp.stack([0.0, 0.0, jnp.where(n_sph[2] < 0, -h, h)])
    p_side = jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi), (2.0 * u_4[2] - 1.0) * h])
    n_side = jnp.stack([jnp.cos(phi), jnp.sin(phi), 0.0])
    return jnp.where(on_side, p_side, p_sph), jnp.where(on_side, n_side, n_sph), True


def _torus_sample(size_3, u_4):
    R, r = size_3[0], size_3[1]
    theta, phi = 2.0 * math.pi * u_4[0], 2.0 * math.pi * u_4[1]
    # Area element (R + r cos phi) dtheta dphi: accept with that weight over its maximum (rejection).
    keep = u_4[2] * (R + r) < R + r * jnp.cos(phi)
    n = jnp.stack([jnp.cos(phi) * jnp.cos(theta), jnp.cos(phi) * jnp.sin(theta), jnp.sin(phi)])
    centre = jnp.stack([R * jnp.cos(theta), R * jnp.sin(theta), 0.0])
    return centre + r * n, n, keep


def local_sample(kind, size_3, u_4):
    """One candidate surface point of a primitive, from 4 uniforms: (point_3, normal_3, valid).
    ``valid`` is False for a rejected torus candidate; other kinds always accept."""
    outs = [f(size_3, u_4) for f in (_box_sample, _cylinder_sample, _capsule_sample, _torus_sample)]
    return tuple(_select(kind, [jnp.asarray(o[i]) for o in outs]) for i in range(3))
