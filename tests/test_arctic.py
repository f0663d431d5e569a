"""ARCTIC's layout (handx_jax/interop/arctic.py): procedural clips written exactly as ARCTIC stores them and read
back (objects and states within 1e-6, part labels as ARCTIC's code reads them, with the docs' inverted labels
refused), the mesh signed distance against the analytic one, crafted pickles refused with nothing run, and MANO
forward kinematics only when a model folder is given (a tiny synthetic MANO-like model, checked against an
independent numpy implementation and known answers)."""

import json
import os
import pickle
import sys
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import sparse
from scipy.spatial.transform import Rotation

from handx_jax import objects as O
from handx_jax.interop import arctic as A
from handx_jax.infra.errors import DataError
from handx_jax.objects import mesh as mesh_lib

RNG = np.random.default_rng(5)
T = 8
N = 512


def _mano_params(T):
    return {h: {"rot": RNG.normal(size=(T, 3)) * 0.5, "pose": RNG.normal(size=(T, 45)) * 0.2,
                "trans": RNG.normal(size=(T, 3)) * 0.2, "shape": RNG.normal(size=10)} for h in ("right", "left")}


def _states(T):
    return np.c_[np.linspace(0, 0.6, T), RNG.normal(size=(T, 3)), RNG.normal(size=(T, 3)) * 0.4]


@pytest.fixture(scope="module")
def release(tmp_path_factory):
    """A fake release: two procedural objects and one sequence each, in ARCTIC's layout."""
    root = tmp_path_factory.mktemp("arctic") / "data"
    # Box-made objects: their tessellation is exact, so the mesh distance must equal the analytic one, and their
    # padded triangle tables share one compiled program (tests/test_objects.py checks curved primitives).
    objs = {"box": O.sample_instance("box", 3), "laptop": O.sample_instance("laptop", 3)}
    seqs = {}
    for name, obj in objs.items():
        A.write_object(root, name, obj, k=24)
        seq = f"s01/{name}_use_01"
        seqs[seq] = (_states(T), _mano_params(T))
        A.write_sequence(root, seq, *seqs[seq])
    return root, objs, seqs


_sdf = jax.jit(O.object_sdf)


def test_round_trip_states_mano_and_meshes(release):
    root, objs, seqs = release
    for seq, (states, mano) in seqs.items():
        got = A.read_sequence(root, seq)
        np.testing.assert_allclose(got.states_Tx7, states, atol=1e-6)
        for h in ("left", "right"):
            for k in A.MANO_FIELDS:
                np.testing.assert_allclose(got.mano[h][k], mano[h][k], atol=1e-6)
        assert got.joints_Tx2x21x3 is None and "MANO model folder" in got.joints_source
        # The raw file is ARCTIC's: a plain (T, 7) float array with the translation in millimetres.
        raw = np.load(root / "raw_seqs" / f"{seq}.object.npy")
        np.testing.assert_allclose(raw[:, 4:], states[:, 4:] * 1000, rtol=1e-6)
    for name, obj in objs.items():
        got = A.read_object(root, name)
        for part in (O.TOP, O.BOTTOM):
            v, f = mesh_lib.tessellate_part(obj, part, k=24)
            tri = np.asarray(got.tri_Fx3x3)[np.asarray(got.tri_part_F) == part]
            np.testing.assert_allclose(tri, v[f], atol=1e-6)
        # The mesh's signed distance, posed (world frame, both parts), is the analytic one: boxes tessellate exactly.
        state = np.r_[0.7, RNG.normal(size=3), 0.1, 0.0, 0.2].astype(np.float32)
        x = (RNG.normal(size=(N, 3)) * 0.06 + state[4:]).astype(np.float32)
        d_mesh = np.asarray(_sdf(O.anonymous(got), state, x)[1])
        d_true = np.asarray(_sdf(O.anonymous(obj), state, x)[1])
        np.testing.assert_allclose(d_mesh, d_true, atol=1e-5)
        assert np.array_equal(d_mesh < 0, d_true < 0) and (d_true < 0).sum() > 5


def test_part_labels_follow_arctic_code_not_docs(release, tmp_path):
    root, objs, _ = release
    d = root / "meta" / "object_vtemplates" / "box"
    labels = np.asarray(json.loads((d / "parts.json").read_text()))
    v, _ = A.read_obj(d / "mesh.obj")
    top_v, _ = A.read_obj(d / "top.obj")
    assert np.array_equal(v[labels == 0], top_v)  # label 0: the top part (ARCTIC's code articulates these)
    # Pose the read object by ARCTIC's formula (quaternion of [0, 0, -1] * angle on label-0 vertices, then the
    # global rotation and translation in mm / 1000), with scipy, and compare with the object's top part.
    obj = A.read_object(root, "box")
    state = np.array([0.9, 0.3, -0.5, 0.2, 0.1, 0.2, 0.3])
    arti = Rotation.from_rotvec(np.array([0, 0, -1.0]) * state[0])
    glob = Rotation.from_rotvec(state[1:4])
    want = glob.apply(arti.apply(v[labels == 0] / 1000)) + state[4:7]
    got = np.asarray(jax.jit(O.to_world)(O.anonymous(obj), O.TOP, state.astype(np.float32),
                                         (v[labels == 0] / 1000).astype(np.float32)))
    np.testing.assert_allclose(got, want, atol=1e-6)
    # Without top.obj / bottom.obj the parts come from mesh.obj split by the labels: the same triangles.
    alt = tmp_path / "data"
    dd = alt / "meta" / "object_vtemplates" / "box"
    dd.mkdir(parents=True)
    for f in ("mesh.obj", "parts.json"):
        (dd / f).write_text((d / f).read_text())
    split = A.read_object(alt, "box")
    np.testing.assert_allclose(np.asarray(split.tri_Fx3x3), np.asarray(obj.tri_Fx3x3), atol=0)
    # The docs' convention (1 for top) beside top.obj / bottom.obj: refused, naming parts.json.
    for f in ("top.obj", "bottom.obj"):
        (dd / f).write_text((d / f).read_text())
    (dd / "parts.json").write_text(json.dumps((1 - labels).tolist()))
    with pytest.raises(DataError, match="parts.json.*labelled 0 lie on bottom.obj"):
        A.read_object(alt, "box")


class _Boom:
    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_crafted_pickles_are_refused_with_nothing_run(release, tmp_path):
    root, _, seqs = release
    marker = tmp_path / "ran"
    boom = _Boom()
    boom.marker = marker
    bad = tmp_path / "data"
    folder = bad / "raw_seqs" / "s02"
    folder.mkdir(parents=True)
    np.save(folder / "box_grab_01.object.npy", np.zeros((T, 7), np.float32))
    np.save(folder / "box_grab_01.mano.npy", np.array({"right": boom}, dtype=object), allow_pickle=True)
    with pytest.raises(DataError, match="refusing to unpickle global .*system"):
        A.read_sequence(bad, "s02/box_grab_01")
    (tmp_path / "mano").mkdir()
    (tmp_path / "mano" / "MANO_LEFT.pkl").write_bytes(pickle.dumps({"v_template": boom}, protocol=2))
    seq = next(iter(seqs))
    # The MANO path runs only when a folder is given: without one the bad model is never opened.
    assert A.read_sequence(root, seq).joints_Tx2x21x3 is None
    with pytest.raises(DataError, match="MANO_LEFT.pkl.*refusing to unpickle global"):
        A.read_sequence(root, seq, mano_dir=tmp_path / "mano")
    assert not marker.exists()
    with pytest.raises(DataError, match="not 'sNN/<object>_<grab|use>_NN'"):
        A.read_sequence(root, "s1/box")


# ---- a tiny synthetic MANO-like model ------------------------------------------------------------------------

V, PARENTS = 778, [-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14]  # MANO's kinematic tree


def _fake_model(rng, zero=False):
    w = rng.random((V, 16)) ** 4
    reg = sparse.random(16, V, density=0.02, random_state=1, format="csc")
    reg = sparse.csc_matrix(reg.multiply(1.0 / np.maximum(reg.sum(1), 1e-9)))
    return {"v_template": rng.normal(size=(V, 3)) * 0.05, "shapedirs": rng.normal(size=(V, 3, 10)) * 1e-3,
            "posedirs": rng.normal(size=(V, 3, 135)) * 1e-3, "J_regressor": reg,
            "weights": w / w.sum(1, keepdims=True), "kintree_table": np.array([[2 ** 32 - 1] + PARENTS[1:],
                                                                              list(range(16))]),
            "hands_mean": np.zeros(45) if zero else rng.normal(size=45) * 0.1, "f": np.zeros((1, 3), np.uint32),
            "bs_style": "lbs"}


def _pickle_like_mano(model, path, protocol):
    """Pickle with shapedirs as a chumpy.ch.Ch (a stand-in module while dumping: chumpy is not installed)."""
    chumpy, ch = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x, self._dirty_vars = x, set()

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    ch.Ch = Ch
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = chumpy, ch
    try:
        path.write_bytes(pickle.dumps(dict(model, shapedirs=Ch(model["shapedirs"])), protocol=protocol))
    finally:
        del sys.modules["chumpy"], sys.modules["chumpy.ch"]


def _numpy_mano(m, rot, pose, trans, shape):
    """Independent MANO: per frame, scipy rotations, a recursive world transform per joint, per-vertex skinning."""
    out = []
    J_reg = m["J_regressor"].toarray()
    for t in range(len(rot)):
        vs = m["v_template"] + m["shapedirs"] @ shape
        J = J_reg @ vs
        rv = np.concatenate([rot[t], pose[t] + m["hands_mean"]]).reshape(16, 3)
        Rs = [Rotation.from_rotvec(r).as_matrix() for r in rv]
        vp = vs + m["posedirs"] @ np.concatenate([(R - np.eye(3)).ravel() for R in Rs[1:]])
        world = []
        for j in range(16):
            M4 = np.eye(4)
            M4[:3, :3] = Rs[j]
            M4[:3, 3] = J[j] - (J[PARENTS[j]] if j else 0)
            world.append(M4 if j == 0 else world[PARENTS[j]] @ M4)
        verts = np.zeros((V, 3))
        for v in A.MANO_TIPS:  # skinning, vertex by vertex: sum_j w_vj [R_j | t_j - R_j J_j]
            G = sum(m["weights"][v, j] * np.c_[world[j][:, :3], world[j][:, 3] - world[j][:, :3] @ J[j]]
                    for j in range(16))
            verts[v] = G[:3, :3] @ vp[v] + G[:3, 3]
        out.append(np.concatenate([[w[:3, 3] for w in world], verts[list(A.MANO_TIPS)]]) + trans[t])
    return np.stack(out)


def test_mano_joints_from_a_model_folder(release, tmp_path):
    root, _, seqs = release
    seq = next(iter(seqs))
    states, mano = seqs[seq]
    folder = tmp_path / "mano"
    folder.mkdir()
    models = {}
    for hand, protocol in (("right", 2), ("left", 0)):  # NEWOBJ and copyreg._reconstructor pickles
        models[hand] = _fake_model(np.random.default_rng(len(hand)))
        _pickle_like_mano(models[hand], folder / f"MANO_{hand.upper()}.pkl", protocol)
    got = A.read_sequence(root, seq, mano_dir=folder)
    assert got.joints_Tx2x21x3.shape == (T, 2, 21, 3) and "MANO" in got.joints_source
    for i, hand in enumerate(A.HANDS):
        want = _numpy_mano(models[hand], *(mano[hand][k] for k in ("rot", "pose", "trans", "shape")))
        np.testing.assert_allclose(got.joints_Tx2x21x3[:, i], want, atol=1e-5)
    # Known answer: rest pose, mean shape, flat mean: the regressor's joints and the tip vertices, translated.
    m = _fake_model(np.random.default_rng(9), zero=True)
    _pickle_like_mano(m, folder / "MANO_RIGHT.pkl", 2)
    z = np.zeros((2, 3))
    j = A.mano_joints(A.load_mano_model(folder, "right"), z, np.zeros((2, 45)), z + [0.1, 0.2, 0.3], np.zeros(10))
    want = np.concatenate([m["J_regressor"].toarray() @ m["v_template"], m["v_template"][list(A.MANO_TIPS)]])
    np.testing.assert_allclose(j[0], want + [0.1, 0.2, 0.3], atol=1e-9)
    # Without a model folder, ARCTIC's processed joints are read where present.
    A.write_processed_joints(root, seq, got.joints_Tx2x21x3)
    again = A.read_sequence(root, seq)
    np.testing.assert_allclose(again.joints_Tx2x21x3, got.joints_Tx2x21x3, atol=1e-6)
    assert "processed" in again.joints_source


# ---- object to motion from ARCTIC's layout (issue 53 item 4) -------------------------------------------------

def test_object_trajectory_alone_and_bad_files_refused(release, tmp_path):
    """The trajectory reads without the hand file, as the object-to-motion task needs; a missing sequence, a wrong
    shape, NaN or a crafted pickle is one DataError naming the file."""
    root, _, seqs = release
    seq, (states, _) = next(iter(seqs.items()))
    np.testing.assert_allclose(A.read_object_states(root, seq), states, atol=1e-6)
    folder = tmp_path / "data" / "raw_seqs" / "s03"
    folder.mkdir(parents=True)
    cases = {"box_use_01": (np.zeros((T, 6), np.float32), r"expected a \(T, 7\) numeric array, got \(8, 6\)"),
             "box_use_02": (np.full((T, 7), np.nan, np.float32), "non-finite"),
             "box_use_03": (np.array({"angle": 1.0}, dtype=object), r"expected a \(T, 7\) numeric array, got dict")}
    for name, (arr, msg) in cases.items():
        np.save(folder / f"{name}.object.npy", arr, allow_pickle=True)
        with pytest.raises(DataError, match=msg) as e:
            A.read_object_states(tmp_path / "data", f"s03/{name}")
        assert f"{name}.object.npy" in str(e.value) and "\n" not in str(e.value)
    marker = tmp_path / "ran"
    boom = _Boom()
    boom.marker = marker
    np.save(folder / "box_use_04.object.npy", np.array([boom], dtype=object), allow_pickle=True)
    with pytest.raises(DataError, match="refusing to unpickle global"):
        A.read_object_states(tmp_path / "data", "s03/box_use_04")
    assert not marker.exists()
    with pytest.raises(DataError, match="no object trajectory for sequence 's03/box_use_09'"):
        A.read_object_states(tmp_path / "data", "s03/box_use_09")


def test_mesh_arrays_rebuild_the_object(release):
    """What an object2motion file carries of a mesh object rebuilds it exactly (triangles, parts, range)."""
    root, _, _ = release
    obj = A.read_object(root, "laptop")
    a = A.mesh_arrays(obj)
    back = A.object_from_mesh_arrays(a["tri"], a["part"], "laptop", a["angle_range"])
    for f in ("tri_Fx3x3", "tri_part_F", "angle_range_2"):
        assert np.array_equal(np.asarray(getattr(back, f)), np.asarray(getattr(obj, f))), f
    with pytest.raises(DataError, match="triangles on both parts"):
        A.object_from_mesh_arrays(a["tri"], np.full_like(a["part"], O.TOP), "laptop", a["angle_range"])


def test_arctic_windows_are_the_model_inputs_of_the_trajectory(release):
    """families/bimart/common.arctic_windows: consecutive windows of the model's frames (the rest left out) or the one
    from --start; G of the features is the window's own trajectory (relative to its first frame), s_o that of the
    primitive object the mesh tessellates exactly, the contact condition "far" where the sequence has no hands."""
    from handx_jax.families.bimart import common as C
    from handx_jax.models import bimart as BM
    from handx_jax.objects.bps import DEFAULT_SCALE_ANGLE
    from handx_jax.objects.features import global_states

    root, objs, seqs = release
    cfg = BM.BimArtConfig(BM.BlockConfig(1, 32, 2, 64), k=8, keypoints=4, frames=3)
    seq = "s01/laptop_use_01"  # no hands (test_mano_joints_from_a_model_folder gives the box's sequence some)
    states = seqs[seq][0]
    d = C.arctic_windows(root, seq, cfg)
    assert d.clips.tolist() == [0, 3] and [r["start"] for r in d.records] == [0, 3]  # frames 6-7 left out
    np.testing.assert_allclose(d.states, np.stack([states[0:3], states[3:6]]), atol=1e-6)
    G = np.asarray(global_states(jnp.asarray(d.states)))
    np.testing.assert_allclose(d.obj[..., -7:-1], G, atol=1e-6)
    s_true = C.object_scales([objs["laptop"]], [DEFAULT_SCALE_ANGLE])[0]
    assert d.obj[0, 0, -1] == pytest.approx(s_true, rel=0.02) and d.obj.shape[-1] == 6 * cfg.k + 7
    assert d.joints is None and np.all(d.contact == 1.0) and d.objects[0].tri_Fx3x3 is not None
    one = C.arctic_windows(root, seq, cfg, start=5)
    np.testing.assert_allclose(one.states[0], states[5:8], atol=1e-6)
    with pytest.raises(DataError, match=r"--start 6: the sequence has 8 frames, a window of 3 starts in \[0, 5\]"):
        C.arctic_windows(root, seq, cfg, start=6)
    with pytest.raises(DataError, match="fewer than the model's window of 60"):
        C.arctic_windows(root, seq, BM.BimArtConfig(k=8))


def test_refinement_energies_on_a_mesh_are_the_primitives(release):
    """Refinement's penetration and projection terms read the object's signed distance: on the box's exact
    tessellation they equal the primitive box's (physics.energies, a few frames of hands near the lid)."""
    from handx_jax.families.bimart import common as C
    from handx_jax.families.bimart import physics as PH
    from handx_jax.models import bimart as BM

    root, objs, seqs = release
    cfg = BM.BimArtConfig(BM.BlockConfig(1, 32, 2, 64), k=8, keypoints=4)
    states = jnp.asarray(seqs["s01/box_use_01"][0][:3], jnp.float32)
    rng = np.random.default_rng(3)
    joints = jnp.asarray(states[:, None, None, 4:7] + rng.normal(size=(3, 2, 21, 3)) * 0.05, jnp.float32)
    H = C.keypoints(joints, cfg)
    D = jnp.asarray(rng.normal(size=H.shape) * 0.01, jnp.float32)
    mesh = PH.energies_jit(joints, H, D, A.read_object(root, "box"), states, cfg)
    prim = PH.energies_jit(joints, H, D, O.anonymous(objs["box"]), states, cfg)
    assert float(prim["pen"]) > 0
    for k in ("proj", "pen"):
        assert float(mesh[k]) == pytest.approx(float(prim[k]), rel=1e-4, abs=1e-9), k
