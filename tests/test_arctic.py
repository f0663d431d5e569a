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
