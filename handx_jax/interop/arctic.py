"""ARCTIC's file layout (Fan et al., CVPR 2023; BimArt's data, §4), read and written.

What ARCTIC's own code does, which this module follows (github.com/zc-alexfan/arctic):
- ``raw_seqs/sNN/{obj}_{grab|use}_NN.object.npy``: a plain (T, 7) float array, [angle (rad), axis-angle (3),
  translation (3, millimetres)]; ``src/arctic/processing.py`` passes ``obj_trans / 1000`` to the object layer.
- ``raw_seqs/sNN/{seq}.mano.npy``: ``np.save`` of a dict (a pickled object array) ``{"right": {...}, "left":
  {...}}``, each with ``rot`` (T, 3), ``pose`` (T, 45) axis-angle, ``trans`` (T, 3) metres, ``shape`` (10,) (the
  loader repeats it per frame) and ``fitting_err`` (T,). Read with ``smplx.MANO(use_pca=False,
  flat_hand_mean=False)`` (``common/body_models.py``), patched to return 21 joints: the 16 of the regressor and
  the fingertip vertices 744, 320, 443, 554, 671 (thumb, index, middle, ring, pinky; ``docs/setup.md``), which is
  this project's joint order (skeleton.py).
- ``meta/object_vtemplates/{obj}/mesh.obj`` (millimetres; ``common/object_tensors.py`` divides by 1000) with
  ``parts.json``, one label per mesh vertex, and ``top.obj`` / ``bottom.obj``, the two parts' own meshes.
  THE TRAP: ``docs/data/data_doc.md`` says parts.json holds "1 for top; 0 for bottom", but ``construct_obj``
  reads it as bool, ``construct_obj_tensors`` adds 1, and ``forward_7d_batch`` articulates ``parts_ids == 1``,
  i.e. the vertices labelled 0. The code is what produced ARCTIC's results, so label 0 is the top part here
  (objects.TOP). ``read_object`` checks the labels against top.obj / bottom.obj where they exist and refuses
  labels that are the other way round.
- Articulation: ``quat_arti = axis_angle_to_quaternion([0, 0, -1] * angle)`` on the top part, then the global
  rotation and translation on both parts: objects/articulated.py's convention.
- ``processed_seqs/sNN/{seq}.npy``: a pickled dict whose ``world_coord`` holds ``joints.right`` / ``joints.left``
  (T, 21, 3) metres, where the release's processing has been run.

Every pickle goes through the project's restricted unpickler (safe_pickle.py): NumPy arrays and plain
containers, plus, for MANO's model file only, inert stand-ins for ``chumpy.ch.Ch`` (its ``x`` array) and
``scipy.sparse`` CSC/CSR matrices (their arrays). Nothing a pickle names is imported or called.
"""

from __future__ import annotations

import copyreg
import io
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib import format as npy_format

from handx_jax import skeleton as sk
from handx_jax.infra.errors import DataError
from handx_jax.objects import BOTTOM, TOP, ArticulatedObject
from handx_jax.objects import mesh as mesh_lib
from handx_jax.infra.safe_pickle import RestrictedUnpickler

MM = 1000.0  # ARCTIC's object files are millimetres; this project is metres
SEQ_RE = re.compile(r"^(?P<object>[a-z]+)_(?P<kind>grab|use)_(?P<num>\d+)$")
MANO_TIPS = (744, 320, 443, 554, 671)  # smplx vertex_ids["mano"]: thumb, index, middle, ring, pinky
HANDS = ("left", "right")  # skeleton.py: hand 0 = LEFT, 1 = RIGHT
MANO_FIELDS = ("rot", "pose", "trans", "shape")


# ---- restricted reading -------------------------------------------------------------------------------------

class _ArcticUnpickler(RestrictedUnpickler):
    what = "ARCTIC files"


class _Inert:
    """A pickled instance of an admitted foreign class, kept as its plain state (never its class's code)."""

    def __setstate__(self, state):
        self.state = state[0] if isinstance(state, tuple) and state and isinstance(state[0], dict) else state


class _ChumpyCh(_Inert):
    """chumpy.ch.Ch: its ``__getstate__`` is its ``__dict__``, whose ``x`` is the array (chumpy/ch.py)."""


class _SparseMatrix(_Inert):
    """scipy.sparse csc/csr_matrix: ``data``, ``indices``, ``indptr``, ``_shape`` in its ``__dict__``."""
    fmt = "csc"


class _SparseCSR(_SparseMatrix):
    fmt = "csr"


class _PickleRefused(Exception):
    """A call the restricted unpickler will not make (turned into a DataError naming the file)."""


def _reconstructor(cls, base, state):
    """copyreg._reconstructor, restricted to the inert stand-ins (protocol 0/1 pickles of new-style objects)."""
    if not (isinstance(cls, type) and issubclass(cls, _Inert)) or base is not object or state is not None:
        raise _PickleRefused(f"copyreg._reconstructor({cls!r}, {base!r}, ...)")
    return object.__new__(cls)


class _ManoUnpickler(_ArcticUnpickler):
    what = "MANO model files"

    def _extra_globals(self):
        table = {("chumpy.ch", "Ch"): _ChumpyCh}
        for mod in ("scipy.sparse.csc", "scipy.sparse._csc"):
            table[(mod, "csc_matrix")] = _SparseMatrix
        for mod in ("scipy.sparse.csr", "scipy.sparse._csr"):
            table[(mod, "csr_matrix")] = _SparseCSR
        for mod in ("copy_reg", "copyreg"):
            table[(mod, "_reconstructor")] = _reconstructor
        # _reconstructor's base argument; calling ``object`` itself builds an empty object, nothing more.
        for mod in ("__builtin__", "builtins"):
            table[(mod, "object")] = object
        return table

    def _unknown_global(self, module, name):
        raise self.error(f"refusing to unpickle global {module}.{name}: a MANO model file holds NumPy arrays, "
                         f"chumpy.ch.Ch and scipy.sparse matrices only (possibly malicious file)")


def _unpickle(f, path, unpickler=_ArcticUnpickler, key=None):
    try:
        return unpickler(f, path=path, key=key).load()
    except DataError:
        raise
    except _PickleRefused as e:
        raise DataError(f"refusing to unpickle {e} (possibly malicious file)", path=path) from None
    except Exception as e:  # a corrupt or truncated payload: EOFError, UnpicklingError, ...
        raise DataError(f"corrupt pickled payload ({type(e).__name__}: {e})", path=path) from None


def load_npy(path) -> Any:
    """An ``.npy`` file: plain arrays as they are; object arrays (``np.save`` of a dict) through the restricted
    unpickler, a 0-d object array unwrapped (``.item()``, as ARCTIC's loaders do)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise DataError(f"cannot read: {e.strerror or e}", path=path) from None
    f = io.BytesIO(data)
    try:
        version = npy_format.read_magic(f)
        read_header = {(1, 0): npy_format.read_array_header_1_0, (2, 0): npy_format.read_array_header_2_0}
        if version not in read_header:
            raise ValueError(f"unsupported .npy format version {version}")
        shape, fortran, dtype = read_header[version](f)
    except (ValueError, EOFError, SyntaxError, TypeError) as e:
        raise DataError(f"not a valid .npy file: {e}", path=path) from None
    if dtype.hasobject:
        arr = _unpickle(f, path)
        if isinstance(arr, np.ndarray) and arr.dtype.hasobject and arr.shape == ():
            return arr.item()
        return arr
    count = int(np.prod(shape))
    raw = f.read(count * dtype.itemsize)
    if len(raw) != count * dtype.itemsize:
        raise DataError("array data is truncated", path=path)
    arr = np.frombuffer(raw, dtype=dtype, count=count)
    return (arr.reshape(shape[::-1]).T if fortran else arr.reshape(shape)).copy()


# ---- meshes -------------------------------------------------------------------------------------------------

def read_obj(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangle faces (F, 3) of a Wavefront .obj (polygons fanned into triangles)."""
    path = Path(path)
    verts, faces = [], []
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise DataError(f"cannot read mesh: {e}", path=path) from None
    for n, line in enumerate(lines, 1):
        tok = line.split()
        if not tok:
            continue
        try:
            if tok[0] == "v":
                verts.append([float(x) for x in tok[1:4]])
            elif tok[0] == "f":
                idx = [int(t.split("/")[0]) for t in tok[1:]]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces += [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]
        except (ValueError, IndexError):
            raise DataError(f"line {n}: cannot parse {line.strip()[:60]!r}", path=path) from None
    v, f = np.asarray(verts, np.float64).reshape(-1, 3), np.asarray(faces, np.int64).reshape(-1, 3)
    if len(v) == 0 or len(f) == 0:
        raise DataError("mesh has no vertices or no faces", path=path)
    if f.min() < 0 or f.max() >= len(v):
        raise DataError(f"a face indexes vertex {int(f.max()) + 1} of {len(v)}", path=path)
    return v, f


def write_obj(path, verts_Vx3, faces_Fx3):
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in np.asarray(verts_Vx3, np.float64)]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces_Fx3)]
    Path(path).write_text("\n".join(lines) + "\n")


def mesh_object(tri_top_Fx3x3, tri_bottom_Fx3x3, category: str, angle_range=(0.0, np.pi)) -> ArticulatedObject:
    """An ArticulatedObject whose parts are triangle meshes (metres, canonical frame), no primitives."""
    tri = np.concatenate([tri_top_Fx3x3, tri_bottom_Fx3x3])
    part = np.r_[np.full(len(tri_top_Fx3x3), TOP), np.full(len(tri_bottom_Fx3x3), BOTTOM)]
    tri, part = mesh_lib.pad_triangles(tri, part)
    z = np.zeros((0,))
    return ArticulatedObject(kind_P=z.astype(np.int32), part_P=z.astype(np.int32), size_Px3=np.zeros((0, 3), np.float32),
                             rot_Px3x3=np.zeros((0, 3, 3), np.float32), trans_Px3=np.zeros((0, 3), np.float32),
                             angle_range_2=np.asarray(angle_range, np.float32),
                             up_3=np.array([0.0, 1.0, 0.0], np.float32), category=category, tri_Fx3x3=tri,
                             tri_part_F=part)


def mesh_arrays(obj: ArticulatedObject) -> dict:
    """What rebuilds a mesh object (``object_from_mesh_arrays``): its padded triangles (F, 3, 3) metres, their parts
    (F,) and its articulation range (2,); plain arrays, for a file that must score the object without ARCTIC."""
    if obj.tri_Fx3x3 is None:
        raise ValueError("not a mesh object")
    return {"tri": np.asarray(obj.tri_Fx3x3, np.float32), "part": np.asarray(obj.tri_part_F, np.int32),
            "angle_range": np.asarray(obj.angle_range_2, np.float32)}


def object_from_mesh_arrays(tri_Fx3x3, part_F, category: str, angle_range_2, path=None) -> ArticulatedObject:
    """``mesh_arrays``' inverse (padding rows, part -1, dropped and re-added by ``mesh_object``)."""
    tri, part = np.asarray(tri_Fx3x3, np.float32), np.asarray(part_F)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3) or part.shape != tri.shape[:1] or not np.isfinite(tri).all():
        raise DataError(f"mesh triangles (F, 3, 3) with one part each expected, got {tri.shape} and {part.shape}",
                        path=path, field="mesh_tri")
    top, bottom = tri[part == TOP], tri[part == BOTTOM]
    if not len(top) or not len(bottom):
        raise DataError("a mesh object needs triangles on both parts", path=path, field="mesh_part")
    return mesh_object(top, bottom, category, tuple(np.asarray(angle_range_2, np.float64)))


def _template_dir(root, name) -> Path:
    return Path(root) / "meta" / "object_vtemplates" / name


def read_object(root, name: str) -> ArticulatedObject:
    """ARCTIC's object template ``{root}/meta/object_vtemplates/{name}/`` as a mesh ArticulatedObject.

    The parts' signed distances use ``top.obj`` / ``bottom.obj`` where both exist (each a part's own mesh);
    otherwise ``mesh.obj``'s faces split by ``parts.json`` (label 0 = top, as ARCTIC's code reads it)."""
    d = _template_dir(root, name)
    v, f = read_obj(d / "mesh.obj")
    labels = _read_parts(d / "parts.json", len(v))
    top_mask = labels == 0  # ARCTIC's code: bool(label) + 1 == 1 -> articulated (see module docstring)
    if (d / "top.obj").exists() and (d / "bottom.obj").exists():
        vt, ft = read_obj(d / "top.obj")
        vb, fb = read_obj(d / "bottom.obj")
        _check_labels(d / "parts.json", v, top_mask, vt, vb)
        tri_top, tri_bottom = vt[ft] / MM, vb[fb] / MM
    else:
        majority_top = top_mask[f].sum(1) >= 2
        tri_top, tri_bottom = v[f[majority_top]] / MM, v[f[~majority_top]] / MM
        if not len(tri_top) or not len(tri_bottom):
            raise DataError("parts.json puts every face in one part", path=d / "parts.json")
    return mesh_object(tri_top, tri_bottom, name)


def _read_parts(path, n_verts) -> np.ndarray:
    try:
        labels = np.asarray(json.loads(Path(path).read_text()))
    except (OSError, ValueError) as e:
        raise DataError(f"cannot read part labels: {e}", path=path) from None
    if labels.shape != (n_verts,) or not np.isin(labels, (0, 1)).all():
        raise DataError(f"expected {n_verts} labels of 0 or 1 (one per mesh.obj vertex), got shape "
                        f"{labels.shape}", path=path)
    return labels.astype(np.int64)


def _check_labels(path, v, top_mask, v_top, v_bottom):
    """Label-0 vertices must lie on top.obj (within 2 mm), not bottom.obj, in the median (the meshes overlap at
    the hinge, so single vertices may be near both)."""
    from scipy.spatial import cKDTree

    if not top_mask.any() or top_mask.all():
        raise DataError("parts.json puts every vertex in one part", path=path)
    d_top = cKDTree(v_top).query(v[top_mask])[0]
    d_bottom = cKDTree(v_bottom).query(v[top_mask])[0]
    if np.median(d_top) > np.median(d_bottom):
        raise DataError("the vertices labelled 0 lie on bottom.obj, not top.obj: ARCTIC's code articulates the "
                        "vertices labelled 0 (its docs say 1 for top); relabel (0 = top, 1 = bottom)", path=path)


def write_object(root, name: str, obj: ArticulatedObject, k: int = 48):
    """A procedural object in ARCTIC's template layout (millimetres): mesh.obj (both parts' tessellations),
    parts.json (0 for the top part's vertices, 1 for the bottom's, as ARCTIC's code reads them), top.obj and
    bottom.obj."""
    d = _template_dir(root, name)
    d.mkdir(parents=True, exist_ok=True)
    (vt, ft), (vb, fb) = (mesh_lib.tessellate_part(obj, p, k) for p in (TOP, BOTTOM))
    write_obj(d / "top.obj", vt * MM, ft)
    write_obj(d / "bottom.obj", vb * MM, fb)
    write_obj(d / "mesh.obj", np.concatenate([vt, vb]) * MM, np.concatenate([ft, fb + len(vt)]))
    (d / "parts.json").write_text(json.dumps([0] * len(vt) + [1] * len(vb)))


# ---- sequences ----------------------------------------------------------------------------------------------

@dataclass
class ArcticSequence:
    """One ARCTIC sequence in this project's units: states (T, 7) with the translation in metres; MANO
    parameters per hand (as stored); joints (T, 2, 21, 3) metres (hand 0 = left) or None, with where they came
    from or, when None, one line saying what is missing."""
    name: str
    object_name: str
    states_Tx7: np.ndarray
    mano: dict
    joints_Tx2x21x3: np.ndarray | None
    joints_source: str


def _seq_paths(root, seq: str) -> tuple[Path, str, str]:
    """``seq`` as 'sNN/{obj}_{grab|use}_NN' -> (raw_seqs folder, subject, sequence name)."""
    subject, _, name = seq.partition("/")
    if not re.fullmatch(r"s\d\d", subject) or not SEQ_RE.match(name):
        raise DataError(f"sequence {seq!r} is not 'sNN/<object>_<grab|use>_NN'", path=root)
    return Path(root) / "raw_seqs" / subject, subject, name


def write_sequence(root, seq: str, states_Tx7, mano: dict):
    """``raw_seqs/{seq}.object.npy`` ((T, 7), translation in mm) and ``.mano.npy`` (the dict ARCTIC stores;
    ``mano[hand]`` holds rot, pose, trans, shape and optionally fitting_err)."""
    folder, _, name = _seq_paths(root, seq)
    folder.mkdir(parents=True, exist_ok=True)
    s = np.array(states_Tx7, np.float64)
    s[:, 4:7] *= MM
    np.save(folder / f"{name}.object.npy", s.astype(np.float32))
    T = len(s)
    out = {}
    for hand in ("right", "left"):
        h = {k: np.asarray(mano[hand][k], np.float32) for k in MANO_FIELDS}
        h["fitting_err"] = np.asarray(mano[hand].get("fitting_err", np.zeros(T)), np.float32)
        out[hand] = h
    np.save(folder / f"{name}.mano.npy", out, allow_pickle=True)


def write_processed_joints(root, seq: str, joints_Tx2x21x3):
    """``processed_seqs/{seq}.npy`` with ``world_coord/joints.{right,left}``, as ARCTIC's processing writes it."""
    _, subject, name = _seq_paths(root, seq)
    folder = Path(root) / "processed_seqs" / subject
    folder.mkdir(parents=True, exist_ok=True)
    j = np.asarray(joints_Tx2x21x3, np.float32)
    np.save(folder / f"{name}.npy", {"world_coord": {"joints.left": j[:, sk.LEFT], "joints.right": j[:, sk.RIGHT]}},
            allow_pickle=True)


def read_sequence(root, seq: str, mano_dir=None) -> ArcticSequence:
    """One sequence of an ARCTIC release at ``root`` (its ``data`` folder: raw_seqs/, meta/, processed_seqs/).

    Joints: from MANO when ``mano_dir`` (the user's folder with MANO_RIGHT.pkl and MANO_LEFT.pkl) is given;
    otherwise from ``processed_seqs/{seq}.npy`` where present; otherwise None with one line on what is missing."""
    folder, subject, name = _seq_paths(root, seq)
    mano_path = folder / f"{name}.mano.npy"
    states = read_object_states(root, seq)
    mano = _check_mano(load_npy(mano_path), len(states), mano_path)
    if mano_dir is not None:
        joints = np.stack([mano_joints(load_mano_model(mano_dir, hand), **mano[hand]) for hand in HANDS], 1)
        source = f"MANO forward kinematics ({Path(mano_dir)})"
    else:
        processed = Path(root) / "processed_seqs" / subject / f"{name}.npy"
        if processed.exists():
            joints = _processed_joints(load_npy(processed), len(states), processed)
            source = f"ARCTIC's processed joints ({processed})"
        else:
            joints = None
            source = (f"no joints: pass a MANO model folder (MANO_RIGHT.pkl, MANO_LEFT.pkl) or run ARCTIC's "
                      f"processing for {processed}")
    return ArcticSequence(name=seq, object_name=SEQ_RE.match(name)["object"], states_Tx7=states, mano=mano,
                          joints_Tx2x21x3=joints, joints_source=source)


def read_object_states(root, seq: str) -> np.ndarray:
    """The object trajectory of a sequence alone, ``raw_seqs/{seq}.object.npy``: (T, 7) float64, [angle, axis-angle,
    translation in metres] (what an object-to-motion model reads; no hand file is needed)."""
    folder, _, name = _seq_paths(root, seq)
    obj_path = folder / f"{name}.object.npy"
    if not obj_path.exists():
        raise DataError(f"no object trajectory for sequence {seq!r} (raw_seqs/{seq}.object.npy)", path=obj_path)
    states = load_npy(obj_path)
    if not isinstance(states, np.ndarray) or states.ndim != 2 or states.shape[1] != 7 or \
            not np.issubdtype(states.dtype, np.number):
        raise DataError(f"expected a (T, 7) numeric array, got {getattr(states, 'shape', type(states).__name__)}",
                        path=obj_path)
    states = states.astype(np.float64)
    if not np.isfinite(states).all():
        raise DataError("the object trajectory holds non-finite values", path=obj_path)
    states[:, 4:7] /= MM
    return states


def _check_mano(data, T, path) -> dict:
    if not isinstance(data, dict) or not all(isinstance(data.get(h), dict) for h in HANDS):
        raise DataError("expected a dict with 'right' and 'left' hand dicts", path=path)
    want = {"rot": (T, 3), "pose": (T, 45), "trans": (T, 3), "shape": (10,)}
    out = {}
    for hand in HANDS:
        out[hand] = {}
        for k, shape in want.items():
            a = np.asarray(data[hand].get(k) if k in data[hand] else np.zeros(0), np.float64)
            if k == "shape" and a.shape == (T, 10):  # a per-frame copy: ARCTIC's docs say frames x 10
                a = a[0]
            if a.shape != shape:
                raise DataError(f"{hand} hand {k!r}: expected shape {shape}, got {a.shape}", path=path, field=k)
            out[hand][k] = a
    return out


def _processed_joints(data, T, path) -> np.ndarray:
    try:
        wc = data["world_coord"]
        j = np.stack([np.asarray(wc["joints.left"]), np.asarray(wc["joints.right"])], 1).astype(np.float64)
    except (KeyError, TypeError, ValueError) as e:
        raise DataError(f"expected world_coord/joints.left and joints.right: {e}", path=path) from None
    if j.shape != (T, 2, sk.NUM_JOINTS, 3):
        raise DataError(f"joints: expected shape {(T, 2, sk.NUM_JOINTS, 3)}, got {j.shape}", path=path)
    return j


# ---- MANO ---------------------------------------------------------------------------------------------------

def _plain(value, path, key):
    """A MANO field as a float64 array: chumpy's ``x``, a sparse matrix densified, or an array as is."""
    if isinstance(value, _ChumpyCh):
        if not isinstance(value.state, dict) or "x" not in value.state:
            raise DataError("a chumpy object without its array 'x' (only plain chumpy.ch.Ch is supported)",
                            path=path, field=key)
        value = value.state["x"]
    elif isinstance(value, _SparseMatrix):
        from scipy import sparse

        st = value.state
        cls = sparse.csc_matrix if value.fmt == "csc" else sparse.csr_matrix
        try:
            value = cls((st["data"], st["indices"], st["indptr"]), shape=tuple(st["_shape"])).toarray()
        except (KeyError, TypeError, ValueError) as e:
            raise DataError(f"unreadable sparse matrix: {e}", path=path, field=key) from None
    return np.asarray(value, np.float64)


def load_mano_model(mano_dir, hand: str) -> dict:
    """The arrays of ``MANO_{RIGHT,LEFT}.pkl`` that forward kinematics needs, as float64 numpy."""
    path = Path(mano_dir) / f"MANO_{hand.upper()}.pkl"
    try:
        with open(path, "rb") as fh:
            raw = _unpickle(io.BytesIO(fh.read()), path, _ManoUnpickler)
    except OSError as e:
        raise DataError(f"cannot read the MANO model: {e.strerror or e}", path=path) from None
    need = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "hands_mean")
    if not isinstance(raw, dict) or any(k not in raw for k in need):
        raise DataError(f"a MANO model holds {', '.join(need)}", path=path)
    m = {k: _plain(raw[k], path, k) for k in need}
    m["parents"] = m.pop("kintree_table")[0].astype(np.int64)
    m["parents"][0] = -1
    return m


def _rodrigues(rotvec_Nx3):
    theta = np.linalg.norm(rotvec_Nx3, axis=-1, keepdims=True)
    k = rotvec_Nx3 / np.maximum(theta, 1e-12)
    K = np.zeros(rotvec_Nx3.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    t = theta[..., None]
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * (K @ K)


def mano_joints(model: dict, rot, pose, trans, shape) -> np.ndarray:
    """(T, 21, 3) joints, metres: MANO's linear blend skinning as smplx.MANO(use_pca=False, flat_hand_mean=False)
    computes it (lbs: shape blend, regressor joints, pose blend, chain of rigid transforms), then ARCTIC's 21
    joints: the 16 transformed joints and the fingertip vertices MANO_TIPS, plus the translation."""
    rot, pose, trans = (np.asarray(x, np.float64) for x in (rot, pose, trans))
    T = len(rot)
    betas = np.broadcast_to(np.asarray(shape, np.float64), (T, model["shapedirs"].shape[-1]))
    v_shaped = model["v_template"] + np.einsum("vck,tk->tvc", model["shapedirs"], betas)
    J = np.einsum("jv,tvc->tjc", model["J_regressor"], v_shaped)                      # (T, 16, 3)
    full = np.concatenate([rot, pose + model["hands_mean"]], 1).reshape(T, -1, 3)    # flat_hand_mean=False
    R = _rodrigues(full)                                                                # (T, 16, 3, 3)
    pose_feature = (R[:, 1:] - np.eye(3)).reshape(T, -1)
    v_posed = v_shaped + np.einsum("vcp,tp->tvc", model["posedirs"], pose_feature)
    parents = model["parents"]
    G = np.zeros((T, len(parents), 4, 4))
    for j, p in enumerate(parents):
        local = np.zeros((T, 4, 4))
        local[:, :3, :3], local[:, 3, 3] = R[:, j], 1.0
        local[:, :3, 3] = J[:, j] - (J[:, p] if p >= 0 else 0.0)
        G[:, j] = local if p < 0 else G[:, p] @ local
    joints16 = G[:, :, :3, 3]
    # Skinning transforms remove the rest joint position: A_j = G_j [I, -J_j].
    A = G.copy()
    A[:, :, :3, 3] -= np.einsum("tjab,tjb->tja", G[:, :, :3, :3], J)
    Tv = np.einsum("vj,tjab->tvab", model["weights"], A)
    verts = np.einsum("tvab,tvb->tva", Tv[..., :3, :3], v_posed) + Tv[..., :3, 3]
    return np.concatenate([joints16, verts[:, list(MANO_TIPS)]], 1) + trans[:, None]
