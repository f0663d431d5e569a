"""The launcher on a real one-node SLURM with accounting (issue 13.5), started by tests/slurm_cluster.sh.

Needs root and apt-get (CI: a clean Debian machine); the cluster script installs slurm-wlm, munge,
slurmdbd and mariadb-server when they are missing. If the cluster cannot start, the test fails with
the script's reason; it is skipped (loudly) where apt-get itself does not exist, when the user opts
out with HANDX_SKIP_SLURM=1, or when it is not run as root outside CI (`make test` on a workstation);
with CI set it is mandatory.

Runs are the light fake stage (tests/sweep_fake_stage.py), so what is timed is the launcher and SLURM:
about 30 s install (first time), 5 s start, ~25 s per case, ~10 s stop.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import socket
import tempfile

import pytest

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
FAKE = str(HERE / "sweep_fake_stage.py")


@pytest.fixture(scope="module")
def slurm(tmp_path_factory):
    if os.environ.get("HANDX_SKIP_SLURM"):
        pytest.skip(f"!!! SLURM TEST NOT RUN: HANDX_SKIP_SLURM={os.environ['HANDX_SKIP_SLURM']} !!!")
    if os.geteuid() != 0:
        if os.environ.get("CI"):  # mandatory in CI, which runs as root
            pytest.fail("the SLURM test needs root (to install and run slurmd/munged); CI runs it as root")
        pytest.skip("!!! SLURM TEST NOT RUN: it needs root to install and run slurmd/munged "
                    f"(running as uid {os.geteuid()}, CI unset); CI runs it as root !!!")
    if not shutil.which("apt-get") and not shutil.which("slurmctld"):
        pytest.skip("!!! SLURM TEST NOT RUN: apt-get is unavailable on this machine and SLURM is not installed !!!")
    # Not under pytest's tmp folder: that is mode 700, and munge/mysql/slurm run as their own users.
    d = Path(tempfile.mkdtemp(prefix="handx-slurm-"))
    d.chmod(0o755)
    ports = {}
    for name in ("DB", "DBD", "CTLD", "SLURMD"):  # free ports, so a system SLURM/MariaDB is left alone
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            ports[f"HANDX_SLURM_{name}_PORT"] = str(s.getsockname()[1])
    t0 = time.time()
    r = subprocess.run(["bash", str(HERE / "slurm_cluster.sh"), "start", str(d)], capture_output=True, text=True,
                       timeout=600, env={**os.environ, **ports})
    if r.returncode != 0:
        subprocess.run(["bash", str(HERE / "slurm_cluster.sh"), "stop", str(d)], capture_output=True, timeout=120)
        shutil.rmtree(d, ignore_errors=True)
        pytest.fail(f"SLURM did not start (tests/slurm_cluster.sh, {time.time() - t0:.0f} s):\n{r.stderr[-3000:]}")
    conf = str(d / "etc/slurm.conf")
    print(f"SLURM up in {time.time() - t0:.1f} s")
    old = os.environ.get("SLURM_CONF")
    os.environ["SLURM_CONF"] = conf
    yield conf
    if old is None:
        os.environ.pop("SLURM_CONF", None)
    else:
        os.environ["SLURM_CONF"] = old
    subprocess.run(["bash", str(HERE / "slurm_cluster.sh"), "stop", str(d)], capture_output=True, timeout=120)
    shutil.rmtree(d, ignore_errors=True)


def _sweep_file(path: Path, seconds: dict) -> Path:
    """A 3-run sweep of the fake stage; ``seconds`` per run name. RESOURCES give the time limit."""
    path.write_text(
        "import sys\nfrom sweeps.launcher import RunSpec\n"
        f"F = {FAKE!r}\nSECONDS = {seconds!r}\n"
        "RESOURCES = {'tiny': {'timeout_min': 10, 'cpus_per_task': 1, 'mem_gb': 1}}\n"
        "def runs(preset='tiny'):\n"
        "    return [RunSpec(n, 'diffusion',"
        " command=(sys.executable, F, '--out', '{run}', '--seconds', str(s), '--size', str(i + 1)),"
        " axes={'layers': i + 1}) for i, (n, s) in enumerate(SECONDS.items())]\n")
    return path


def _launch(sweep: Path, out: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "handx_jax", "sweep", "run", str(sweep), "--preset", "tiny", "--executor", "slurm",
           "--data", str(out.parent), "--out", str(out), *extra]
    env = {**os.environ, "PYTHONPATH": str(REPO), "JAX_PLATFORMS": "cpu"}
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _wait_file(path: Path, limit: float) -> None:
    end = time.time() + limit
    while not path.exists():
        assert time.time() < end, f"{path} did not appear within {limit} s"
        time.sleep(0.1)


def _invocations(run: Path) -> list[dict]:
    p = run / "invocations.log"
    return [json.loads(x) for x in p.read_text().splitlines()] if p.exists() else []


def _rows(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]


def _squeue() -> str:
    return subprocess.run(["squeue", "-h", "-r", "-o", "%i %T"], capture_output=True, text=True).stdout


def test_scancel_midway_then_relaunch(slurm, tmp_path):
    """3 runs as one job array; scancel of a running job is recorded as a failure while the launcher
    waits for the others; the relaunch redoes only the cancelled run; every row appears once."""
    t0 = time.time()
    sweep = _sweep_file(tmp_path / "s.py", {"a": 1, "b": 60, "c": 1})
    out = tmp_path / "sweep"
    p = _launch(sweep, out)
    _wait_file(out / "runs/b/pid", 90)
    job_b = json.loads((out / "slurm_jobs.json").read_text())["b"]
    subprocess.run(["scancel", job_b], check=True)
    log, _ = p.communicate(timeout=120)
    assert p.returncode == 1, log  # b failed; the launcher waited for a and c, then exited non-zero
    rows = {r["run_id"]: r for r in _rows(out)}
    assert rows["a"]["status"] == "done" and rows["c"]["status"] == "done", log
    assert rows["b"]["status"] == "failed" and "CANCELLED" in rows["b"]["error"], rows["b"]
    # The array's time limit came from the sweep's preset, not submitit's 5-minute default.
    sbatch = next((out / "submitit").glob("*_submission.sh")).read_text()
    assert "--time=10" in sbatch
    # Relaunch (b quick now): only b runs again; a and c are not redone.
    sweep = _sweep_file(tmp_path / "s.py", {"a": 1, "b": 1, "c": 1})
    p = _launch(sweep, out)
    log, _ = p.communicate(timeout=120)
    assert p.returncode == 0, log
    assert [len(_invocations(out / "runs" / n)) for n in "abc"] == [1, 2, 1]
    rows = _rows(out)
    assert sorted(r["run_id"] for r in rows) == ["a", "b", "c"] and {r["status"] for r in rows} == {"done"}
    assert all(r["device_kind"] == "cpu" and r["wall_time_s"] > 0 for r in rows)
    print(f"scancel case: {time.time() - t0:.1f} s")


def test_relaunch_while_a_job_of_the_first_launch_still_runs(slurm, tmp_path):
    """A launcher killed while its jobs run; the relaunch adopts the running job instead of submitting
    a second one on the same run folder, waits for it, and ends with every row once."""
    t0 = time.time()
    sweep = _sweep_file(tmp_path / "s.py", {"x": 1, "y": 12, "z": 1})
    out = tmp_path / "sweep"
    p = _launch(sweep, out)
    _wait_file(out / "runs/y/pid", 90)
    first_ids = json.loads((out / "slurm_jobs.json").read_text())
    p.send_signal(signal.SIGKILL)  # the launcher dies; its SLURM jobs go on
    p.wait()
    assert first_ids["y"] in _squeue()
    p = _launch(sweep, out)
    log, _ = p.communicate(timeout=120)
    assert p.returncode == 0, log
    assert f"adopting" in log and f"y={first_ids['y']}" in log, log
    assert json.loads((out / "slurm_jobs.json").read_text())["y"] == first_ids["y"]  # not resubmitted
    assert len(_invocations(out / "runs/y")) == 1  # trained once, by the first launch's job
    rows = _rows(out)
    assert sorted(r["run_id"] for r in rows) == ["x", "y", "z"] and {r["status"] for r in rows} == {"done"}
    # --existing cancel: an earlier launch's job is cancelled and resubmitted, never run twice at once.
    sweep2 = _sweep_file(tmp_path / "s2.py", {"w": 20})
    out2 = tmp_path / "sweep2"
    p = _launch(sweep2, out2)
    _wait_file(out2 / "runs/w/pid", 90)
    old = json.loads((out2 / "slurm_jobs.json").read_text())["w"]
    p.send_signal(signal.SIGKILL)
    p.wait()
    sweep2 = _sweep_file(tmp_path / "s2.py", {"w": 1})
    p = _launch(sweep2, out2, "--existing", "cancel")
    log, _ = p.communicate(timeout=120)
    assert p.returncode == 0 and "cancelling 1 job" in log, log
    assert json.loads((out2 / "slurm_jobs.json").read_text())["w"] != old
    assert [r["status"] for r in _rows(out2)] == ["done"]
    print(f"relaunch case: {time.time() - t0:.1f} s")


def test_two_task_job_initialises_from_slurm(slurm, tmp_path):
    """`srun -n 2`: handx_jax.train.initialize_distributed sees SLURM_NTASKS=2 and jax.distributed takes
    the coordinator, process count and ids from SLURM's environment; the loss curve matches one process."""
    t0 = time.time()
    worker = str(HERE / "distributed_worker.py")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COORDINATOR", "JAX_NUM_PROC", "JAX_PROCESS"))}
    env.update(PYTHONPATH=str(REPO), JAX_PLATFORMS="cpu", WANDB_MODE="disabled")
    one = subprocess.run([sys.executable, worker, str(tmp_path / "one")], env=env, capture_output=True, text=True,
                         timeout=120)
    assert one.returncode == 0, one.stderr[-2000:]
    r = subprocess.run(["srun", "-n", "2", "-c", "1", "-t", "5", "--chdir", str(tmp_path), sys.executable, worker,
                        str(tmp_path / "two")], env=env, capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    assert "process 0/2 devices 2 step 12" in r.stdout and "process 1/2 devices 2 step 12" in r.stdout, r.stdout
    losses = [[json.loads(x)["loss"] for x in (tmp_path / d / "metrics.jsonl").read_text().splitlines()]
              for d in ("one", "two")]
    assert len(losses[0]) == 12 and all(abs(a - b) <= 1e-5 * abs(a) for a, b in zip(*losses)), losses
    print(f"srun -n 2 case: {time.time() - t0:.1f} s")
