"""BimArt's articulated objects (handx_jax/objects): exact primitive signed distances against independent numpy
geometry and a brute-force surface search, the Eikonal property, area-uniform surface samples, ARCTIC's hinge
convention (top part about -z), the categories' sizes and ranges, and jit / vmap / grad."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from handx_jax import objects as O
from handx_jax.objects import primitives as prim
from scipy.spatial.transform import Rotation

RNG = np.random.default_rng(7)


def _single(kind, size, rot=np.eye(3), trans=np.zeros(3)):
    """An object whose bottom part is one primitive (the top part empty: padding rows only)."""
    pad = dict(kind=0, part=O.NO_PART, size=np.zeros(3), rot=np.eye(3), trans=np.zeros(3))
    rows = [dict(kind=kind, part=O.BOTTOM, size=np.asarray(size, float), rot=rot, trans=trans)] + [pad] * 7
    f = lambda k, dt: jnp.asarray(np.stack([r[k] for r in rows]), dt)
    return O.ArticulatedObject(f("kind", jnp.int32), f("part", jnp.int32), f("size", jnp.float32),
                               f("rot", jnp.float32), f("trans", jnp.float32), jnp.array([0.0, 1.0]),
                               jnp.array([0.0, 1.0, 0.0]), "single")


# Independent numpy geometry: the nearest point on the solid (outside) or the nearest face (inside).
def _np_box(q, s):
    outside = np.linalg.norm(q - np.clip(q, -s, s), axis=1)
    inside = -np.min(s - np.abs(q), axis=1)
    return np.where(np.all(np.abs(q) <= s, axis=1), inside, outside)


def _np_cylinder(q, s):
    r, h = s[0], s[1]
    rho = np.hypot(q[:, 0], q[:, 1])
    near_rho, near_z = np.minimum(rho, r), np.clip(q[:, 2], -h, h)
    outside = np.hypot(rho - near_rho, q[:, 2] - near_z)
    inside = -np.minimum(r - rho, h - np.abs(q[:, 2]))
    return np.where((rho <= r) & (np.abs(q[:, 2]) <= h), inside, outside)


def _np_capsule(q, s):
    seg = np.stack([np.zeros(len(q)), np.zeros(len(q)), np.clip(q[:, 2], -s[1], s[1])], 1)
    return np.linalg.norm(q - seg, axis=1) - s[0]


def _np_torus(q, s):
    rho = np.hypot(q[:, 0], q[:, 1])
    circle = np.stack([q[:, 0], q[:, 1], np.zeros(len(q))], 1) * (s[0] / np.maximum(rho, 1e-12))[:, None]
    return np.linalg.norm(q - circle, axis=1) - s[1]


CASES = [("box", prim.BOX, (0.05, 0.02, 0.035), _np_box), ("cylinder", prim.CYLINDER, (0.03, 0.06, 0), _np_cylinder),
         ("capsule", prim.CAPSULE, (0.015, 0.04, 0), _np_capsule), ("torus", prim.TORUS, (0.04, 0.01, 0), _np_torus)]


def _pose():
    return Rotation.from_rotvec(RNG.normal(size=3)).as_matrix(), RNG.normal(size=3) * 0.05


# A few programs, each compiled once for every object here (tables padded to one shape, names stripped) and
# called with N = 512 points: XLA's compile time is most of these tests' CPU.
N = 512
_canon = jax.jit(O.canonical_part_sdf)
_canon_grad = jax.jit(jax.vmap(jax.grad(lambda o, part, x: O.canonical_part_sdf(o, part, x[None])[0], 2),
                               (None, None, 0)))
_world = jax.jit(O.object_sdf)
_to_world = jax.jit(O.to_world)
_pose_jit = jax.jit(O.part_pose)


def canon(obj, part, x):
    return np.asarray(_canon(O.anonymous(obj), part, jnp.asarray(x, jnp.float32)))


def canon_grad(obj, part, x):
    return np.asarray(_canon_grad(O.anonymous(obj), part, jnp.asarray(x, jnp.float32)))


def world_sdf(obj, st, x):
    return [np.asarray(v) for v in _world(O.anonymous(obj), st, x)]


def to_world(obj, part, st, x):
    return _to_world(O.anonymous(obj), part, st, x)


@pytest.fixture(scope="module")
def sdf_fn():
    return lambda obj, p: canon(obj, O.BOTTOM, p)


@pytest.mark.parametrize("name,kind,size,reference", CASES, ids=[c[0] for c in CASES])
def test_primitive_sdf_matches_independent_geometry(sdf_fn, name, kind, size, reference):
    R, t = _pose()
    obj = _single(kind, size, R, t)
    a, b = size[0], size[1]
    box = {"box": size, "cylinder": (a, a, b), "capsule": (a, a, a + b), "torus": (a + b, a + b, b)}[name]
    q = RNG.uniform(-1.5, 1.5, size=(N, 3)) * np.asarray(box)  # local points, 12-30% of them inside
    d = np.asarray(sdf_fn(obj, jnp.asarray(q @ R.T + t, jnp.float32)))
    np.testing.assert_allclose(d, reference(q, np.asarray(size, float)), atol=2e-6)
    assert (d < 0).sum() > 20 and (d > 0).sum() > 20


def _np_surface_grid(kind, s, k=120):
    """Dense surface points from each shape's own parameterisation (numpy, not the sampler under test)."""
    u = np.linspace(0, 1, k)
    U, V = [a.ravel() for a in np.meshgrid(u, u)]
    phi, th = 2 * np.pi * U, 2 * np.pi * V
    if kind == prim.BOX:
        faces = []
        for ax in range(3):
            i1, i2 = (ax + 1) % 3, (ax + 2) % 3
            for sign in (-1, 1):
                f = np.zeros((len(U), 3))
                f[:, ax], f[:, i1], f[:, i2] = sign * s[ax], (2 * U - 1) * s[i1], (2 * V - 1) * s[i2]
                faces.append(f)
        return np.concatenate(faces)
    if kind == prim.CYLINDER:
        side = np.stack([s[0] * np.cos(phi), s[0] * np.sin(phi), (2 * V - 1) * s[1]], 1)
        caps = [np.stack([s[0] * V * np.cos(phi), s[0] * V * np.sin(phi), np.full_like(V, z)], 1) for z in (-s[1], s[1])]
        return np.concatenate([side] + caps)
    if kind == prim.CAPSULE:
        side = np.stack([s[0] * np.cos(phi), s[0] * np.sin(phi), (2 * V - 1) * s[1]], 1)
        sph = np.stack([np.cos(phi) * np.sin(th / 2), np.sin(phi) * np.sin(th / 2), np.cos(th / 2)], 1) * s[0]
        sph[:, 2] += np.where(sph[:, 2] >= 0, s[1], -s[1])
        return np.concatenate([side, sph])
    return np.stack([(s[0] + s[1] * np.cos(th)) * np.cos(phi), (s[0] + s[1] * np.cos(th)) * np.sin(phi),
                     s[1] * np.sin(th)], 1)


@pytest.mark.parametrize("name,kind,size,reference", CASES, ids=[c[0] for c in CASES])
def test_primitive_distance_is_the_brute_force_nearest_surface_point(sdf_fn, name, kind, size, reference):
    s = np.asarray(size, float)
    grid = _np_surface_grid(kind, s)
    q = RNG.uniform(-0.07, 0.07, size=(N, 3))[:60]
    q = np.concatenate([q, np.zeros((N - 60, 3))])
    brute = np.array([np.sqrt(((grid - x) ** 2).sum(1).min()) for x in q[:60]])
    d = sdf_fn(_single(kind, size), q)
    # The grid's cells are under 2.7 mm x 1.6 mm on every shape here, so a grid point lies within 1.6 mm of
    # the nearest surface point; and no surface point is nearer than the exact distance.
    assert np.all(np.abs(np.abs(d[:60]) - brute) < 1.6e-3) and np.all(np.abs(d[:60]) <= brute + 1e-6)


@pytest.mark.parametrize("name,kind,size,reference", CASES, ids=[c[0] for c in CASES])
def test_eikonal_and_normals(name, kind, size, reference):
    R, t = _pose()
    obj = _single(kind, size, R, t)
    p, n = (np.asarray(v) for v in O.surface_samples(obj, O.BOTTOM, N, 3))
    np.testing.assert_allclose(canon(obj, O.BOTTOM, p), 0.0, atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(n), axis=1), 1.0, atol=1e-5)
    # Just outside and (by a quarter of the thinnest half-size, short of any medial axis) inside, |grad| = 1
    # and the gradient is the sampled outward normal.
    depth = 0.25 * min(v for v in size if v > 0)
    for off in (1e-3, -depth):
        x = p + off * n
        # Keep the points whose nearest surface point is still their sample (inside, near an edge, another
        # face can be nearer): there the distance is |off|.
        keep = np.abs(np.abs(canon(obj, O.BOTTOM, x)) - abs(off)) < 2e-6
        assert keep.mean() > 0.5
        g = canon_grad(obj, O.BOTTOM, x)[keep]
        np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-4)
        np.testing.assert_allclose(g, np.asarray(n)[keep], atol=1e-3)
    far = RNG.uniform(-0.3, 0.3, (N, 3)) + t
    g = canon_grad(obj, O.BOTTOM, far)[np.abs(canon(obj, O.BOTTOM, far)) > 1e-4]
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-4)


def test_samples_are_uniform_by_area_on_a_union():
    cab = O.sample_instance("cabinet", 1)
    ps, ns = zip(*[O.surface_samples(cab, O.TOP, N, seed) for seed in range(8)])
    p = np.concatenate(ps)
    assert max(np.abs(canon(cab, O.TOP, x)).max() for x in ps) < 2e-6
    # The door (box) and knob (cylinder) touch: the union's area drops the two glued discs, and no sample lies on
    # them (the knob's base cap and the door face under it).
    size, trans = np.asarray(cab.size_Px3), np.asarray(cab.trans_Px3)
    door, (kr, kh) = size[0], size[1][:2]
    knob_area = 2 * np.pi * kr * 2 * kh + np.pi * kr ** 2
    union = 8 * (door[0] * door[1] + door[1] * door[2] + door[0] * door[2]) + knob_area - np.pi * kr ** 2
    base_y = trans[1, 1] - kh  # the knob's glued base, on the door's front face
    radial = np.hypot(p[:, 0] - trans[1, 0], p[:, 2] - trans[1, 2])
    on_knob = (p[:, 1] > base_y + 1e-6) & (radial < kr + 1e-5)
    frac, expect, m = on_knob.mean(), knob_area / union, len(p)
    assert abs(frac - expect) < 4 * math.sqrt(expect * (1 - expect) / m)
    assert not ((np.abs(p[:, 1] - base_y) < 1e-6) & (radial < kr - 1e-4)).any()
    # A torus's outer half (cos phi > 0) holds (pi R + 2 r) / (2 pi R) of its area.
    R, r = 0.04, 0.012
    tor = _single(prim.TORUS, (R, r, 0))
    p = np.concatenate([O.surface_samples(tor, O.BOTTOM, N, seed)[0] for seed in range(8)])
    outer = (np.hypot(p[:, 0], p[:, 1]) > R).mean()
    expect = (math.pi * R + 2 * r) / (2 * math.pi * R)
    assert abs(outer - expect) < 4 * math.sqrt(expect * (1 - expect) / len(p))


def test_hinge_is_arctic_convention_and_poses_invert():
    box = O.sample_instance("box", 2)
    st = np.array([math.pi / 2, 0, 0, 0, 0, 0, 0], np.float32)
    # Rotation about -z by 90 degrees: -x -> +y (a lid lying along -x from the hinge stands up), z fixed.
    pts = np.zeros((N, 3), np.float32)
    pts[:3] = [[-1.0, 0, 0], [0, 0, 0.3], [0, 1.0, 0]]
    np.testing.assert_allclose(np.asarray(to_world(box, O.TOP, st, pts))[:3], [[0, 1, 0], [0, 0, 0.3], [1, 0, 0]],
                               atol=1e-6)
    np.testing.assert_allclose(np.asarray(to_world(box, O.BOTTOM, st, pts)), np.asarray(pts), atol=0)
    state = np.r_[0.7, RNG.normal(size=3), RNG.normal(size=3)].astype(np.float32)
    x = (RNG.normal(size=(N, 3)) * 0.1).astype(np.float32)
    for part in (O.TOP, O.BOTTOM):
        R, t = (np.asarray(v) for v in _pose_jit(O.anonymous(box), state))
        np.testing.assert_allclose((np.asarray(to_world(box, part, state, x)) - t[part]) @ R[part], np.asarray(x),
                                   atol=1e-5)
        # A rigid motion moves the distance field with the part.
        np.testing.assert_allclose(world_sdf(box, state, to_world(box, part, state, x))[1][part],
                                   canon(box, part, x), atol=1e-5)
    np.testing.assert_allclose(R[0] @ R[0].T, np.eye(3), atol=1e-5)
    np.testing.assert_allclose(R[1], Rotation.from_rotvec(state[1:4]).as_matrix(), atol=1e-5)  # axis-angle
    np.testing.assert_allclose(np.asarray(_pose_jit(O.anonymous(box), np.zeros(7, np.float32))[0]),
                               np.stack([np.eye(3)] * 2), atol=0)  # the identity, where Rodrigues is 0 / 0
    # The top part's rotation relative to the bottom is about the hinge (-z) by the angle.
    rel = np.asarray(R[1].T @ R[0])
    np.testing.assert_allclose(rel @ [0, 0, 1], [0, 0, 1], atol=1e-5)
    assert abs(math.acos((np.trace(rel) - 1) / 2) - 0.7) < 1e-4


@pytest.mark.parametrize("name", sorted(O.CATEGORIES))
def test_categories_are_realistic_and_parts_do_not_interpenetrate(name):
    cat = O.CATEGORIES[name]
    lo, hi = cat.angle_range
    assert lo == 0 and {"box": 110, "laptop": 180, "scissors": 40, "cabinet": 110, "bottle": 170}[name] == \
        round(math.degrees(hi))
    a, b = cat.sample(11), cat.sample(11)
    assert all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))
    assert not np.array_equal(np.asarray(cat.sample(12).size_Px3), np.asarray(a.size_Px3))
    sizes = cat.draw_sizes(11)
    assert all(cat.sizes[k][0] <= v <= cat.sizes[k][1] for k, v in sizes.items())
    # At every angle of the range, no surface point of one part lies inside the other (beyond float error).
    top, _ = O.surface_samples(a, O.TOP, N, 0)
    bottom, _ = O.surface_samples(a, O.BOTTOM, N, 0)
    for angle in np.linspace(lo, hi, 5):
        st = np.array([angle, 0.3, -0.2, 0.1, 0.5, 0.0, 0.2], np.float32)
        _, d_top = world_sdf(a, st, to_world(a, O.TOP, st, top))
        _, d_bot = world_sdf(a, st, to_world(a, O.BOTTOM, st, bottom))
        assert d_top[1].min() > -1e-5 and d_bot[0].min() > -1e-5
    # The object has a plausible size: its bottom part fits in a 1.2 m cube and is over 5 cm across.
    ext = np.ptp(np.asarray(bottom), axis=0).max()
    assert 0.05 < ext < 1.2


def test_jit_vmap_grad():
    objs = [O.anonymous(O.sample_instance(name, 4)) for name in ("laptop", "scissors", "bottle")]
    stacked = jax.tree.map(lambda *x: np.stack(x), *objs)  # categories share one padded table shape
    x = (RNG.normal(size=(N, 3)) * 0.1).astype(np.float32)
    st = np.r_[0.4, RNG.normal(size=6) * 0.1].astype(np.float32)

    def loss(obj, s, pts):
        return jnp.sum(jnp.tanh(O.part_sdf(obj, O.TOP, s, pts) / 0.05))

    # vmap over instances of three categories (one padded shape), then the gradient w.r.t. the state (the
    # guidance needs it) of the top part, which depends on all seven numbers.
    d = np.asarray(jax.jit(jax.vmap(O.object_sdf, (0, None, None)))(stacked, st, x)[1])
    for i, obj in enumerate(objs):
        np.testing.assert_allclose(d[i], world_sdf(obj, st, x)[1], atol=1e-6)
    g_state = np.asarray(jax.jit(jax.grad(loss, 1))(objs[0], st, x))
    eps, st_np = 1e-3, np.asarray(st)
    fd = []
    for j in range(7):
        hi, lo = st_np.copy(), st_np.copy()
        hi[j] += eps
        lo[j] -= eps
        fd.append((np.sum(np.tanh(world_sdf(objs[0], hi, x)[1][O.TOP] / 0.05))
                   - np.sum(np.tanh(world_sdf(objs[0], lo, x)[1][O.TOP] / 0.05))) / (2 * eps))
    # float32 differences of a 512-point sum, and the few points whose nearest face changes within eps
    # (a distance field has kinks on its medial axes), allow a few percent.
    np.testing.assert_allclose(g_state, fd, atol=0.04 * np.abs(fd).max())
    assert np.abs(g_state[0]) > 0  # the angle moves the top part
