"""Bad input to ``handx import`` / ``handx export`` (issue 43): every case the probe of b725d7e found is
one line naming the file, tensor, key or flag, exit 2, with nothing half-written; two writers of one
``--out`` cannot both succeed, a killed writer's temporary folder is removed by the next run, and a
stride-0 tensor cannot make the reader allocate what its storage does not hold.

The checkpoints are the official fixtures (tests/fixtures/official_{diffusion,evaluator}, copies of
shared/reference/official_*_case/), edited and re-saved with the project's own PyTorch writer. Most
cases fail before the T5 encoder is loaded (milliseconds); the real-process cases (concurrent imports,
kill -9, a real full tmpfs) take a few seconds each.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from handx_jax.cli import main
from handx_jax.interop import torch_pickle as tp

FIX = Path(__file__).parent / "fixtures"
DIFF, EVAL = FIX / "official_diffusion", FIX / "official_evaluator"
ENV = {**os.environ, "JAX_PLATFORMS": "cpu"}


@pytest.fixture(scope="module")
def sd():
    from handx_jax.interop.official_diffusion import read_state_dict

    return read_state_dict(DIFF / "model.pt")


@pytest.fixture(scope="module")
def stats(tmp_path_factory):
    p = tmp_path_factory.mktemp("stats") / "stats.npz"
    np.savez(p, mean=np.zeros((42, 4), np.float32), std=np.ones((42, 4), np.float32))
    return p


def _pt(tmp_path, sd, name="model.pt", wrap="state_dict", **changes) -> Path:
    """The fixture's state dict with ``changes`` (name → array), saved as ``{wrap: sd}``."""
    d = {k: v.copy() for k, v in sd.items()}
    d.update({k.replace("__", "."): v for k, v in changes.items()})
    return tp.save(tmp_path / name, {wrap: d})


def _config(tmp_path, text=None, **edits) -> Path:
    body = (DIFF / "config.yaml").read_text() if text is None else text
    for k, v in edits.items():
        body = "\n".join(f"  {k}: {v}" if ln.strip().startswith(f"{k}:") else ln for ln in body.splitlines())
    p = tmp_path / "config.yaml"
    p.write_text(body + "\n")
    return p


def _fail(argv, capsys) -> str:
    """Run ``handx ARGV`` in-process expecting exit 2 and one line on stderr; return that line."""
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, (rc, err)
    return err.strip()


def _import(model, out, stats, *extra):
    return ["import", "handx-diffusion", model, "--encoder", DIFF / "t5", "--stats", stats, "--out", out, *extra]


# --------------------------------------------------------------------------------------------------
# Diffusion import: the checkpoint's values, shapes and settings


def test_nan_weight_is_refused_at_import_naming_the_tensor(tmp_path, sd, stats, capsys):
    w = sd["seq_trans_decoder.layers.1.linear1.weight"].copy()
    w[3, 5] = np.nan
    pt = _pt(tmp_path, sd, seq_trans_decoder__layers__1__linear1__weight=w)
    err = _fail(_import(pt, tmp_path / "R", stats, "--heads", "4"), capsys)
    assert err == (f"handx: error: file {pt}: tensor 'seq_trans_decoder.layers.1.linear1.weight' holds 1 non-finite "
                   "value(s) (NaN or inf; first at (3, 5)): the weights are broken (a diverged run?) and would make "
                   "every output NaN")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]


@pytest.mark.parametrize("case", ["config_blamed", "correct_tensor_blamed"])
def test_a_wrong_shape_tensor_is_named_against_the_right_source(tmp_path, sd, stats, capsys, case):
    cfg = _config(tmp_path)
    if case == "config_blamed":  # one damaged tensor of width 32; config.yaml and 8 tensors say 64
        pt = _pt(tmp_path, sd, null_text_embedding=np.zeros((1, 1, 32), np.float32))
        want = ("tensor 'null_text_embedding' has shape (1, 1, 32): width 32, but 8 other tensor(s) "
                "(left_hand_cls_token, …) have width 64")
    else:  # a layer's norm of the wrong size: blamed on itself, with where the size it should have comes from
        pt = _pt(tmp_path, sd, seq_trans_decoder__layers__1__norm2__weight=np.ones(32, np.float32))
        want = ("tensor 'seq_trans_decoder.layers.1.norm2.weight' has shape (32,); the sizes imply (64,) (width 64 "
                "and FF 128 agreed by the tensors' shapes, 4 heads from config.yaml's model.num_heads)")
    err = _fail(_import(pt, tmp_path / "R", stats, "--config", cfg), capsys)
    assert err == f"handx: error: file {pt}: {want}"
    assert not (tmp_path / "R").exists()


def test_a_state_dict_under_another_key_is_named(tmp_path, sd, stats, capsys):
    pt = _pt(tmp_path, sd, wrap="model")
    err = _fail(_import(pt, tmp_path / "R", stats, "--heads", "4"), capsys)
    assert err == (f"handx: error: file {pt}: no state dict in the checkpoint: it holds a dict of 'model' "
                   f"({len(sd)} tensors); expected the official {{'state_dict': {{name: tensor}}}} (or a bare "
                   "{name: tensor})")


CONFIG_CASES = {
    "latent_dim: abc": ({"latent_dim": "abc"}, "model.latent_dim is 'abc', not a whole number"),
    "num_heads: 3": ({"num_heads": 3}, "model.num_heads 3 does not divide the width 64 (the tensors' shapes): each "
                                       "head takes D / H values"),
    "num_heads: 0": ({"num_heads": 0}, "model.num_heads is 0; it must be a whole number >= 1"),
    "no model: section": (None, "no 'model:' section (top-level keys: ['seed', 'trainer']); the official config.yaml "
                                "has model: with latent_dim, layers, num_heads, ff_size"),
}


@pytest.mark.parametrize("case", sorted(CONFIG_CASES))
def test_config_yaml_errors_name_config_yaml(tmp_path, stats, capsys, case):
    edits, want = CONFIG_CASES[case]
    cfg = _config(tmp_path, "seed: 1\ntrainer:\n  max_epochs: 3") if edits is None else _config(tmp_path, **edits)
    err = _fail(_import(DIFF / "model.pt", tmp_path / "R", stats, "--config", cfg), capsys)
    assert err == f"handx: error: file {cfg}: {want}"


@pytest.mark.parametrize("heads, want", [("-4", "--heads is -4; it must be a whole number >= 1"),
                                         ("3", "--heads 3 does not divide the width 64 (the tensors' shapes): each "
                                               "head takes D / H values")])
def test_heads_flag_errors_name_the_flag(tmp_path, stats, capsys, heads, want):
    err = _fail(_import(DIFF / "model.pt", tmp_path / "R", stats, "--heads", heads), capsys)
    assert err == f"handx: error: {want}"


@pytest.mark.parametrize("bad", ["nan", "zero", "negative"])
def test_stats_with_a_bad_std_is_one_line(tmp_path, stats, capsys, bad):
    std = np.ones((42, 4), np.float32)
    std[1, 2] = {"nan": np.nan, "zero": 0.0, "negative": -1.0}[bad]
    p = tmp_path / "s.npz"
    np.savez(p, mean=np.zeros((42, 4), np.float32), std=std)
    err = _fail(_import(DIFF / "model.pt", tmp_path / "R", p, "--heads", "4"), capsys)
    assert err == (f"handx: error: file {p}: std is zero, negative or not finite at [6] (the motion is divided by it "
                   "without an epsilon)")


# --------------------------------------------------------------------------------------------------
# Evaluator import


def _eval_import(ckpt, out, mean=EVAL / "mean_can_pos.npy", std=EVAL / "std_can_pos.npy"):
    return ["import", "handx-evaluator", ckpt, "--mean", mean, "--std", std, "--encoder", EVAL / "t5", "--out", out]


def test_evaluator_nan_weight_and_text_std_file(tmp_path, capsys):
    sd = tp.load(EVAL / "epoch=269.ckpt")["state_dict"]
    w = sd["motionencoder.seqTransEncoder.layers.0.linear2.weight"].copy()
    w[0, 1] = np.inf
    ckpt = tp.save(tmp_path / "nan.ckpt", {"state_dict": {**sd, "motionencoder.seqTransEncoder.layers.0.linear2."
                                                                     "weight": w}})
    err = _fail(_eval_import(ckpt, tmp_path / "EV"), capsys)
    assert err == (f"handx: error: file {ckpt}: tensor 'motionencoder.seqTransEncoder.layers.0.linear2.weight' holds 1 "
                   "non-finite value(s) (NaN or inf; first at (0, 1)): the weights are broken (a diverged run?) and "
                   "would make every output NaN")
    txt = tmp_path / "std.txt"
    txt.write_text("0.1 0.2 0.3\n")
    err = _fail(_eval_import(EVAL / "epoch=269.ckpt", tmp_path / "EV", std=txt), capsys)
    assert err == (f"handx: error: file {txt}: not a .npy file (it starts with b'0.1 0.'; NumPy array files start "
                   "with b'\\x93NUMPY')")
    assert "allow_pickle" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nan.ckpt", "std.txt"]


# --------------------------------------------------------------------------------------------------
# Bounded reads


class _Expanded:
    """A tensor the test's writer emits as a stride-0 view of a 4-value storage."""


def test_a_stride_0_tensor_is_refused_by_name_before_it_is_materialised(tmp_path, monkeypatch):
    plain = tp._Pickle.save

    def save(self, obj):
        if not isinstance(obj, _Expanded):
            return plain(self, obj)
        key = len(self.storages)
        self.storages.append(np.zeros(4, np.float32))
        self.glob("torch._utils", "_rebuild_tensor_v2")
        self.emit(b"((")
        plain(self, "storage")
        self.glob("torch", "FloatStorage")
        for v in (str(key), "cpu", 4):
            plain(self, v)
        self.emit(b"tQ")
        for v in (0, (200_000, 100_000), (0, 0), False):
            plain(self, v)
        self.glob("collections", "OrderedDict")
        self.emit(b")RtR")

    monkeypatch.setattr(tp._Pickle, "save", save)
    path = tp.save(tmp_path / "expanded.pt", {"state_dict": {"ok": np.ones(3, np.float32), "w": _Expanded()}})
    monkeypatch.undo()
    t0 = time.perf_counter()
    with pytest.raises(Exception) as e:
        tp.load(path)
    assert time.perf_counter() - t0 < 5  # refused, not 80 GB allocated
    assert str(e.value) == (f"file {path}: tensor ['state_dict']['w']: size (200000, 100000) stride (0, 0) "
                            "materialises 76,294 MiB from a storage of 16 bytes (an expansion over 16 MiB); refused "
                            "(a crafted or corrupt file?)")


# --------------------------------------------------------------------------------------------------
# Export: every output checked first, all or nothing


@pytest.fixture(scope="module")
def runs(tmp_path_factory, stats):
    """An imported run, and a copy whose weights hold a NaN (as a diverged run's would)."""
    import shutil

    import jax
    import orbax.checkpoint as ocp

    from handx_jax.interop import official_diffusion as od
    from handx_jax.infra.checksums import write_tree_checksum
    from handx_jax.train import load_params

    root = tmp_path_factory.mktemp("runs")
    od.import_checkpoint(DIFF / "model.pt", root / "run", encoder=DIFF / "t5", heads=4, stats=stats)
    shutil.copytree(root / "run", root / "nan")
    params, _ = load_params(root / "run")
    params = jax.tree_util.tree_map(np.asarray, params)
    params["params"]["layer1"]["ff"]["lin1"]["kernel"] = params["params"]["layer1"]["ff"]["lin1"]["kernel"].copy()
    params["params"]["layer1"]["ff"]["lin1"]["kernel"][0, 0] = np.nan
    state = {"params": params, "opt_state": {}, "ema": {}, "step": np.zeros((), np.int32)}
    shutil.rmtree(root / "nan" / "checkpoints")
    mngr = ocp.CheckpointManager((root / "nan" / "checkpoints").absolute(),
                                 options=ocp.CheckpointManagerOptions(create=True, enable_async_checkpointing=False))
    mngr.save(0, args=ocp.args.StandardSave(state))
    mngr.wait_until_finished()
    mngr.close()
    write_tree_checksum(root / "nan" / "checkpoints" / "0")
    return root


NAN_PARAM = "parameter ['params']['layer1']['ff']['lin1']['kernel'] holds 1 non-finite value(s) (NaN or inf) of " \
            "8192: the weights are broken (a diverged run?) and every output would be NaN"


def test_export_refuses_nan_weights_and_existing_outputs(runs, tmp_path, capsys):
    ck = (runs / "nan" / "checkpoints" / "0").resolve()
    err = _fail(["export", "handx-diffusion", runs / "nan", "--out", tmp_path / "m.pt"], capsys)
    assert err == f"handx: error: file {ck}: {NAN_PARAM}"
    existing = tmp_path / "old.pt"
    existing.write_bytes(b"keep")
    err = _fail(["export", "handx-diffusion", runs / "run", "--out", existing], capsys)
    assert err == f"handx: error: --out {existing} already exists; pass --force (overwrite=True) to replace it"
    assert existing.read_bytes() == b"keep"
    stats_file = tmp_path / "stats"
    stats_file.write_text("x")
    err = _fail(["export", "handx-diffusion", runs / "run", "--out", tmp_path / "a.pt", "--stats", stats_file], capsys)
    assert err == (f"handx: error: --stats {stats_file} is a file; it names the folder to write mean.npy and std.npy "
                   "into")
    (tmp_path / "cfgdir").mkdir()
    err = _fail(["export", "handx-diffusion", runs / "run", "--out", tmp_path / "b.pt", "--config",
                 tmp_path / "cfgdir"], capsys)
    assert err == f"handx: error: --config {tmp_path / 'cfgdir'} is a directory; it names the file to write"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cfgdir", "old.pt", "stats"]  # no model.pt left
    assert list((tmp_path / "cfgdir").iterdir()) == []
    assert main(["export", "handx-diffusion", str(runs / "run"), "--out", str(existing), "--force"]) == 0
    assert tp.load(existing)["state_dict"]
    capsys.readouterr()


def test_generate_with_nan_weights_names_the_parameter_not_the_output(runs, tmp_path, capsys):
    out = tmp_path / "gen.npz"
    rc = main(["generate", "--run", str(runs / "nan"), "--left", "a wave", "--right", "a fist", "--interaction",
               "apart", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    ck = (runs / "nan" / "checkpoints" / "0").resolve()
    assert rc == 2 and err == f"handx generate: error: file {ck}: {NAN_PARAM}"
    assert not out.exists()


# --------------------------------------------------------------------------------------------------
# Faults with real processes: two writers of one --out, kill -9, a full disk


def _handx(*argv, **kw):
    return subprocess.Popen([sys.executable, "-m", "handx_jax", *map(str, argv)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV, **kw)


def test_two_imports_to_one_out_cannot_both_succeed(tmp_path, stats):
    out = tmp_path / "R"
    procs = [_handx(*_import(DIFF / "model.pt", out, stats, "--heads", "4")) for _ in range(2)]
    res = [(p.wait(120), *p.communicate()) for p in procs]
    ok = [r for r in res if r[0] == 0]
    refused = [r for r in res if r[0] != 0]
    assert len(ok) == 1 and len(refused) == 1, res
    assert ok[0][1].startswith(f"wrote {out}: diffusion run")
    rc, _, err = refused[0]
    assert rc == 2 and err.count("\n") == 1, err
    assert err.startswith(f"handx: error: {out} is in use by pid ") or \
        err == f"handx: error: {out} already exists; pass --force (overwrite=True) to replace it\n", err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["R"]  # no lock, no temporary folder left


KILLED_WRITER = textwrap.dedent("""
    import sys, time
    def stall(*a, **k):  # the writer is killed here, half-way through filling its temporary folder
        print("writing", flush=True)
        time.sleep(600)
    if sys.argv[1] == "handx-diffusion":
        import handx_jax.infra.checksums
        handx_jax.infra.checksums.write_tree_checksum = stall  # after orbax wrote the weights
    else:
        import handx_jax.evaluation.checkpoint
        handx_jax.evaluation.checkpoint.write_params_msgpack = stall  # after the T5 folder
    from handx_jax.cli import main
    sys.exit(main(["import", *sys.argv[1:]]))
""")


@pytest.mark.parametrize("what", ["handx-diffusion", "handx-evaluator"])
def test_a_writer_killed_mid_import_leaves_a_temporary_folder_the_next_run_removes(tmp_path, stats, what):
    out = tmp_path / "OUT"
    if what == "handx-diffusion":
        args = [DIFF / "model.pt", "--encoder", DIFF / "t5", "--heads", "4", "--stats", stats, "--out", out]
    else:
        args = _eval_import(EVAL / "epoch=269.ckpt", out)[2:]
    p = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, what, *map(str, args)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=ENV)
    assert p.stdout.readline() == "writing\n", p.stderr.read()
    os.kill(p.pid, signal.SIGKILL)
    p.wait(30)
    left = [x.name for x in tmp_path.iterdir() if x.name.startswith(".OUT.")]
    tmps = [x for x in left if x.endswith(".tmp")]
    assert len(tmps) == 1 and sorted(left) == sorted([".OUT.lock", *tmps]), left  # what kill -9 leaves
    r = subprocess.run([sys.executable, "-m", "handx_jax", "import", what, *map(str, args)], capture_output=True,
                       text=True, env=ENV, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert f"handx: recovering a stale lock on {out} (pid {p.pid} on " in lines[0]
    assert lines[1] == f"handx: removed {tmps[0]} in {tmp_path}: left by a writer of OUT that was killed"
    assert len(lines) == 2, r.stderr
    assert sorted(x.name for x in tmp_path.iterdir()) == ["OUT"]


@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a tmpfs needs root")
def test_import_onto_a_full_disk_is_one_line_without_library_tracebacks(tmp_path, stats, capsys):
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=300k", "tmpfs", str(disk)]).returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    argv = _import(DIFF / "model.pt", disk / "R", stats, "--heads", "4")
    try:
        # the free-space check says it first (in-process) ...
        err = _fail(argv, capsys)
        assert err.startswith(f"handx: error: no space left on device writing {disk / 'R' / 'checkpoints'}; it "
                              "needs 1.0 MB, "), err
        assert os.listdir(disk) == []
        # ... and with the check off, orbax itself hits ENOSPC: what orbax, tensorstore and asyncio print while
        # failing (~110 lines before) is held back, in a process of its own as a user's would be
        code = ("import sys; from handx_jax.infra import diskspace; from handx_jax.cli import main\n"
                "diskspace.check_free_space = lambda *a, **k: None\nsys.exit(main(sys.argv[1:]))")
        r = subprocess.run([sys.executable, "-c", code, *map(str, argv)], capture_output=True, text=True, env=ENV,
                           timeout=120)
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr[-3000:]
        assert r.stderr.startswith(f"handx: error: no space left on device writing {disk / 'R'}, "), r.stderr
        assert os.listdir(disk) == []
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def test_a_record_that_inflates_far_beyond_the_file_is_refused_before_it_is_read(tmp_path):
    import zipfile

    path = tmp_path / "bomb.pt"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("archive/data.pkl", b"\x80\x02}.")  # an empty dict
        zf.writestr("archive/data/0", b"\0" * (64 << 20))  # 64 MiB of zeros: ~64 KB deflated
    with pytest.raises(Exception) as e:
        tp.load(path)
    assert str(e.value).startswith(f"file {path}: its records inflate to 64 MiB (archive/data/0: 64 MiB) from a file "
                                   f"of {path.stat().st_size:,} bytes, past 4x its size + 16 MiB; refused")
