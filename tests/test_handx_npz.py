"""Tests for handx_jax.interop.handx_npz: official .npz format round trips and the restricted unpickler."""

from __future__ import annotations

import builtins
import io
import os
import pickle
import zipfile

import numpy as np
import pytest
from numpy.lib import format as npy_format

from handx_jax.interop.handx_npz import (
    HandXClip,
    read_handx_mano_npz,
    read_handx_npz,
    read_npz_dicts,
    write_handx_npz,
)
from handx_jax.infra.errors import DataError


def _clips(n: int = 12, seed: int = 0) -> list[HandXClip]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        k = 1 + i % 5
        out.append(HandXClip(
            key=str(i),
            motion=rng.normal(scale=0.1, size=(60, 2, 21, 3)).astype(np.float32),
            left=[f"left hand {i}.{v} – curls its fingers ✋" for v in range(k)],
            right=[f"right hand {i}.{v}" for v in range(k)],
            interaction=[f"hands {i}.{v} \"touch\"\nnewline" for v in range(k)],
        ))
    return out


def _entry(motion=None, n=2, **over):
    d = {
        "motion": np.zeros((60, 2, 21, 3), np.float32) if motion is None else motion,
        "left_annotation": [f"l{i}" for i in range(n)],
        "right_annotation": [f"r{i}" for i in range(n)],
        "interaction_annotation": [f"i{i}" for i in range(n)],
    }
    d.update(over)
    return d


def _savez(path, entries: dict) -> None:
    """The official writer: np.savez of a dict (each value becomes a 0-d object array)."""
    np.savez(path, **{k: np.array(v, dtype=object) if isinstance(v, dict) else v for k, v in entries.items()})


def _npy_object_member(payload: bytes) -> bytes:
    """A .npy file declaring a 0-d object array followed by an arbitrary pickle payload."""
    f = io.BytesIO()
    npy_format.write_array_header_1_0(f, {"descr": "|O", "fortran_order": False, "shape": ()})
    return f.getvalue() + payload


def _zip(path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)


# ----------------------------------------------------------------------------------------------
# round trips

def test_write_then_np_load_reads_the_same_dicts(tmp_path):
    clips = _clips()
    path = tmp_path / "train_can_pos_all_wotextfeat.npz"
    write_handx_npz(path, clips)
    with np.load(path, allow_pickle=True) as d:  # our own file: safe to load with pickle here
        assert sorted(d.files, key=int) == [c.key for c in clips]
        for c in clips:
            e = d[c.key].item()
            assert set(e) == {"motion", "left_annotation", "right_annotation", "interaction_annotation"}
            assert e["motion"].dtype == np.float32 and e["motion"].shape == (60, 2, 21, 3)
            np.testing.assert_array_equal(e["motion"], c.motion)
            assert e["left_annotation"] == c.left and type(e["left_annotation"]) is list
            assert e["right_annotation"] == c.right
            assert e["interaction_annotation"] == c.interaction


def test_write_then_read_reproduces_exactly(tmp_path):
    clips = _clips()
    path = tmp_path / "a.npz"
    write_handx_npz(path, clips)
    back = read_handx_npz(path)
    assert [c.key for c in back] == [str(i) for i in range(12)]  # numeric key order ("10" after "9")
    for a, b in zip(clips, back):
        assert b.motion.dtype == np.float32
        np.testing.assert_array_equal(a.motion, b.motion)
        assert (a.left, a.right, a.interaction) == (b.left, b.right, b.interaction)
        assert all(type(s) is str for s in b.left + b.right + b.interaction)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]  # atomic: no leftovers


def test_reads_archives_written_by_np_savez_and_numpy1_pickles(tmp_path):
    # float64 motion as numpy itself would store it; the reader returns float32
    m = np.random.default_rng(1).normal(size=(60, 2, 21, 3))
    path = tmp_path / "official.npz"
    _savez(path, {"0": _entry(m), "1": _entry(n=5)})
    back = read_handx_npz(path)
    np.testing.assert_array_equal(back[0].motion, m.astype(np.float32))
    assert back[1].left == [f"l{i}" for i in range(5)]
    # a NumPy 1.x archive pickles numpy.core.multiarray._reconstruct with protocol 3
    payload = pickle.dumps(np.array(_entry(m), dtype=object), protocol=3)
    assert b"numpy._core.multiarray" in payload
    payload = payload.replace(b"numpy._core.multiarray", b"numpy.core.multiarray")
    legacy = tmp_path / "legacy.npz"
    _zip(legacy, {"0.npy": _npy_object_member(payload)})
    np.testing.assert_array_equal(read_handx_npz(legacy)[0].motion, m.astype(np.float32))
    # protocol-5 pickles (ndarray via _frombuffer) are accepted too
    p5 = tmp_path / "p5.npz"
    _zip(p5, {"0.npy": _npy_object_member(pickle.dumps(np.array(_entry(m), dtype=object), protocol=5))})
    np.testing.assert_array_equal(read_handx_npz(p5)[0].motion, m.astype(np.float32))


def test_mano_reader(tmp_path):
    rng = np.random.default_rng(2)
    e = {f"{h}_{k}": rng.normal(size=(60, w)).astype(np.float32)
         for h in ("left", "right") for k, w in (("pose", 48), ("shape", 10), ("trans", 3))}
    path = tmp_path / "train_mano.npz"
    _savez(path, {"0": e, "1": e})
    back = read_handx_mano_npz(path)
    assert [c.key for c in back] == ["0", "1"]
    np.testing.assert_array_equal(back[1].right_pose, e["right_pose"])
    np.testing.assert_array_equal(back[0].left_trans, e["left_trans"])
    bad = dict(e, left_shape=np.zeros((60, 9), np.float32))
    _savez(path, {"0": e, "4": bad})
    with pytest.raises(DataError, match=r"train_mano\.npz.*clip 4.*left_shape.*shape"):
        read_handx_mano_npz(path)


# ----------------------------------------------------------------------------------------------
# the restricted unpickler

class _SystemCall:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


class _EvalCall:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (builtins.eval, (f"open({str(self.marker)!r}, 'w').close()",))


@pytest.mark.parametrize("make", [_SystemCall, _EvalCall])
@pytest.mark.parametrize("nested", [False, True])
def test_malicious_payload_is_rejected_without_executing(tmp_path, make, nested):
    marker = tmp_path / "pwned"
    evil = make(marker)
    obj = np.array(_entry(left_annotation=["ok", evil]), dtype=object) if nested else evil
    payload = pickle.dumps(obj, protocol=4)  # pickling does not run the call; unpickling would
    path = tmp_path / "evil.npz"
    good = io.BytesIO()
    np.save(good, np.array(_entry(), dtype=object), allow_pickle=True)
    _zip(path, {"0.npy": good.getvalue(), "7.npy": _npy_object_member(payload)})
    with pytest.raises(DataError) as ei:
        read_handx_npz(path)
    msg = str(ei.value)
    assert "evil.npz" in msg and "clip 7" in msg and "refusing to unpickle" in msg
    assert ("system" in msg) if make is _SystemCall else ("builtins.eval" in msg)
    with pytest.raises(DataError):
        read_npz_dicts(path)
    assert not marker.exists()


# ----------------------------------------------------------------------------------------------
# validation errors

def test_truncated_and_corrupt_archives(tmp_path):
    path = tmp_path / "trunc.npz"
    write_handx_npz(path, _clips(3))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match=r"trunc\.npz.*truncated or corrupt"):
        read_handx_npz(path)
    # intact directory, damaged member data → the key is named (CRC mismatch)
    path2 = tmp_path / "corrupt.npz"
    write_handx_npz(path2, _clips(3))
    with zipfile.ZipFile(path2) as zf:
        info = zf.getinfo("1.npy")
        start = info.header_offset + 30 + len(info.filename) + len(info.extra) + 200
    raw = bytearray(path2.read_bytes())
    raw[start:start + 64] = bytes(64)
    path2.write_bytes(bytes(raw))
    with pytest.raises(DataError, match=r"corrupt\.npz.*clip 1.*truncated or corrupt"):
        read_handx_npz(path2)
    # a member whose pickle stops half way
    path3 = tmp_path / "half.npz"
    payload = pickle.dumps(np.array(_entry(), dtype=object), protocol=4)
    _zip(path3, {"2.npy": _npy_object_member(payload[: len(payload) // 2])})
    with pytest.raises(DataError, match=r"half\.npz.*clip 2.*corrupt pickled payload"):
        read_handx_npz(path3)


@pytest.mark.parametrize("entry, pattern", [
    (_entry(np.zeros((60, 2, 20, 3), np.float32)), r"clip 3, field 'motion': wrong shape \(60, 2, 20, 3\)"),
    (_entry(np.zeros((59, 2, 21, 3), np.float32)), r"clip 3, field 'motion': wrong shape"),
    (_entry(right_annotation=["a", "b", "c"]), r"clip 3, field 'right_annotation': annotation lists have unequal"),
    (_entry(interaction_annotation=["a"]), r"clip 3, field 'interaction_annotation': .*unequal"),
    (_entry(n=0), r"clip 3, field 'left_annotation': empty annotation list"),
    (_entry(left_annotation=["a", 5]), r"clip 3, field 'left_annotation': entry 1 is int"),
    (_entry(left_annotation="just a string"), r"clip 3, field 'left_annotation': expected a list"),
    ({k: v for k, v in _entry().items() if k != "motion"}, r"clip 3, field 'motion': missing field"),
    ({k: v for k, v in _entry().items() if k != "interaction_annotation"},
     r"clip 3, field 'interaction_annotation': missing field"),
    (_entry(np.full((60, 2, 21, 3), "x")), r"clip 3, field 'motion': expected a real numeric array"),
])
def test_invalid_entries_raise_data_error(tmp_path, entry, pattern):
    path = tmp_path / "bad_clips.npz"
    _savez(path, {"0": _entry(), "3": entry})
    with pytest.raises(DataError, match=r"bad_clips\.npz, " + pattern):
        read_handx_npz(path)


def test_non_dict_entries(tmp_path):
    path = tmp_path / "nondict.npz"
    np.savez(path, **{"0": np.array(_entry(), dtype=object), "5": np.zeros((60, 2, 21, 3))})
    with pytest.raises(DataError, match=r"nondict\.npz, clip 5: entry is not a dict.*float64"):
        read_handx_npz(path)
    np.savez(path, **{"5": np.array(["a", "b"], dtype=object)})
    with pytest.raises(DataError, match=r"clip 5: entry is not a dict"):
        read_handx_npz(path)
    _zip(path, {"0.npy": b"garbage", "notes.txt": b"x"})
    with pytest.raises(DataError, match=r"nondict\.npz"):
        read_handx_npz(path)


def test_nonfinite_motion_is_reported(tmp_path):
    m = np.zeros((60, 2, 21, 3), np.float32)
    m[4, 1, 2, 0] = np.nan
    m[9, 0, 0, 1] = np.inf
    path = tmp_path / "nan.npz"
    _savez(path, {"0": _entry(), "1": _entry(m)})
    with pytest.raises(DataError, match=r"nan\.npz, clip 1, field 'motion': 2 non-finite.*\[4, 9\]"):
        read_handx_npz(path)
    back = read_handx_npz(path, allow_nonfinite=True)  # the importer decides
    assert np.isnan(back[1].motion[4, 1, 2, 0])


def test_writer_validates_and_is_atomic(tmp_path):
    path = tmp_path / "out.npz"
    write_handx_npz(path, _clips(2))
    before = path.read_bytes()
    bad = HandXClip(key="1", motion=np.zeros((60, 2, 21, 2)), left=["a"], right=["b"], interaction=["c"])
    with pytest.raises(DataError, match=r"out\.npz, clip 1, field 'motion': wrong shape"):
        write_handx_npz(path, [_clips(1)[0], bad])
    dup = _clips(2)
    with pytest.raises(DataError, match="duplicate key"):
        write_handx_npz(path, [dup[0], dup[0]])
    uneq = HandXClip(key="2", motion=np.zeros((60, 2, 21, 3)), left=["a", "b"], right=["b"], interaction=["c"])
    with pytest.raises(DataError, match=r"clip 2.*unequal"):
        write_handx_npz(path, [uneq])
    assert path.read_bytes() == before  # failed writes leave the old file untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.npz"]
