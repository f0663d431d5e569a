"""The sweep launcher: sweep files, shared steps, failures, locks, kill -9 and relaunch, results tables.

Most tests use a light fake stage (tests/sweep_fake_stage.py) instead of JAX training, so they take
about a second each; one slow test runs the real diffusion stages.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from handx_jax.infra.errors import DataError
from handx_jax.infra.provenance import versions
from handx_jax.infra.runlock import RunLock, RunLocked, is_locked, pid_alive
from sweeps.launcher import RunSpec, Step, SweepConfig, collect_results, launch, load_sweep, stage_state, status

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
FAKE = str(HERE / "sweep_fake_stage.py")
TINY = ("model.layers=1", "model.dim=32", "model.heads=4", "model.ff=64", "train.steps=4", "train.batch_size=8",
        "train.log_every=2", "train.ckpt_every=2", "train.wandb=disabled")


def fake(name, *args, size=1, needs=(), **axes):
    cmd = (sys.executable, FAKE, "--out", "{run}", "--size", str(size), *args)
    return RunSpec(name, "diffusion", command=cmd, needs=needs, axes={"layers": size, **axes})


def cfg_for(tmp_path, **kw):
    return SweepConfig(data=str(tmp_path / "data"), encoder="", out=str(tmp_path / "sweep"), **kw)


def rows_of(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines()]


def invocations(run):
    p = Path(run) / "invocations.log"
    return [json.loads(line) for line in p.read_text().splitlines()] if p.exists() else []


# ------------------------------------------------------------------------------------------------
# Sweep files


def test_sweep_files_define_the_grids(tmp_path):
    dd = load_sweep("sweeps/diffusion_depth_data.py", preset="paper")
    assert len(dd) == 12 and len({s.name for s in dd}) == 12
    assert {(s.axes["layers"], s.axes["data_fraction"]) for s in dd} == {
        (L, f) for L in (4, 8, 12, 16) for f in (0.05, 0.2, 1.0)}
    # Run ids are a deterministic function of the overrides (same call, same ids; any change, new id).
    assert [s.name for s in dd] == [s.name for s in load_sweep("sweeps/diffusion_depth_data.py", preset="paper")]
    assert {s.name for s in load_sweep("sweeps/diffusion_depth_data.py", preset="paper", steps=10)}.isdisjoint(
        {s.name for s in dd})
    pairs = load_sweep("sweeps/diffusion_depth_data.py", preset="tiny", sampling="pairs")
    assert all("data.sampling=pairs" in s.overrides for s in pairs) and len(pairs) == 12

    ladder = load_sweep("sweeps/diffusion_flops_ladder.py", preset="paper")
    assert [s.overrides[:4] for s in ladder][0] == ("model.layers=2", "model.dim=256", "model.heads=4", "model.ff=1024")
    assert all("data.fraction=0.05" in s.overrides for s in ladder) and len(ladder) == 7
    from handx_jax.families.diffusion import flops
    from handx_jax.models.dit import DiTConfig

    g = [flops.paper_flops(DiTConfig(layers=s.axes["layers"], dim=s.axes["dim"], heads=s.axes["heads"],
                                     ff=s.axes["ff"]))["flops_per_sample_paper"] / 1e9 for s in ladder]
    assert [round(x, 2) for x in g] == [3.83, 4.22, 5.22, 6.98, 9.74, 12.86, 24.63]
    assert len(load_sweep("sweeps/diffusion_flops_ladder.py", preset="tiny")) == 7
    width = load_sweep("sweeps/diffusion_width.py", preset="paper")
    assert {s.axes["layers"] for s in width} == {8} and [s.axes["dim"] for s in width] == [256, 384, 512, 768]

    ar = load_sweep("sweeps/ar_size_codebook.py", preset="paper")
    assert len(ar) == 12 and all(s.family == "ar" for s in ar)
    # One tokenizer step per codebook, shared by the three LM sizes; one joined text cache for all.
    keys = {}
    for s in ar:
        text, tok = s.needs
        assert text.name == "text-joined" and tok.name == f"tokenizer-K{s.axes['codebook']}"
        keys.setdefault(s.axes["codebook"], set()).add(tok.key)
        # The codebook reaches the tokenizer as its config key only; the launcher passes --tokenizer itself
        # (the registry: ar is trained from a tokenizer run).
        assert tok.family == "tokenizer" and not s.args
        train = tok.commands[0]
        assert f"model.codebook={s.axes['codebook']}" in train and "--codebook" not in train
    assert sorted(keys) == [512, 1024, 2048, 4096] and all(len(v) == 1 for v in keys.values())
    assert len({k for v in keys.values() for k in v}) == 4
    assert {s.preset for s in ar} == {"8L-512", "12L-768", "16L-1024"}
    # ``cpu`` (make sweep-ar-cpu): 3 LM sizes x 3 codebooks, one tokenizer per codebook shared by the sizes, the
    # largest (longest) LMs first, steps growing with size, sampled generation as a run setting.
    cpu = load_sweep("sweeps/ar_size_codebook.py", preset="cpu")
    assert [(s.axes["layers"], s.axes["dim"], s.axes["codebook"]) for s in cpu] == [
        (L, d, K) for L, d in ((3, 96), (2, 64), (1, 32)) for K in (256, 1024, 4096)]
    toks = {}
    for s in cpu:
        toks.setdefault(s.axes["codebook"], set()).add(s.needs[1].key)
        st = {o.split("=")[0]: o.split("=")[1] for o in s.overrides}
        assert st["train.steps"] == {1: "150", 2: "300", 3: "600"}[s.axes["layers"]]
        assert st["sample.temperature"] == "0.6"
        # the level-0 recipe (docs/results/ar_text): concise captions, 10% conditioning dropout
        assert (st["data.levels"], st["data.text_drop"], st["train.batch_size"]) == ("0", "0.1", "64")
    assert all(len(v) == 1 for v in toks.values()) and len({k for v in toks.values() for k in v}) == 3

    bad = tmp_path / "bad.py"
    bad.write_text("from sweeps.launcher import RunSpec\ndef runs():\n    return [RunSpec('a'), RunSpec('a')]\n")
    with pytest.raises(ValueError, match="unique"):
        load_sweep(bad)


def test_a_paper_sized_point_names_its_size():
    """The sweep files pass the preset that names a point's size (models/ladder.py), not a placeholder."""
    ladder = load_sweep("sweeps/diffusion_flops_ladder.py", preset="paper")
    assert [s.preset for s in ladder] == ["L2-d256", "paper-4L", "L4-d384", "L8-d384", "L8-d512", "L12-d512",
                                          "L12-d768"]
    depth = {s.axes["layers"]: s.preset for s in load_sweep("sweeps/diffusion_depth_data.py", preset="paper")}
    assert depth == {4: "paper-4L", 8: "paper-8L", 12: "paper-12L", 16: "paper-4L"}  # 16 layers: no name, a base
    assert {s.preset for s in load_sweep("sweeps/diffusion_width.py", preset="tiny")} == {"tiny"}


def test_a_renamed_command_keeps_its_steps_key():
    """A step's key names what it computes: the tokenizer step runs `handx data tokens` since issue 42 (was
    `handx tokenize`) and keeps the key it had (the AR LMs' run ids carry it), pinned here from before."""
    from sweeps.spec import Step, family_step

    tok = family_step("tokenizer", "tokenizer-K256", "small", ("model.codebook=256",))
    assert tok.commands[1][:3] == ("handx", "data", "tokens")
    assert tok.key == "tokenizer-K256-f365810f4f32"
    old = Step(tok.name, (tok.commands[0], ("handx", "tokenize", *tok.commands[1][3:])), family=tok.family)
    assert old.key == tok.key and Step(tok.name, tok.commands[:1]).key != tok.key


def test_cpu_study_presets_fix_epochs_and_match_steps_to_size():
    """``cpu``: every size takes the same steps, a fraction f takes f of them (fixed epochs). ``matched``: the
    same grid, steps ×0.5 / ×1 / ×2 over the three sizes; the middle size's runs are the same runs (ids)."""
    def steps(preset):
        return {(s.axes["dim"], s.axes["data_fraction"]): int(dict(o.split("=", 1) for o in s.overrides)["train.steps"])
                for s in load_sweep("sweeps/diffusion_cpu_study.py", preset=preset)}

    assert steps("cpu") == {(d, f): 1500 if f == 1.0 else 300 for d in (32, 64, 128) for f in (0.2, 1.0)}
    assert steps("matched") == {(32, 1.0): 750, (32, 0.2): 150, (64, 1.0): 1500, (64, 0.2): 300,
                                (128, 1.0): 3000, (128, 0.2): 600}
    cpu, matched = (load_sweep("sweeps/diffusion_cpu_study.py", preset=p) for p in ("cpu", "matched"))
    assert {s.name for s in cpu} & {s.name for s in matched} == {s.name for s in cpu if s.axes["dim"] == 64}
    assert [s.axes["dim"] for s in matched][:2] == [128, 128]  # most expensive first
    # A replicate with another training seed: the same grid, new run ids; the default seed keeps the ids.
    rep = load_sweep("sweeps/diffusion_cpu_study.py", preset="matched", seeds=1)
    assert all("train.seed=1" in s.overrides for s in rep) and not {s.name for s in rep} & {s.name for s in matched}
    both = load_sweep("sweeps/diffusion_cpu_study.py", preset="matched", seeds=[42, 1])
    assert {s.name for s in both} == {s.name for s in matched} | {s.name for s in rep}  # 42: the default's ids
    with pytest.raises(ValueError, match="distinct whole numbers"):
        load_sweep("sweeps/diffusion_cpu_study.py", preset="matched", seeds=[1, 1])
    with pytest.raises(ValueError, match="scales the steps of 3 sizes, got 1"):
        load_sweep("sweeps/diffusion_cpu_study.py", preset="matched", sizes=((1, 32, 2, 64),))


def test_run_names_cannot_leave_out(tmp_path):
    bad = tmp_path / "evil.py"
    bad.write_text("from sweeps.launcher import RunSpec\ndef runs():\n    return [RunSpec('../../escape')]\n")
    with pytest.raises(DataError, match="not allowed"):
        load_sweep(bad)
    cfg = cfg_for(tmp_path)
    for name in ("../x", "a/b", "..", ".hidden", "x/../../y"):
        with pytest.raises(DataError, match="not allowed"):
            launch([RunSpec(name, command=("true",))], cfg)
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
    f = tmp_path / "step.py"
    f.write_text("from sweeps.launcher import RunSpec, Step\n"
                 "def runs():\n    return [RunSpec('a', needs=(Step('../tok', (('true',),)),))]\n")
    with pytest.raises(DataError, match="step name"):
        load_sweep(f)


def test_collect_refuses_a_mistyped_path(tmp_path):
    r = subprocess.run([sys.executable, "-m", "handx_jax", "sweep", "collect", "--out", str(tmp_path / "no-such-sweep")],
                       capture_output=True, text=True, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode != 0 and "no sweep folder" in r.stderr and r.stdout == ""
    assert not (tmp_path / "no-such-sweep").exists()
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="not a sweep folder"):
        collect_results(tmp_path / "empty")


# ------------------------------------------------------------------------------------------------
# Launch, failures, shared steps, results


def test_failure_is_recorded_and_the_sweep_goes_on(tmp_path, monkeypatch):
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)  # a user who names no cache
    cfg = cfg_for(tmp_path)
    specs = [fake("a", size=1), fake("b", "--fail", size=2), fake("c", size=3)]
    res = launch(specs, cfg)
    assert list(res.failed) == ["b"] and "exit 3" in res.failed["b"] and "failing on purpose" in res.failed["b"]
    rows = rows_of(res.results)
    assert [r["run_id"] for r in rows] == ["a", "b", "c"]
    assert [r["status"] for r in rows] == ["done", "failed", "done"]
    assert "failing on purpose" in rows[1]["error"]
    a = rows[0]
    # Provenance columns of a launcher row.
    assert a["sweep"] == "sweep" and a["device_kind"] == "cpu" and a["wall_time_s"] > 0 and a["git_commit"]
    assert a["params"] == 1000 and a["flops_per_sample"] == 1e6 and a["layers"] == 1
    csv = (tmp_path / "sweep/results.csv").read_text().splitlines()
    assert csv[0].startswith("run_id,family") and len(csv) == 4 and "status" in csv[0]
    # Every run shares one persistent JAX compilation cache under the sweep folder, unless the user names one.
    assert invocations(tmp_path / "sweep/runs/a")[0]["cache"] == str(tmp_path / "sweep/jax_cache")
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "mine"))
    launch([fake("d")], SweepConfig(**{**cfg.__dict__, "out": str(tmp_path / "sweep2")}))
    assert invocations(tmp_path / "sweep2/runs/d")[0]["cache"] == str(tmp_path / "mine")
    st = {r["name"]: r["status"] for r in status(tmp_path / "sweep")}
    assert st == {"a": "done", "b": "failed", "c": "done"}
    # The CLI exits non-zero at the end, after running every run.
    sweep = tmp_path / "s.py"
    sweep.write_text(f"import sys\nfrom sweeps.launcher import RunSpec\nF = {FAKE!r}\n"
                     "def runs(preset='tiny'):\n"
                     "    return [RunSpec(n, 'diffusion', command=(sys.executable, F, '--out', '{run}') + x)"
                     " for n, x in (('p', ('--fail',)), ('q', ()))]\n")
    r = subprocess.run([sys.executable, "-m", "handx_jax", "sweep", "run", str(sweep), "--preset", "tiny",
                        "--data", str(tmp_path), "--out", str(tmp_path / "cli")], capture_output=True, text=True,
                       cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode == 1 and "1 of 2 run(s) failed" in r.stderr
    assert (tmp_path / "cli/runs/q/train_done.json").exists()
    r = subprocess.run([sys.executable, "-m", "handx_jax", "sweep", "status", "--out", str(tmp_path / "cli")],
                       capture_output=True, text=True, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode == 0 and "1 done, 0 running, 1 failed, 0 pending" in r.stdout


def test_shared_steps_run_once_and_are_recorded(tmp_path):
    cfg = cfg_for(tmp_path, max_parallel=2)
    tok = lambda k: Step(f"tok-K{k}", ((sys.executable, FAKE, "--out", "{out}", "--seconds", "0.3"),  # noqa: E731
                                       (sys.executable, "-c", f"open('{{out}}/codebook','w').write('{k}')")))
    specs = [fake(f"r{i}-K{k}", "--tokenizer", f"{{step:tok-K{k}}}", size=i, needs=(tok(k),), codebook=k)
             for k in (8, 16) for i in (1, 2, 3)]
    res = launch(specs, cfg)
    assert not res.failed
    steps = sorted((tmp_path / "sweep/steps").iterdir())
    assert [p.name.rsplit("-", 1)[0] for p in steps] == ["tok-K16", "tok-K8"]
    for p in steps:  # each step ran once although three runs (two at a time) needed it
        assert len(invocations(p)) == 1 and (p / "step_done.json").exists()
    for s in specs:
        d = tmp_path / "sweep/runs" / s.name
        prov = json.loads((d / "provenance.json").read_text())
        assert prov["versions"] == versions() and {"jax", "jaxlib", "flax", "optax", "orbax-checkpoint",
                                                    "numpy"} <= {k for k, v in prov["versions"].items() if v}
        k = s.axes["codebook"]
        assert prov["steps"][f"tok-K{k}"]["dir"] == str(tmp_path / "sweep/steps" / tok(k).key)
        assert json.loads((d / "config.json").read_text())["tokenizer"] == prov["steps"][f"tok-K{k}"]["dir"]
    assert {r["codebook"] for r in rows_of(res.results)} == {8, 16}
    # A relaunch redoes nothing.
    launch(specs, cfg)
    assert all(len(invocations(p)) == 1 for p in steps)
    assert all(len(invocations(tmp_path / "sweep/runs" / s.name)) == 1 for s in specs)


# ------------------------------------------------------------------------------------------------
# Run-folder lock


def test_runlock_excludes_recovers_and_is_inherited(tmp_path):
    d = tmp_path / "run"
    with RunLock(d):
        assert is_locked(d)["pid"] == os.getpid()
        # Another process (not our child: a grandchild) is refused with a message naming the holder.
        code = (f"from handx_jax.infra.runlock import RunLock, RunLocked\ntry:\n    RunLock({str(d)!r}).acquire()\n"
                "except RunLocked as e:\n    print('LOCKED', e)\n")
        outer = f"import subprocess, sys; subprocess.run([sys.executable, '-c', {code!r}])"
        r = subprocess.run([sys.executable, "-c", outer], capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": str(REPO)})
        assert f"LOCKED {d} is in use by pid {os.getpid()}" in r.stdout
        # ... but a child this process started to work in the folder inherits it.
        code = (f"from handx_jax.infra.runlock import RunLock\nl = RunLock({str(d)!r}).acquire()\n"
                "print('INHERITED', l.inherited)\nl.release()\n")
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": str(REPO)})
        assert "INHERITED True" in r.stdout
        with RunLock(d):  # re-entrant in one thread
            pass
        assert is_locked(d)
    assert not (d / ".lock").exists()
    # A lock left by a dead process is recovered.
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    (d / ".lock").write_text(json.dumps({"pid": p.pid, "host": os.uname().nodename, "started": time.time()}))
    with pytest.raises(RunLocked):
        RunLock(d).acquire()
    p.kill()
    p.wait()
    assert not pid_alive(p.pid) and is_locked(d) is None
    with RunLock(d):
        assert is_locked(d)["pid"] == os.getpid()


def test_kill9_of_the_launcher_ends_its_child_and_the_relaunch_finishes(tmp_path):
    """Issue 14.8: a launcher killed with -9 must not leave a trainer running, and the relaunch must
    finish every run exactly once without redoing finished ones."""
    sweep = tmp_path / "slow.py"
    sweep.write_text(f"import sys\nfrom sweeps.launcher import RunSpec\nF = {FAKE!r}\n"
                     "def runs(seconds=0.2):\n"
                     "    return [RunSpec(n, 'diffusion',"
                     " command=(sys.executable, F, '--out', '{run}', '--seconds', str(s)),"
                     " axes={'layers': i + 1}) for i, (n, s) in enumerate((('a', 0.2), ('b', 30), ('c', 0.2)))]\n")
    out = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "handx_jax", "sweep", "run", str(sweep), "--data", str(tmp_path), "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    launcher = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pid_file = out / "runs/b/pid"
    deadline = time.time() + 60
    # Non-empty: the fake stage creates the file, then writes its pid (a read in between finds it empty).
    while not (pid_file.exists() and pid_file.read_text().strip()) and time.time() < deadline:
        time.sleep(0.05)
    assert pid_file.exists(), "run b never started"
    child = int(pid_file.read_text())
    assert pid_alive(child)
    assert {r["name"]: r["status"] for r in status(out)} == {"a": "done", "b": "running", "c": "pending"}
    launcher.send_signal(signal.SIGKILL)
    launcher.wait()
    deadline = time.time() + 10
    while pid_alive(child) and time.time() < deadline:
        time.sleep(0.05)
    assert not pid_alive(child), "the training child outlived its launcher"
    st = {r["name"]: r["status"] for r in status(out)}
    assert st == {"a": "done", "b": "failed", "c": "pending"}  # b's holder died mid-run
    # Relaunch (b fast this time): the stale lock is recovered, a is not redone, b and c finish.
    sweep.write_text(sweep.read_text().replace("('b', 30)", "('b', 0.2)"))
    r = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert [len(invocations(out / "runs" / n)) for n in "abc"] == [1, 2, 1]
    rows = rows_of(out / "results.jsonl")
    assert [x["run_id"] for x in rows] == ["a", "b", "c"] and {x["status"] for x in rows} == {"done"}


# ------------------------------------------------------------------------------------------------
# Scores from another evaluator are stale


def _fake_evaluator(path: Path, *, level: int = 0, weights: bytes = b"w1") -> Path:
    """An evaluator folder as far as its identity goes (what evaluator_id and the launcher read)."""
    import numpy as np

    from handx_jax.evaluation import FORMAT, FORMAT_VERSION

    path.mkdir(parents=True, exist_ok=True)
    meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "evaluator_config": {"latent": 8},
            "text": {"max_len": 16, "train_levels": [0], "eval_level": level},
            "encoder": {"fingerprint": "enc", "tokenizer_fingerprint": "tok"}}
    (path / "evaluator.json").write_text(json.dumps(meta))
    (path / "params.msgpack").write_bytes(weights * 32)
    np.savez(path / "norm_stats.npz", evaluator_mean=np.zeros(3, np.float32), evaluator_std=np.ones(3, np.float32))
    return path


def _fake_handx_stages(monkeypatch, on_stage):
    """Run the fake training stage for real and hand each handx stage to ``on_stage(name, argv)`` (it
    writes the stage's output and returns what to record); returns the list of recorded calls."""
    import sweeps.stages as stages  # run_command: the stages' subprocess runner

    calls, real = [], stages.run_command

    def run_command(argv, log, env):
        argv = list(argv)
        if "handx_jax" not in argv:
            calls.append("train")
            return real(argv, log, env)
        calls.append(on_stage(argv[argv.index("handx_jax") + 1], argv))
        return 0.0

    monkeypatch.setattr(stages, "run_command", run_command)
    return calls


def test_scores_of_another_evaluator_are_redone_and_kept(tmp_path, monkeypatch):
    """Relaunching a sweep with another evaluator rescores every finished run without retraining it,
    keeps the old scores beside the new, and regenerates only when the caption level changed."""
    import shutil

    import numpy as np

    import sweeps.launcher as L
    import sweeps.stages as stages  # run_command: the stages' subprocess runner
    from analysis.schema import row_from_run_dir
    from handx_jax.evaluation import evaluator_id

    calls = []
    real = stages.run_command

    def run_command(argv, log, env):
        argv = list(argv)
        if "handx_jax" not in argv:  # the fake training stage runs for real
            calls.append("train")
            return real(argv, log, env)
        run = Path(argv[argv.index("--run") + 1] if "--run" in argv else argv[argv.index("--out") + 1])
        if argv[argv.index("handx_jax") + 1] == "generate":
            calls.append(("generate", int(argv[argv.index("--level") + 1])))
            Path(argv[argv.index("--out") + 1]).write_bytes(os.urandom(16))
        else:
            E = argv[argv.index("--evaluator") + 1]
            calls.append(("evaluate", evaluator_id(E)))
            (run / "eval.json").write_text(json.dumps({"rprec_top3": 0.2, "_meta": {"evaluator_id": evaluator_id(E)}}))
        return 0.0

    monkeypatch.setattr(stages, "run_command", run_command)
    E1 = _fake_evaluator(tmp_path / "E1")
    spec = fake("a")
    cfg = cfg_for(tmp_path, evaluator=str(E1))
    run = tmp_path / "sweep" / "runs" / "a"
    L.run_one(spec, cfg)
    id1 = evaluator_id(E1)
    assert calls == ["train", ("generate", 0), ("evaluate", id1)] and L.is_complete(cfg, spec)
    assert row_from_run_dir(run)["evaluator_id"] == id1
    L.run_one(spec, cfg)  # finished, same evaluator: nothing runs
    assert len(calls) == 3
    generated = (run / "generated.npz").read_bytes()

    prov = json.loads((run / "provenance.json").read_text())
    (run / "provenance.json").write_text(json.dumps({**prov, "git_commit": "commit-that-trained"}))

    # Other weights, same caption level: rescored only; the old scores stay as eval.<old id>.json.
    E2 = _fake_evaluator(tmp_path / "E2", weights=b"w2")
    id2 = evaluator_id(E2)
    cfg2 = cfg_for(tmp_path, evaluator=str(E2))
    assert id2 != id1 and stage_state(cfg2, spec) == {"train": True, "generate": True, "evaluate": False}
    assert not L.is_complete(cfg2, spec) and L.stale_scores(cfg2, run) == "evaluate"
    assert L.run_status(tmp_path / "sweep", cfg2, spec) == ("pending", "scored by another evaluator: rescore")
    L.run_one(spec, cfg2)
    assert calls[3:] == [("evaluate", id2)] and (run / "generated.npz").read_bytes() == generated
    assert json.loads((run / f"eval.{id1}.json").read_text())["_meta"]["evaluator_id"] == id1
    assert row_from_run_dir(run)["evaluator_id"] == id2 and L.stale_scores(cfg2, run) is None
    prov = json.loads((run / "provenance.json").read_text())  # the row says what trained it, not what rescored
    assert prov["git_commit"] == "commit-that-trained" and prov["stages"]["evaluate"]["git_commit"] == L.git_commit()

    # A copy of E2 elsewhere is the same evaluator (nothing to redo); the stats are hashed by value.
    E2b = tmp_path / "copy"
    shutil.copytree(E2, E2b)
    np.savez(E2b / "norm_stats.npz", evaluator_mean=np.zeros(3, np.float32), evaluator_std=np.ones(3, np.float32))
    assert evaluator_id(E2b) == id2 and L.is_complete(cfg_for(tmp_path, evaluator=str(E2b)), spec)

    # An evaluator scoring another caption level: the samples were prompted at the old level, so regenerate.
    E3 = _fake_evaluator(tmp_path / "E3", level=2, weights=b"w2")
    cfg3 = cfg_for(tmp_path, evaluator=str(E3))
    assert L.stale_scores(cfg3, run) == "generate" and not stage_state(cfg3, spec)["generate"]
    L.run_one(spec, cfg3)
    assert calls[4:] == [("generate", 2), ("evaluate", evaluator_id(E3))] and calls.count("train") == 1

    # Scores that do not say who made them (written before evaluator ids) are redone too.
    (run / "eval.json").write_text(json.dumps({"rprec_top3": 0.3, "_meta": {}}))
    L.run_one(spec, cfg3)
    assert calls[6:] == [("evaluate", evaluator_id(E3))] and (run / "eval.unrecorded.json").exists()


def test_rescore_a_sweep_with_a_new_evaluator(tmp_path, monkeypatch, capsys):
    """`handx sweep rescore --out OUT --evaluator E`: the sweep's trained runs are scored by E with the sweep's
    own settings, in the sweep's order; an untrained run is named and left alone; a second rescore is a no-op."""
    import shutil

    from handx_jax.cli import main
    from handx_jax.evaluation import evaluator_id

    def on_stage(stage, argv):
        if stage == "generate":
            assert argv[argv.index("--samples") + 1] == "3"  # the sweep's setting, kept by rescore
            Path(argv[argv.index("--out") + 1]).write_bytes(b"x")
        else:
            E = argv[argv.index("--evaluator") + 1]
            run = Path(argv[argv.index("--out") + 1])
            (run / "eval.json").write_text(json.dumps({"rprec_top3": 0.25, "_meta": {"evaluator_id": evaluator_id(E)}}))
        return stage

    calls = _fake_handx_stages(monkeypatch, on_stage)
    (tmp_path / "data").mkdir()
    E1, E2 = _fake_evaluator(tmp_path / "E1"), _fake_evaluator(tmp_path / "E2", weights=b"w2")
    cfg = cfg_for(tmp_path, evaluator=str(E1), eval_samples=3)
    assert not launch([fake("a"), fake("b", size=2), fake("c", "--fail")], cfg).failed.keys() - {"c"}
    assert calls.count("eval") == 2
    calls.clear()
    assert main(["sweep", "rescore", "--out", str(tmp_path / "sweep"), "--evaluator", str(E2)]) == 0
    out = capsys.readouterr().out
    assert "rescoring 2 of 3 run(s)" in out and "not trained, left alone: c" in out
    assert calls == ["eval", "eval"]  # nothing trained, samples reused
    rows = rows_of(tmp_path / "sweep" / "results.jsonl")
    assert [r["run_id"] for r in rows] == ["a", "b", "c"]
    assert [r.get("evaluator_id") for r in rows] == [evaluator_id(E2)] * 2 + [None]
    assert main(["sweep", "rescore", "--out", str(tmp_path / "sweep"), "--evaluator", str(E2)]) == 0
    assert "rescoring 0 of 3 run(s)" in capsys.readouterr().out and calls == ["eval", "eval"]
    assert main(["sweep", "rescore", "--out", str(tmp_path / "nope"), "--evaluator", str(E2)]) == 2
    assert "no sweep folder" in capsys.readouterr().err
    assert main(["sweep", "rescore", "--out", str(tmp_path / "sweep"), "--evaluator", str(tmp_path / "E9")]) == 2
    assert "--evaluator " + str(tmp_path / "E9") + ": no such folder" in capsys.readouterr().err  # standard.naming
    # a sweep whose evaluator has since been deleted still reports its status
    shutil.rmtree(E2)
    assert [r["status"] for r in status(tmp_path / "sweep")] == ["done", "done", "failed"]


def test_a_sweep_launched_with_a_relative_out_is_read_from_anywhere(tmp_path, monkeypatch):
    """sweep.json keeps --out as given; reading the sweep from another working directory (or after the
    folder moved) must find its runs, not rewrite the table with every run pending."""
    from handx_jax.cli import main

    (tmp_path / "data").mkdir()
    monkeypatch.chdir(tmp_path)
    cfg = SweepConfig(data=str(tmp_path / "data"), encoder="", out="rel/sweep")
    assert not launch([fake("a"), fake("b", size=2)], cfg).failed
    before = rows_of(tmp_path / "rel/sweep/results.jsonl")
    assert [r["status"] for r in before] == ["done", "done"]
    monkeypatch.chdir(REPO)
    assert main(["sweep", "collect", "--out", str(tmp_path / "rel/sweep")]) == 0
    assert rows_of(tmp_path / "rel/sweep/results.jsonl") == before
    assert [r["status"] for r in status(tmp_path / "rel/sweep")] == ["done", "done"]
    (tmp_path / "rel/sweep").rename(tmp_path / "moved")
    assert [r["status"] for r in status(tmp_path / "moved")] == ["done", "done"]


def test_scores_at_another_block_are_redone_from_the_same_samples(tmp_path, monkeypatch, capsys):
    """A sweep scores at its R-Precision block (the sweep file's RPREC_BLOCK, or --block): runs
    scored at another block are rescored from their samples, the old scores kept as
    eval.<id>.b<block>.json and never overwritten; the table's rprec_block follows."""
    import sweeps.launcher as L
    from analysis.schema import row_from_run_dir
    from handx_jax.cli import main
    from handx_jax.evaluation import evaluator_id

    def on_stage(stage, argv):
        if stage == "generate":
            Path(argv[argv.index("--out") + 1]).write_bytes(os.urandom(16))
            return "generate"
        E, block = argv[argv.index("--evaluator") + 1], int(argv[argv.index("--block") + 1])
        (Path(argv[argv.index("--out") + 1]) / "eval.json").write_text(json.dumps(
            {"rprec_top3": 3.0 / block, "_meta": {"evaluator_id": evaluator_id(E), "rprec_block": block}}))
        return ("evaluate", block)

    calls = _fake_handx_stages(monkeypatch, on_stage)
    (tmp_path / "data").mkdir()
    E = _fake_evaluator(tmp_path / "E")
    eid = evaluator_id(E)
    spec, run = fake("a"), tmp_path / "sweep" / "runs" / "a"
    assert not launch([spec], cfg_for(tmp_path, evaluator=str(E))).failed  # default block 32
    assert calls == ["train", "generate", ("evaluate", 32)]
    samples = (run / "generated.npz").read_bytes()

    cfg16 = cfg_for(tmp_path, evaluator=str(E), rprec_block=16)
    assert L.stale_scores(cfg16, run) == "block"
    assert stage_state(cfg16, spec) == {"train": True, "generate": True, "evaluate": False}
    assert L.run_status(tmp_path / "sweep", cfg16, spec) == (
        "pending", "scored at R-Precision block 32, the sweep's is 16: rescore")
    assert main(["sweep", "rescore", "--out", str(tmp_path / "sweep"), "--evaluator", str(E), "--block", "16"]) == 0
    assert "at R-Precision block 16" in capsys.readouterr().out
    assert calls[3:] == [("evaluate", 16)] and (run / "generated.npz").read_bytes() == samples
    assert json.loads((run / f"eval.{eid}.b32.json").read_text())["rprec_top3"] == 3.0 / 32
    assert row_from_run_dir(run)["rprec_block"] == 16
    assert rows_of(tmp_path / "sweep" / "results.jsonl")[0]["rprec_block"] == 16
    # the rescore's block is now the sweep's: a plain relaunch or rescore has nothing to do
    assert json.loads((tmp_path / "sweep" / "sweep.json").read_text())["config"]["rprec_block"] == 16
    assert main(["sweep", "rescore", "--out", str(tmp_path / "sweep"), "--evaluator", str(E)]) == 0
    assert "rescoring 0 of 1" in capsys.readouterr().out and len(calls) == 4

    # Back to 32 and to 16 again: each earlier file is kept, none overwritten.
    L.run_one(spec, cfg_for(tmp_path, evaluator=str(E)))
    L.run_one(spec, cfg16)
    assert calls[4:] == [("evaluate", 32), ("evaluate", 16)] and calls.count("train") == 1
    kept = sorted(p.name for p in run.glob("eval.*.json"))
    assert kept == [f"eval.{eid}.b16.json", f"eval.{eid}.b32.2.json", f"eval.{eid}.b32.json"]

    # The sweep file names its block; a bad one is refused with one line.
    assert L.load_rprec_block("sweeps/diffusion_flops_ladder.py") == 16
    assert L.load_rprec_block("sweeps/diffusion_cpu_study.py") == 32
    with pytest.raises(SystemExit) as e:
        main(["sweep", "run", "sweeps/diffusion_flops_ladder.py", "--block", "1", "--out", str(tmp_path / "x")])
    assert e.value.code == 2 and "at least 2" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------
# The real diffusion stages


@pytest.mark.slow
def test_pairs_sampling_draws_the_references_items(tmp_path):
    """``data.sampling=pairs`` draws (clip, level) items as the reference does. A real diffusion sweep through
    the launcher, its rows (sizes, parameters, both FLOPs conventions, data fraction and sampling read from each
    run's config.json) and OUT/jax_cache are tests/test_first_hour.py's (the README's sweep); killing and
    relaunching a sweep of real stages is tests/test_ar_sweep.py's."""
    from diffusion_fixtures import ENCODER, make_dataset

    from handx_jax.families.diffusion import load_train_data, make_config

    data = make_dataset(tmp_path)
    # A run that sets no sampling draws whole clips ("clips" keeps every level of each clip).
    assert make_config("tiny", TINY, data="", encoder="").data.sampling == "clips"
    # pairs: RandomState(42).choice without replacement over all train items, nested across fractions.
    import numpy as np

    cfg = make_config("tiny", TINY + ("data.fraction=0.5", "data.sampling=pairs"), data=str(data), encoder=str(ENCODER))
    td = load_train_data(cfg)
    n = len(td.clips) * td.levels
    k = round(0.5 * n)
    assert np.array_equal(td.items, np.sort(np.random.RandomState(42).choice(n, k, replace=False)))
    small = np.sort(np.random.RandomState(42).permutation(n)[:round(0.05 * n)])
    assert set(small) <= set(td.items) and td.num_items == k
    b = td.batch(np.arange(3))
    assert np.array_equal(b["x0"], td.x_NxFx42x4[td.items[:3] // td.levels])


def test_dry_run_and_slurm_time_limit(tmp_path, capsys):
    from handx_jax.cli import main

    for f, n in (("diffusion_depth_data", 12), ("diffusion_flops_ladder", 7), ("diffusion_width", 4),
                 ("ar_size_codebook", 12)):
        assert main(["sweep", "run", f"sweeps/{f}.py", "--preset", "paper", "--executor", "slurm", "--dry-run",
                     "--out", str(tmp_path / f)]) == 0
        lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
        assert len(lines) == n + 2 and lines[-1]["slurm"]["timeout_min"] == 48 * 60  # the preset's time limit
        # The ladder scores at Table B / Fig. 4's R-Precision block, the others at Table 2-5's.
        assert lines[-2] == {"rprec_block": 16 if f == "diffusion_flops_ladder" else 32}
        assert not (tmp_path / f).exists()
    # Without a time limit, SLURM is refused rather than left to submitit's 5-minute default.
    with pytest.raises(ValueError, match="time limit"):
        launch([fake("a")], cfg_for(tmp_path, executor="slurm"))
    assert not (tmp_path / "sweep").exists()


def test_diffusion_sweep_overrides_are_valid_configs():
    """Every run of the diffusion sweep files, both presets, is a valid diffusion config of its axes."""
    from handx_jax.families.diffusion import make_config as mk

    def build(s):
        return mk(s.preset, list(s.overrides), data="", encoder="")

    for f in ("diffusion_depth_data", "diffusion_flops_ladder", "diffusion_width"):
        for preset in ("tiny", "short", "paper"):
            for s in load_sweep(f"sweeps/{f}.py", preset=preset, sampling="pairs"):
                c = build(s)
                assert (c.model.layers, c.model.dim) == (s.axes["layers"], s.axes["dim"])
                assert c.data.fraction == s.axes["data_fraction"] and c.data.sampling == "pairs"
                assert c.model.dim % c.model.heads == 0
                assert c.train.bf16 == (preset != "tiny")


def test_short_preset_trains_the_paper_sizes_on_a_short_schedule():
    """``short``: the paper's sizes (the same seven Table B rows as ``paper``), 1,000 steps × 128, lr 5e-4 with
    a 100-step warm-up and a cosine decay, no dropout; ``lr`` replaces the lr for every size, ``sizes`` keeps a
    subset of the ladder, and each gives new run ids."""
    from handx_jax.families.diffusion import make_config as mk

    paper = load_sweep("sweeps/diffusion_flops_ladder.py", preset="paper")
    short = load_sweep("sweeps/diffusion_flops_ladder.py", preset="short")
    assert [s.axes for s in short] == [s.axes for s in paper]
    c = mk(short[-1].preset, list(short[-1].overrides))
    assert (c.model.layers, c.model.dim, c.model.heads, c.model.ff) == (12, 768, 12, 3072)
    assert (c.train.steps, c.train.batch_size, c.train.optim.lr, c.train.optim.warmup_steps) == (1000, 128, 5e-4, 100)
    assert c.train.optim.schedule == "cosine" and c.model.dropout == 0.0 and c.train.bf16
    assert mk(paper[-1].preset, list(paper[-1].overrides)).train.steps == 100_000
    # Table C's depths and the width sweep's widths at the short schedule
    assert [s.axes["layers"] for s in load_sweep("sweeps/diffusion_depth_data.py", preset="short")][:4] == [4, 8, 12, 16]
    assert [s.axes["dim"] for s in load_sweep("sweeps/diffusion_width.py", preset="short")] == [256, 384, 512, 768]

    low = load_sweep("sweeps/diffusion_flops_ladder.py", preset="short", lr=2.5e-4, sizes=[(12, 768), [2, 256]])
    assert [(s.axes["layers"], s.axes["dim"]) for s in low] == [(2, 256), (12, 768)]  # the ladder's order
    assert all(mk(s.preset, list(s.overrides)).train.optim.lr == 2.5e-4 for s in low)
    assert {s.name for s in low}.isdisjoint({s.name for s in short})
    with pytest.raises(ValueError, match=r"\(12, 1024\)\] are not on the short ladder"):
        load_sweep("sweeps/diffusion_flops_ladder.py", preset="short", sizes=[(12, 1024)])
    with pytest.raises(ValueError, match=r"\(tiny \| short \| paper\)"):
        load_sweep("sweeps/diffusion_flops_ladder.py", preset="long")


def test_generate_stage_passes_only_family_agnostic_settings(tmp_path):
    """The generate stage's settings are ``sample.*`` overrides: the registry's sweep default for the run's
    family, then the run's own, then the sweep's ``--set`` (the last wins); an old sweep.json's
    ``sampler``/``sampler_steps`` are read as those overrides."""
    from sweeps.launcher import generate_settings
    from sweeps.results import load_state

    d = RunSpec("d", "diffusion", overrides=("model.layers=1", "sample.steps=8"))
    a = RunSpec("a", "ar", overrides=("sample.temperature=0.5",))
    cfg = cfg_for(tmp_path, sample=("sample.steps=25",))
    assert generate_settings(cfg, d) == ["sample.sampler=ddim", "sample.steps=50", "sample.steps=8", "sample.steps=25"]
    assert generate_settings(cfg_for(tmp_path), a) == ["sample.temperature=0.5"]  # nothing of diffusion's
    out = tmp_path / "old"
    out.mkdir()
    doc = {"config": {"data": "D", "encoder": "", "out": "x", "sampler": "ddim", "sampler_steps": 25},
           "runs": [{"name": "d", "family": "diffusion", "overrides": ["model.layers=1"]}]}
    (out / "sweep.json").write_text(json.dumps(doc))
    old_cfg, specs = load_state(out)
    assert old_cfg.sample == ("sample.sampler=ddim", "sample.steps=25") and specs[0].family == "diffusion"
