"""One writer per run folder: an O_EXCL lock file with the holder's pid, host and start time.

    with RunLock(run_dir):          # raises RunLocked naming the holder if another live process has it
        train(...)

Two trainers on one run folder interleave ``metrics.jsonl`` and overwrite each other's checkpoints
(issue 14.8: a sweep launcher killed with -9 left its child training, and the relaunch started a
second one beside it). The lock is a file ``RUN/.lock`` created with ``O_CREAT | O_EXCL``, which is
atomic on local file systems and on NFS v3+, holding ``{"pid", "host", "started", "cmd"}``.

A lock is *stale* when its holder is on this host and that pid no longer exists (or was reused by a
process that started after the lock was taken); a stale lock is removed and taken over, with a line
on stderr. A lock held from another host cannot be checked from here, so it is respected unless it
is older than ``stale_after`` seconds (None: never); ``handx`` prints the holder so the user can
decide. Re-entrant within one process (a launcher that holds the lock may run the stage in-process).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

LOCK_NAME = ".lock"


class RunLocked(RuntimeError):
    """Another live process holds the run folder's lock."""

    def __init__(self, run_dir: Path, holder: dict, what: str | None = None):
        self.run_dir, self.holder = run_dir, holder
        since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(holder.get("started", 0)))
        super().__init__(f"{what or run_dir} is in use by pid {holder.get('pid')} on {holder.get('host')} "
                         f"(since {since}: {holder.get('cmd', '?')}); wait for it, or end that process "
                         f"(a lock from a dead process is recovered automatically)")


def _proc_start_time(pid: int) -> float | None:
    """Start time of ``pid`` in seconds since the epoch (Linux /proc), None if unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        ticks = int(stat.rsplit(")", 1)[1].split()[19])
        boot = next(float(ln.split()[1]) for ln in Path("/proc/stat").read_text().splitlines()
                    if ln.startswith("btime"))
        return boot + ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, StopIteration):
        return None


def pid_alive(pid: int, started: float | None = None) -> bool:
    """True if ``pid`` runs here (and, if ``started`` is given, did not start after it: no pid reuse)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by someone else
    if started is not None:
        st = _proc_start_time(pid)
        if st is not None and st > started + 2.0:  # the pid was reused by a younger process
            return False
    try:  # a zombie has exited; only its parent has not reaped it yet
        if Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
            return False
    except (OSError, IndexError):
        pass
    return True


def read_holder(run_dir: str | os.PathLike, lock_file: str | os.PathLike | None = None) -> dict | None:
    """The lock's content, or None if the folder is not locked (a torn file reads as {})."""
    p = Path(lock_file) if lock_file is not None else Path(run_dir) / LOCK_NAME
    try:
        return json.loads(p.read_text() or "{}")
    except FileNotFoundError:
        return None
    except (json.JSONDecodeError, OSError):
        return {}


def _slurm_job_active(job: str) -> bool | None:
    """Whether SLURM still lists ``job`` (None when squeue is unavailable)."""
    if not shutil.which("squeue"):
        return None
    r = subprocess.run(["squeue", "-h", "-o", "%T", "-j", str(job)], capture_output=True, text=True)
    if r.returncode != 0 and "Invalid job id" not in r.stderr:
        return None
    return bool(r.stdout.strip())


def holder_alive(holder: dict, stale_after: float | None = None) -> bool:
    if holder.get("host") == socket.gethostname():
        pid = holder.get("pid")
        return isinstance(pid, int) and pid_alive(pid, holder.get("started"))
    if holder.get("slurm_job"):  # a job on another node: ask SLURM whether it still runs
        active = _slurm_job_active(holder["slurm_job"])
        if active is not None:
            return active
    if stale_after is not None and time.time() - float(holder.get("started", 0)) > stale_after:
        return False
    return bool(holder)


_LOCAL = threading.local()  # .held: lock path -> depth, for re-entry within one thread


def _held() -> dict[str, int]:
    if not hasattr(_LOCAL, "held"):
        _LOCAL.held = {}
    return _LOCAL.held


class RunLock:
    """Context manager (or ``acquire()``/``release()``) for exclusive use of a run folder."""

    def __init__(self, run_dir: str | os.PathLike, *, stale_after: float | None = None,
                 lock_file: str | os.PathLike | None = None, what: str | None = None):
        self.run_dir = Path(run_dir)
        self.path = Path(lock_file) if lock_file is not None else self.run_dir / LOCK_NAME
        self.what = what  # how a refusal names what is locked (default: the folder)
        self.stale_after = stale_after
        self._owned = False
        self._made = False
        self.inherited = False

    @classmethod
    def for_output(cls, out: str | os.PathLike) -> "RunLock":
        """The lock of an output that does not exist yet (a folder written by ``infra.atomic.atomic_dir``, a file):
        ``.NAME.lock`` beside it, so two writers of one ``--out`` cannot both write it (issue 43)."""
        out = Path(out)
        return cls(out.parent, lock_file=out.parent / f".{out.name}.lock", what=str(out))

    def _holder(self) -> dict | None:
        return read_holder(self.run_dir, self.path)

    def acquire(self) -> "RunLock":
        """Take the lock; raise :class:`RunLocked` naming the holder if a live process has it.

        Re-entrant in one thread; a child of the holder (the launcher's ``handx train``) inherits it.
        """
        key = str(self.path.absolute())
        held = _held()
        if key in held:
            held[key] += 1
            self._owned = True
            return self
        self._made = not self.run_dir.exists()  # ours to remove again if nothing was written into it
        self.run_dir.mkdir(parents=True, exist_ok=True)
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time(),
              "cmd": " ".join(sys.argv)[:300], "slurm_job": _slurm_job_id()}
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is None:
                    continue  # released between our open and read: try again
                if holder == {}:
                    # Written by a holder that died between open and write, or being written now.
                    time.sleep(0.2)
                    holder = self._holder()
                    if holder is None:
                        continue  # released meanwhile: try again
                    if holder == {}:
                        try:
                            made_at = self.path.stat().st_mtime
                        except FileNotFoundError:
                            continue  # released between the read and the stat (a sweep's parallel runs did)
                        if time.time() - made_at < 5:
                            raise RunLocked(self.run_dir, {"pid": "?", "host": "?", "started": made_at}, self.what)
                if (holder and holder.get("pid") == os.getppid() and holder.get("host") == socket.gethostname()
                        and pid_alive(os.getppid())):
                    self.inherited = True  # our parent holds it and started us to work in the folder
                    return self
                if holder and holder_alive(holder, self.stale_after):
                    raise RunLocked(self.run_dir, holder, self.what)
                print(f"handx: recovering a stale lock on {self.what or self.run_dir} (pid {holder.get('pid')} on "
                      f"{holder.get('host')} is gone)", file=sys.stderr)
                try:
                    self.path.unlink()
                except FileNotFoundError:
                    pass
                continue
            with os.fdopen(fd, "w") as f:
                json.dump(me, f)
                f.flush()
                os.fsync(f.fileno())
            held[key] = 1
            self._owned = True
            return self
        raise RunLocked(self.run_dir, self._holder() or {}, self.what)

    def release(self) -> None:
        if not self._owned:
            return
        self._owned = False
        key = str(self.path.absolute())
        held = _held()
        held[key] -= 1
        if held[key] == 0:
            del held[key]
            holder = self._holder()
            if holder and holder.get("pid") == os.getpid() and holder.get("host") == socket.gethostname():
                self.path.unlink(missing_ok=True)

    def __enter__(self) -> "RunLock":
        return self.acquire()

    def __exit__(self, exc_type, *exc) -> None:
        made = self._made and self._owned and not self.inherited
        self.release()
        if exc_type is not None and made:  # a run refused before it wrote anything leaves no folder (issue 31)
            with contextlib.suppress(OSError):
                self.run_dir.rmdir()  # only if empty


def _slurm_job_id() -> str | None:
    job = os.environ.get("SLURM_JOB_ID")
    if job and os.environ.get("SLURM_ARRAY_TASK_ID"):
        return f"{os.environ.get('SLURM_ARRAY_JOB_ID', job)}_{os.environ['SLURM_ARRAY_TASK_ID']}"
    return job


def is_locked(run_dir: str | os.PathLike) -> dict | None:
    """The live holder of ``run_dir``'s lock, or None (no lock, or a stale one)."""
    h = read_holder(run_dir)
    return h if h and holder_alive(h) else None


def pdeathsig_preexec(sig: int = 15, parent_pid: int | None = None):
    """A ``preexec_fn`` that asks Linux to send ``sig`` to the child when its parent dies.

    A launcher killed with -9 cannot clean up; with this, its training child gets SIGTERM at once
    instead of running on beside the relaunch (issue 14.8). libc is loaded here, in the parent, so
    the forked child only calls prctl (no imports or loader locks between fork and exec). Returns
    None where prctl is unavailable (non-Linux).
    """
    try:
        import ctypes

        prctl = ctypes.CDLL("libc.so.6", use_errno=True).prctl
    except OSError:  # pragma: no cover - non-Linux
        return None
    parent = os.getpid() if parent_pid is None else parent_pid
    PR_SET_PDEATHSIG = 1

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, sig, 0, 0, 0)
        if os.getppid() != parent:  # the parent died before prctl took effect
            os.kill(os.getpid(), sig)

    return preexec
