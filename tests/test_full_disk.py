"""A full disk (issue 14.8): every writer fails with one clear line naming the path and the bytes it
needed, removes its temporary folder and exits non-zero. Before, memory-mapped writes to a full tmpfs
killed `data import-handx`, `data synth` and `text cache` with SIGBUS (exit 135, no message) and left
a hidden `.NAME.XXXX.tmp` folder behind.

A real 2 MB tmpfs is used where it can be mounted (root); elsewhere the same code paths are driven by
reporting 2 MB free (free_bytes) and by failing a write with ENOSPC.
"""

import errno
import os
import subprocess
import sys
import uuid

import numpy as np
import pytest

from handx_jax.cli import main as handx
from handx_jax.infra import atomic, diskspace, npy_writer
from handx_jax.interop.handx_npz import HandXClip, write_handx_npz

SMALL = 2 << 20


@pytest.fixture
def small_disk(tmp_path, monkeypatch):
    """(folder on a 2 MB file system, whether it is a real tmpfs)."""
    d = tmp_path / f"disk-{uuid.uuid4().hex[:6]}"
    d.mkdir()
    real = os.geteuid() == 0 and subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={SMALL}", "tmpfs", str(d)],
                                                capture_output=True).returncode == 0
    if not real:
        monkeypatch.setattr(diskspace, "free_bytes", lambda path: SMALL)
    yield d, real
    if real:
        subprocess.run(["umount", "-l", str(d)], check=False)


def _npz(path, n):
    rng = np.random.default_rng(0)
    write_handx_npz(path, [HandXClip(str(i), rng.normal(0, 0.05, (60, 2, 21, 3)), [f"l{i}"], [f"r{i}"], [f"i{i}"])
                           for i in range(n)])
    return path


def _enospc(*a, **k):
    raise OSError(errno.ENOSPC, "No space left on device")


def test_import_on_a_full_disk_is_a_clean_error(small_disk, tmp_path):
    disk, real = small_disk
    npz = _npz(tmp_path / "train_x.npz", 100)  # 3 MB of motion for a 2 MB disk
    cmd = ["data", "import-handx", str(npz), "--no-events", "--out", str(disk / "ds")]
    if real:  # a separate process: the old code died here by SIGBUS (exit 135)
        r = subprocess.run([sys.executable, "-m", "handx_jax", *cmd], capture_output=True, text=True,
                           env={**os.environ, "JAX_PLATFORMS": "cpu"})
        rc, err = r.returncode, r.stderr
    else:
        import contextlib
        import io

        buf = io.StringIO()
        with contextlib.redirect_stderr(buf):
            rc = handx(cmd)
        err = buf.getvalue()
    assert rc == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"no space left on device writing {disk / 'ds'}; it needs 2.9 MB, 2.0 MB free" in err
    assert os.listdir(disk) == []  # no hidden temporary folder left


def test_write_that_hits_enospc_removes_its_folder(small_disk, tmp_path, monkeypatch, capsys):
    """Past the up-front check (space taken meanwhile), the failing write itself is the clean error."""
    disk, real = small_disk
    for where in ("handx_jax.dataset.format.check_free_space", "handx_jax.infra.npy_writer.check_free_space"):
        monkeypatch.setattr(where, lambda *a, **k: None)
    if not real:
        def append(self, rows):
            with diskspace.disk_full_as_error(self.path, self.nbytes):
                _enospc()
        monkeypatch.setattr(npy_writer.NpyWriter, "append", append)
    npz = _npz(tmp_path / "train_x.npz", 100)
    assert handx(["data", "import-handx", str(npz), "--no-events", "--out", str(disk / "ds")]) == 2
    err = capsys.readouterr().err
    assert f"no space left on device writing {disk / 'ds' / 'motion.npy'}; it needs 2.9 MB" in err
    assert os.listdir(disk) == []


def test_every_command_reports_enospc_in_one_line(monkeypatch, capsys, tmp_path):
    """A bare OSError 28 from anywhere (a library's own write) becomes one line, exit 2."""
    from handx_jax.commands import data as data_cli

    def full(a):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "x.bin"))

    monkeypatch.setattr(data_cli, "_export", full)
    assert handx(["data", "export-handx", "--data", str(tmp_path), "--out", str(tmp_path / "o.npz")]) == 2
    assert capsys.readouterr().err == f"handx: error: no space left on device writing {tmp_path / 'x.bin'} " \
                                      "(free some space or write elsewhere)\n"

    def wrapped(a):  # e.g. a checkpoint library that wraps the OSError in its own exception
        try:
            _enospc()
        except OSError as e:
            raise RuntimeError("write failed") from e

    monkeypatch.setattr(data_cli, "_export", wrapped)
    assert handx(["data", "export-handx", "--data", str(tmp_path), "--out", str(tmp_path / "o.npz")]) == 2
    assert capsys.readouterr().err.startswith("handx: error: no space left on device")


def test_atomic_write_and_npy_writer_name_the_file(tmp_path, monkeypatch):
    monkeypatch.setattr(diskspace, "free_bytes", lambda path: 1000)
    with pytest.raises(diskspace.DiskFullError, match=r"writing .*big\.npy; it needs 7\.8 KB, 1000 B free"):
        npy_writer.NpyWriter(tmp_path / "big.npy", np.float32, (2000,))
    real_fdopen = os.fdopen

    class Full:
        def __init__(self, f):
            self.f = f

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, data):
            _enospc()

    monkeypatch.setattr(atomic.os, "fdopen", lambda fd, mode: Full(real_fdopen(fd, mode)))
    with pytest.raises(diskspace.DiskFullError, match=r"writing .*a\.json; it needs 3 B"):
        atomic.atomic_write_bytes(tmp_path / "a.json", b"abc")
    assert sorted(os.listdir(tmp_path)) == []
    with npy_writer.NpyWriter(tmp_path / "ok.npy", np.int16, (3, 2)) as w:  # and it writes a valid .npy
        w.append(np.arange(4).reshape(2, 2))
        w.append(np.array([[7, 8]]))
    np.testing.assert_array_equal(np.load(tmp_path / "ok.npy"), [[0, 1], [2, 3], [7, 8]])
