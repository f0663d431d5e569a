import json
import os

import numpy as np
import pytest

from handx_jax.infra import atomic, errors, readers


def test_atomic_write_leaves_no_temp_and_replaces(tmp_path):
    p = tmp_path / "a" / "f.json"
    atomic.atomic_write_json(p, {"x": 1})
    atomic.atomic_write_json(p, {"x": 2})
    assert json.loads(p.read_text()) == {"x": 2}
    assert os.listdir(p.parent) == ["f.json"]


def test_atomic_dir_refuses_existing_and_keeps_old_on_failure(tmp_path):
    d = tmp_path / "ds"
    with atomic.atomic_dir(d) as t:
        (t / "a.txt").write_text("old")
    with pytest.raises(FileExistsError):
        with atomic.atomic_dir(d):
            pass
    with pytest.raises(RuntimeError):
        with atomic.atomic_dir(d, overwrite=True) as t:
            (t / "a.txt").write_text("new")
            raise RuntimeError("killed mid-build")
    assert (d / "a.txt").read_text() == "old"  # nothing already written is lost
    assert sorted(os.listdir(tmp_path)) == ["ds"]  # and no temporary left behind
    with atomic.atomic_dir(d, overwrite=True) as t:
        (t / "a.txt").write_text("new")
    assert (d / "a.txt").read_text() == "new"


def test_jsonl_torn_last_line(tmp_path):
    p = tmp_path / "m.jsonl"
    atomic.append_jsonl(p, {"step": 1})
    with open(p, "a") as f:
        f.write('{"step": 2, "lo')  # killed mid-write
    assert readers.read_jsonl(p, strict=False) == [{"step": 1}]
    with pytest.raises(errors.DataError, match="m.jsonl"):
        readers.read_jsonl(p)


def test_npy_roundtrip(tmp_path):
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    atomic.atomic_save_npy(tmp_path / "a.npy", a)
    np.testing.assert_array_equal(np.load(tmp_path / "a.npy"), a)


def test_data_error_names_file_clip_field():
    e = errors.DataError("bad", path="x.npz", clip="7", field="motion")
    assert "x.npz" in str(e) and "clip 7" in str(e) and "'motion'" in str(e)


def test_atomic_files_get_normal_permissions(tmp_path):
    p = atomic.atomic_write_text(tmp_path / "f.txt", "x")
    ref = tmp_path / "ref.txt"
    ref.write_text("x")
    assert (p.stat().st_mode & 0o777) == (ref.stat().st_mode & 0o777)


def test_atomic_dir_gets_normal_permissions(tmp_path):
    with atomic.atomic_dir(tmp_path / "d") as t:
        (t / "x").write_text("1")
    ref = tmp_path / "ref"
    ref.mkdir()
    assert ((tmp_path / "d").stat().st_mode & 0o777) == (ref.stat().st_mode & 0o777)


def test_read_format_meta_names_the_file_and_the_problem(tmp_path):
    from handx_jax.infra.errors import DataError
    from handx_jax.infra.readers import read_format_meta

    p = tmp_path / "meta.json"
    with pytest.raises(DataError, match="build one first") as e:
        read_format_meta(p, "fmt-x", 2, missing="build one first")
    assert str(tmp_path) in str(e.value)
    p.write_text("{not json")
    with pytest.raises(DataError, match="corrupt JSON"):
        read_format_meta(p, "fmt-x", 2)
    p.write_text('{"format": "other", "format_version": 2}')
    with pytest.raises(DataError, match="not a fmt-x .format='other'"):
        read_format_meta(p, "fmt-x", 2)
    p.write_text('{"format": "fmt-x", "format_version": 1}')
    with pytest.raises(DataError, match="format_version 1 is not supported .this code reads 2.; redo"):
        read_format_meta(p, "fmt-x", 2, upgrade="; redo")
    p.write_text('{"format": "fmt-x", "format_version": 2, "k": 3}')
    assert read_format_meta(p, "fmt-x", 2) == {"format": "fmt-x", "format_version": 2, "k": 3}


def test_tree_checksum_catches_a_changed_file(tmp_path):
    """For checkpoint folders written by a library (Orbax step directories): one SHA256SUMS listing."""
    from handx_jax.infra.checksums import verify_tree_checksum, write_tree_checksum
    from handx_jax.infra.errors import DataError

    d = tmp_path / "ckpt" / "10"
    (d / "state").mkdir(parents=True)
    (d / "state" / "a.bin").write_bytes(bytes(range(200)))
    (d / "meta.json").write_text("{}")
    assert verify_tree_checksum(d) is False
    write_tree_checksum(d)
    assert (d / "SHA256SUMS").read_text().splitlines()[1].endswith("  state/a.bin")
    assert verify_tree_checksum(d, required=True)
    data = bytearray((d / "state" / "a.bin").read_bytes())
    data[10:74] = bytes(b ^ 0xFF for b in data[10:74])  # 64 flipped bytes
    (d / "state" / "a.bin").write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"file .*state/a\.bin: checksum mismatch"):
        verify_tree_checksum(d)
    (d / "state" / "a.bin").unlink()
    with pytest.raises(DataError, match="listed in SHA256SUMS but missing"):
        verify_tree_checksum(d)


def test_run_lock_taken_when_a_torn_lock_is_released_during_the_wait(tmp_path):
    """A lock file that is still empty (its holder between open and write) and then released while the
    next process waits: the waiter takes the lock. It used to stat the vanished file and die with
    FileNotFoundError (a sweep's parallel runs sharing one step did, in scripts/gpu_lease_ar.sh's dry run)."""
    import threading

    from handx_jax.infra.runlock import LOCK_NAME, RunLock, read_holder

    lock_file = tmp_path / LOCK_NAME
    lock_file.write_text("")  # torn: opened, not yet written
    threading.Timer(0.05, lock_file.unlink).start()  # released within the waiter's 0.2 s pause
    with RunLock(tmp_path):
        assert read_holder(tmp_path)["pid"] == os.getpid()
    assert not lock_file.exists()
