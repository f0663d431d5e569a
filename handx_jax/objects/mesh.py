"""Triangle meshes as object parts: an exact signed distance (ARCTIC's objects are meshes, BimArt §4), primitive
tessellation (to write procedural objects in ARCTIC's layout), and area-uniform mesh samples.

Distance: the exact point-to-triangle distance (the closest point by Voronoi region of the triangle, Ericson,
Real-Time Collision Detection §5.1.5), min over the part's triangles. Sign: the generalised winding number
(Jacobson et al. 2013; each triangle's solid angle by Van Oosterom & Strackee 1983), inside where it exceeds 1/2.
It needs outward-oriented faces and tolerates unions of closed shells and small holes, which the sign of the
nearest face's pseudo-normal does not (a face of one shell inside another would flip it). Triangles are visited in
chunks of ``TRI_CHUNK`` under ``lax.scan``, so memory is (points x chunk), not (points x faces).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.objects import primitives

TRI_CHUNK = 256


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def point_triangle_sq_distance(p_Nx3, a_Fx3, b_Fx3, c_Fx3):
    """(N, F) squared distance from each point to each triangle (exact; Ericson §5.1.5)."""
    p = p_Nx3[:, None, :]
    a, b, c = a_Fx3[None], b_Fx3[None], c_Fx3[None]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    def safe_div(n, d):
        return n / jnp.where(jnp.abs(d) > 1e-30, d, 1e-30)

    denom = va + vb + vc
    face = a + ab * safe_div(vb, denom)[..., None] + ac * safe_div(vc, denom)[..., None]
    w_bc = safe_div(d4 - d3, (d4 - d3) + (d5 - d6))
    edge_bc = b + (c - b) * w_bc[..., None]
    edge_ac = a + ac * safe_div(d2, d2 - d6)[..., None]
    edge_ab = a + ab * safe_div(d1, d1 - d3)[..., None]
    # Regions in Ericson's order of tests; later tests take precedence here, so build from the last one back.
    q = face
    q = jnp.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[..., None], edge_bc, q)
    q = jnp.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[..., None], edge_ac, q)
    q = jnp.where(((d6 >= 0) & (d5 <= d6))[..., None], jnp.broadcast_to(c, q.shape), q)
    q = jnp.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[..., None], edge_ab, q)
    q = jnp.where(((d3 >= 0) & (d4 <= d3))[..., None], jnp.broadcast_to(b, q.shape), q)
    q = jnp.where(((d1 <= 0) & (d2 <= 0))[..., None], jnp.broadcast_to(a, q.shape), q)
    diff = p - q
    return _dot(diff, diff)


def solid_angles(p_Nx3, a_Fx3, b_Fx3, c_Fx3):
    """(N, F) signed solid angle of each triangle seen from each point (Van Oosterom & Strackee)."""
    a, b, c = a_Fx3[None] - p_Nx3[:, None], b_Fx3[None] - p_Nx3[:, None], c_Fx3[None] - p_Nx3[:, None]
    la, lb, lc = (jnp.linalg.norm(v, axis=-1) for v in (a, b, c))
    det = _dot(a, jnp.cross(b, c))
    den = la * lb * lc + _dot(a, b) * lc + _dot(b, c) * la + _dot(c, a) * lb
    return 2.0 * jnp.arctan2(det, den)


def mesh_sdf(tri_Fx3x3, mask_F, p_Nx3):
    """Signed distance of points to the closed surface made by the masked triangles: (N,). F must be a multiple
    of TRI_CHUNK (``pad_triangles``)."""
    F = tri_Fx3x3.shape[0]
    tris = tri_Fx3x3.reshape(F // TRI_CHUNK, TRI_CHUNK, 3, 3)
    masks = mask_F.reshape(F // TRI_CHUNK, TRI_CHUNK)
    p_sg = jax.lax.stop_gradient(p_Nx3)

    def step(carry, chunk):
        best, wind = carry
        tri, m = chunk
        d2 = point_triangle_sq_distance(p_Nx3, tri[:, 0], tri[:, 1], tri[:, 2])
        best = jnp.minimum(best, jnp.min(jnp.where(m[None], d2, jnp.inf), axis=1))
        om = solid_angles(p_sg, tri[:, 0], tri[:, 1], tri[:, 2])
        wind = wind + jnp.sum(jnp.where(m[None], om, 0.0), axis=1)
        return (best, wind), None

    n = p_Nx3.shape[0]
    (best, wind), _ = jax.lax.scan(step, (jnp.full((n,), jnp.inf, p_Nx3.dtype), jnp.zeros((n,), p_Nx3.dtype)),
                                   (tris, masks))
    inside = wind / (4.0 * math.pi) > 0.5
    pos = best > 0
    dist = jnp.where(pos, jnp.sqrt(jnp.where(pos, best, 1.0)), 0.0)
    return jnp.where(inside, -dist, dist)


def pad_triangles(tri_Fx3x3, part_F):
    """Pad to a multiple of TRI_CHUNK with masked rows (part -1, a degenerate far triangle): numpy in, numpy out."""
    F = len(tri_Fx3x3)
    n = max(1, -(-F // TRI_CHUNK)) * TRI_CHUNK
    far = np.full((n - F, 3, 3), 1e3, np.float32) + np.eye(3, dtype=np.float32)[None]
    return (np.concatenate([np.asarray(tri_Fx3x3, np.float32), far]),
            np.concatenate([np.asarray(part_F, np.int32), np.full(n - F, -1, np.int32)]))


def triangle_areas(tri_Fx3x3):
    return 0.5 * jnp.linalg.norm(jnp.cross(tri_Fx3x3[:, 1] - tri_Fx3x3[:, 0], tri_Fx3x3[:, 2] - tri_Fx3x3[:, 0]),
                                 axis=-1)


def mesh_samples(tri_Fx3x3, mask_F, u_Mx3):
    """Area-uniform points on the masked triangles with their face normals, from uniforms (M, 3)."""
    area = jnp.where(mask_F, triangle_areas(tri_Fx3x3), 0.0)
    cdf = jnp.cumsum(area) / jnp.sum(area)
    f = jnp.clip(jnp.searchsorted(cdf, u_Mx3[:, 0], side="right"), 0, tri_Fx3x3.shape[0] - 1)
    t = tri_Fx3x3[f]
    s = jnp.sqrt(u_Mx3[:, 1:2])
    # Uniform on a triangle: (1 - sqrt u) a + sqrt u (1 - v) b + sqrt u v c.
    p = (1 - s) * t[:, 0] + s * (1 - u_Mx3[:, 2:3]) * t[:, 1] + s * u_Mx3[:, 2:3] * t[:, 2]
    n = jnp.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    return p, n / jnp.maximum(jnp.linalg.norm(n, axis=-1, keepdims=True), 1e-20)


# ---- tessellation of primitives (numpy; outward, counter-clockwise faces) -------------------------------------

def _grid_faces(rows, cols, wrap_cols=True):
    """Quads of a (rows x cols) vertex grid (row-major) split into two triangles each."""
    faces = []
    for i in range(rows - 1):
        for j in range(cols if wrap_cols else cols - 1):
            a, b = i * cols + j, i * cols + (j + 1) % cols
            c, d = (i + 1) * cols + j, (i + 1) * cols + (j + 1) % cols
            faces += [(a, b, d), (a, d, c)]
    return faces


def _revolve(profile_rz, k):
    """A closed surface of revolution about z from a (r, z) profile running from the bottom pole to the top
    pole (r = 0 at both ends): vertices, faces with outward normals."""
    phi = np.linspace(0, 2 * np.pi, k, endpoint=False)
    inner = profile_rz[1:-1]
    ring = np.stack([inner[:, :1] * np.cos(phi), inner[:, :1] * np.sin(phi),
                     np.repeat(inner[:, 1:], k, 1)], -1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, profile_rz[0, 1]]], ring, [[0, 0, profile_rz[-1, 1]]]])
    rows = len(inner)
    faces = [(1 + i * k + j, 1 + i * k + (j + 1) % k, 1 + (i + 1) * k + (j + 1) % k) for i in range(rows - 1)
             for j in range(k)]
    faces += [(1 + i * k + j, 1 + (i + 1) * k + (j + 1) % k, 1 + (i + 1) * k + j) for i in range(rows - 1)
              for j in range(k)]
    top = len(v) - 1
    faces += [(0, 1 + (j + 1) % k, 1 + j) for j in range(k)]
    faces += [(top, 1 + (rows - 1) * k + j, 1 + (rows - 1) * k + (j + 1) % k) for j in range(k)]
    return v, np.array(faces)


def tessellate_primitive(kind, size_3, k=48):
    """Vertices (metres, local frame) and outward faces of one primitive; boxes are exact."""
    a, b, c = (float(x) for x in size_3)
    if kind == primitives.BOX:
        v = np.array([[x, y, z] for x in (-a, a) for y in (-b, b) for z in (-c, c)])
        # Each face's corners counter-clockwise seen from outside.
        quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
        return v, np.array([f for q in quads for f in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    if kind == primitives.CYLINDER:
        return _revolve(np.array([[0, -b], [a, -b], [a, b], [0, b]]), k)
    if kind == primitives.CAPSULE:
        t = np.linspace(-np.pi / 2, np.pi / 2, k // 4 + 1)
        low = np.stack([a * np.cos(t), -b + a * np.sin(t)], 1)[: k // 8 + 1]
        high = np.stack([a * np.cos(t), b + a * np.sin(t)], 1)[k // 8:]
        return _revolve(np.concatenate([low, high]), k)
    R, r = a, b
    theta = np.linspace(0, 2 * np.pi, k, endpoint=False)
    phi = np.linspace(0, 2 * np.pi, k // 2, endpoint=False)
    T, P = np.meshgrid(theta, phi, indexing="ij")
    v = np.stack([(R + r * np.cos(P)) * np.cos(T), (R + r * np.cos(P)) * np.sin(T), r * np.sin(P)], -1)
    n_phi = len(phi)
    faces = []
    for i in range(k):
        for j in range(n_phi):
            p00, p01 = i * n_phi + j, i * n_phi + (j + 1) % n_phi
            p10, p11 = ((i + 1) % k) * n_phi + j, ((i + 1) % k) * n_phi + (j + 1) % n_phi
            faces += [(p00, p10, p11), (p00, p11, p01)]
    return v.reshape(-1, 3), np.array(faces)


def tessellate_part(obj, part, k=48):
    """Vertices (part canonical frame, metres) and faces of every primitive of one part, concatenated."""
    verts, faces, base = [], [], 0
    for i in range(obj.n_primitives):
        if int(obj.part_P[i]) != part:
            continue
        v, f = tessellate_primitive(int(obj.kind_P[i]), np.asarray(obj.size_Px3[i]), k)
        verts.append(v @ np.asarray(obj.rot_Px3x3[i], float).T + np.asarray(obj.trans_Px3[i], float))
        faces.append(f + base)
        base += len(v)
    return np.concatenate(verts), np.concatenate(faces)
