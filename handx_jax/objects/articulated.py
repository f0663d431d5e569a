"""A two-part articulated object (BimArt §3, App. B; ARCTIC's convention) and its pure functions.

Canonical frame: the hinge is the z axis through the origin. Part 0 ("top") rotates by the state's angle about
-z (ARCTIC's ``object_tensors`` rotates the vertices whose part label is 0 by ``[0, 0, -1] * angle``); part 1
("bottom") does not. Then both take the global rotation (axis-angle) and translation:

    x_world = R_g (R_hinge(angle) x_canonical) + t_g      for the top part,
    x_world = R_g x_canonical + t_g                        for the bottom part.

State per frame: (7,) = [angle (rad), axis-angle rotation (3), translation (3, metres)], ARCTIC's
``.object.npy`` layout with its millimetres converted at the reader. Parts are unions of primitives
(``primitives.py``), each with a pose in its part's canonical frame. Every function here is pure JAX: jit,
vmap over points, states or instances of one category, and grad w.r.t. points, states or sizes all work.

A union's signed distance is the min over its primitives: exact outside the part, and inside it wherever the
nearest boundary is a primitive's own face; where two primitives of one part overlap, the depth is a lower
bound (the categories keep overlaps small: a knob on a door, a ring on a shank).
"""

import dataclasses
import functools

import jax
import jax.numpy as jnp

from handx_jax.objects import mesh, primitives
from handx_jax.objects.rotation import hinge_matrix, rotvec_to_matrix

TOP, BOTTOM = 0, 1
NO_PART = -1  # a padding row of the primitive table
PART_NAMES = ("top", "bottom")
STATE_DIM = 7


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ArticulatedObject:
    """Primitive table (P rows) of one object instance; all arrays, plus the static category name.

    kind_P: primitives.BOX / CYLINDER / CAPSULE / TORUS;  part_P: TOP, BOTTOM or NO_PART (padding);  size_Px3: the kind's
    parameters (box half extents; cylinder/capsule radius, half height; torus R, r);  rot_Px3x3, trans_Px3:
    primitive-local -> part canonical frame;  angle_range_2: the category's articulation range (rad);
    up_3: the canonical direction that points up when the object stands on a table (for placing it).
    """
    kind_P: jax.Array
    part_P: jax.Array
    size_Px3: jax.Array
    rot_Px3x3: jax.Array
    trans_Px3: jax.Array
    angle_range_2: jax.Array
    up_3: jax.Array
    category: str = dataclasses.field(default="custom", metadata=dict(static=True))
    # A mesh object (ARCTIC's, interop/arctic.py): triangles in the canonical frame, each with its part, padded
    # to a multiple of mesh.TRI_CHUNK (part NO_PART); None for a procedural object. A part's signed distance is
    # the min over its primitives and its mesh (mesh.py: exact distance, winding-number sign).
    tri_Fx3x3: jax.Array | None = None
    tri_part_F: jax.Array | None = None

    @property
    def n_primitives(self):
        return self.kind_P.shape[-1]


def part_pose(obj, state_7):
    """World-from-canonical rigid transforms of both parts: R_2x3x3, t_2x3 (index TOP, BOTTOM)."""
    del obj  # the hinge passes through the canonical origin for every object (ARCTIC's convention)
    R_g = rotvec_to_matrix(state_7[1:4])
    R_top = R_g @ hinge_matrix(state_7[0])
    t = state_7[4:7]
    return jnp.stack([R_top, R_g]), jnp.stack([t, t])


def to_world(obj, part, state_7, points_Nx3):
    """Part-canonical points -> world points at this state."""
    R, t = part_pose(obj, state_7)
    return points_Nx3 @ R[part].T + t[part]


def to_part(obj, part, state_7, points_Nx3):
    """World points -> the part's canonical frame at this state (inverse of ``to_world``)."""
    R, t = part_pose(obj, state_7)
    return (points_Nx3 - t[part]) @ R[part]


def directions_to_world(obj, part, state_7, vectors_Nx3):
    """Part-canonical directions (normals) -> world directions (rotation only)."""
    R, _ = part_pose(obj, state_7)
    return vectors_Nx3 @ R[part].T


def _mesh_part_sdf(obj, part, points_Nx3):
    return mesh.mesh_sdf(obj.tri_Fx3x3, obj.tri_part_F == part, points_Nx3)


def canonical_part_sdf(obj, part, points_Nx3):
    """Signed distance of part-canonical points to one part: (N,)."""
    d = jnp.full(points_Nx3.shape[:1], jnp.inf, points_Nx3.dtype)
    if obj.n_primitives:
        d_PxN = primitives.primitive_sdf(obj.kind_P, obj.size_Px3, obj.rot_Px3x3, obj.trans_Px3, points_Nx3)
        d = jnp.min(jnp.where((obj.part_P == part)[:, None], d_PxN, jnp.inf), axis=0)
    if obj.tri_Fx3x3 is not None:
        d = jnp.minimum(d, _mesh_part_sdf(obj, part, points_Nx3))
    return d


def part_sdf(obj, part, state_7, points_Nx3):
    """Signed distance (metres, negative inside) of world points to one part at this state: (N,)."""
    return canonical_part_sdf(obj, part, to_part(obj, part, state_7, points_Nx3))


def object_sdf(obj, state_7, points_Nx3):
    """Signed distance of world points to the whole object: (min over parts (N,), per part (2, N))."""
    R, t = part_pose(obj, state_7)
    q_2xNx3 = jnp.einsum("kni,kij->knj", points_Nx3[None] - t[:, None], R)
    per_part = jnp.full((2,) + points_Nx3.shape[:1], jnp.inf, points_Nx3.dtype)
    if obj.n_primitives:
        # One pass over all primitives, each reading the points in its own part's frame.
        d_PxN = primitives.primitive_sdf(obj.kind_P, obj.size_Px3, obj.rot_Px3x3, obj.trans_Px3,
                                         q_2xNx3[jnp.maximum(obj.part_P, 0)])
        per_part = jnp.stack([jnp.min(jnp.where((obj.part_P == p)[:, None], d_PxN, jnp.inf), axis=0)
                              for p in (TOP, BOTTOM)])
    if obj.tri_Fx3x3 is not None:
        per_part = jnp.minimum(per_part, jnp.stack([_mesh_part_sdf(obj, p, q_2xNx3[p]) for p in (TOP, BOTTOM)]))
    return jnp.min(per_part, axis=0), per_part


def object_sdf_frames(obj, states_Tx7, points_TxNx3):
    """``object_sdf`` over a clip: ((T, N), (T, 2, N))."""
    return jax.vmap(object_sdf, (None, 0, 0))(obj, states_Tx7, points_TxNx3)


def part_areas(obj):
    """Total primitive and mesh area per part, (2,) (overlapping primitives counted twice)."""
    out = jnp.zeros(2)
    if obj.n_primitives:
        area_P = jax.vmap(primitives.surface_area)(obj.kind_P, obj.size_Px3)
        out = out + jnp.stack([jnp.sum(jnp.where(obj.part_P == p, area_P, 0.0)) for p in (TOP, BOTTOM)])
    if obj.tri_Fx3x3 is not None:
        area_F = mesh.triangle_areas(obj.tri_Fx3x3)
        out = out + jnp.stack([jnp.sum(jnp.where(obj.tri_part_F == p, area_F, 0.0)) for p in (TOP, BOTTOM)])
    return out


# Candidates drawn per requested sample: enough for the torus's rejection (acceptance R/(R+r) >= 1/2 for the
# rings used here) and for points covered by a touching or overlapping primitive of the same part.
_OVERSAMPLE = 4


def surface_samples(obj, part, n, seed):
    """``n`` points uniform by area on the part's surface, with outward unit normals, in the part's
    canonical frame: (points_nx3, normals_nx3). ``n`` is a Python int; ``part`` an int; ``seed`` an int or key.
    Compiled once per table shape and ``n``, whatever the category (see ``anonymous``)."""
    return _surface_samples(anonymous(obj), part, n, seed)


def anonymous(obj):
    """The object without its category name: the name is static pytree data, so jitted functions that strip
    it compile once for every category of one table shape instead of once per category."""
    return dataclasses.replace(obj, category="")


@functools.partial(jax.jit, static_argnums=(2,))
def _surface_samples(obj, part, n, seed):
    """Candidates are drawn per primitive in proportion to its area, then those inside or on another primitive
    of the same part (not on the union's surface) are dropped, which keeps the density uniform on the union.
    """
    key = jax.random.PRNGKey(seed) if jnp.ndim(seed) == 0 else seed
    if not obj.n_primitives:  # a mesh object: area-uniform on its triangles, face normals
        return mesh.mesh_samples(obj.tri_Fx3x3, obj.tri_part_F == part, jax.random.uniform(key, (n, 3)))
    m = _OVERSAMPLE * n
    # One uniform draw feeds everything (each jax.random call costs seconds of XLA compile on CPU): column 0
    # picks the primitive by inverse CDF of the areas, 1-4 the point on it, 5 the order among valid points.
    u_Mx6 = jax.random.uniform(key, (m, 6))
    area_P = jax.vmap(primitives.surface_area)(obj.kind_P, obj.size_Px3)
    cdf_P = jnp.cumsum(jnp.where(obj.part_P == part, area_P, 0.0))
    cdf_P = cdf_P / cdf_P[-1]
    prim_M = jnp.sum(u_Mx6[:, :1] >= cdf_P[None, :-1], axis=1)
    # A primitive of another part has zero width in the CDF and is never picked, except through the float
    # rounding of a cumsum at u = 1; the part mask below removes that case.
    p_loc, n_loc, ok = jax.vmap(primitives.local_sample)(obj.kind_P[prim_M], obj.size_Px3[prim_M], u_Mx6[:, 1:5])
    ok = ok & (obj.part_P[prim_M] == part)
    R, t = obj.rot_Px3x3[prim_M], obj.trans_Px3[prim_M]
    p_Mx3 = jnp.einsum("mij,mj->mi", R, p_loc) + t
    n_Mx3 = jnp.einsum("mij,mj->mi", R, n_loc)
    d_PxM = primitives.primitive_sdf(obj.kind_P, obj.size_Px3, obj.rot_Px3x3, obj.trans_Px3, p_Mx3)
    others = (obj.part_P[:, None] == part) & (jnp.arange(obj.n_primitives)[:, None] != prim_M[None, :])
    # A candidate on a face glued to another primitive sits at distance 0 from it: 1 micron of clearance.
    covered = jnp.any(others & (d_PxM < 1e-6), axis=0)
    valid = ok & ~covered
    order = jnp.argsort(jnp.where(valid, 0.0, 2.0) + u_Mx6[:, 5])[:n]
    return p_Mx3[order], n_Mx3[order]


def world_surface(obj, part, state_7, points_Px3, normals_Px3):
    """Canonical surface samples of a part -> world points and normals at this state."""
    return to_world(obj, part, state_7, points_Px3), directions_to_world(obj, part, state_7, normals_Px3)
