"""The host's cores as several CPU devices for sampling (handx_jax.infra.hostdevices, issue 15).

Each case runs tests/hostdevices_worker.py in a fresh process, because JAX fixes the CPU device count
when it starts: with HANDX_CPU_DEVICES=2 the sampler splits a batch the devices divide over both (and
keeps one device for a batch they do not), and its samples equal one device's up to float rounding (the
same noise draws, per-sample maths on half the rows); AR decoding splits its rows too and gives the same
tokens, greedy and sampled; training stays on one device per process.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
WORKER = str(HERE / "hostdevices_worker.py")


def _env(**kw):
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_NUM_CPU_DEVICES")}
    # the suite's XLA flags (tests/conftest.py) without a device count: the worker sets its own
    flags = " ".join(f for f in os.environ.get("XLA_FLAGS", "").split() if "device_count" not in f)
    env.update({"XLA_FLAGS": flags} if flags else {})
    return {**env, "PYTHONPATH": str(HERE.parent), "JAX_PLATFORMS": "cpu", "WANDB_MODE": "disabled", **kw}


def test_split_sampling_matches_one_device(tmp_path):
    import jax

    from handx_jax.infra import hostdevices

    p = subprocess.run([sys.executable, WORKER, str(tmp_path / "two.npz"), str(tmp_path / "one.npz")],
                       env=_env(HANDX_CPU_DEVICES="2"), capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    info = json.loads(p.stdout.strip().splitlines()[-1])
    # two devices: batch 4 split in two, batch 3 (odd) on one device (its sampler is the plain one-device
    # program, not run: the reference pass runs that program); training on one device (train._mesh);
    # the reference pass (hostdevices' one-device answer, no mesh) splits nothing
    assert info == {"configured": 2, "devices": 2, "train_mesh": 1, "sample_devices": {"4": 2, "3": 1, "ar": 2},
                    "reference_devices": {"4": 1, "3": 1, "ar": 1}}
    # ... which is what this one-device process gets for every batch
    assert jax.device_count() == 1 and all(hostdevices.inference_mesh(b) is None for b in (3, 4))
    two, one = dict(np.load(tmp_path / "two.npz")), dict(np.load(tmp_path / "one.npz"))
    assert sorted(one) == sorted(two)
    # AR decoding: the same tokens, greedy and sampled (each row draws with its own key)
    assert not np.array_equal(one["ar_temperature"], one["ar_greedy"])  # sampling really sampled
    for k in [k for k in one if k.startswith("ar_")]:
        np.testing.assert_array_equal(two.pop(k), one.pop(k), err_msg=k)
    assert sorted(one) == ["guided_4", "unguided_4"]
    for k in one:
        assert np.abs(one[k]).max() > 0.1  # real samples, not zeros
        np.testing.assert_allclose(two[k], one[k], atol=2e-5, err_msg=k)
    assert not np.allclose(one["guided_4"], one["unguided_4"], atol=1e-3)  # guidance reached both paths


def test_bad_device_count_is_one_clear_line(tmp_path):
    for bad in ("0", "two"):
        p = subprocess.run([sys.executable, "-m", "handx_jax", "params", "diffusion", "--preset", "tiny"],
                           env=_env(HANDX_CPU_DEVICES=bad), capture_output=True, text=True, timeout=120)
        assert p.returncode == 2, p.stderr
        assert f"HANDX_CPU_DEVICES={bad!r}" in p.stderr and "Traceback" not in p.stderr


def test_configure_respects_the_users_choice(monkeypatch):
    from handx_jax.infra import hostdevices as H

    monkeypatch.delenv(H.ENV, raising=False)
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=3")
    assert H.configure() is None  # XLA_FLAGS names a count: left alone
    monkeypatch.delenv("XLA_FLAGS")
    monkeypatch.setenv("JAX_NUM_CPU_DEVICES", "3")
    assert H.configure() is None  # set for JAX directly: left alone
    monkeypatch.delenv("JAX_NUM_CPU_DEVICES")
    import jax

    jax.devices()  # this pytest process's backends are running: too late to change, so nothing changes
    assert H.configure() is None
    monkeypatch.setenv(H.ENV, "5")
    assert H.default_count() == 5
    monkeypatch.delenv(H.ENV)
    assert 1 <= H.default_count() <= H.MAX_DEFAULT
    with pytest.raises(ValueError, match="HANDX_CPU_DEVICES='-1'"):
        monkeypatch.setenv(H.ENV, "-1")
        H.default_count()
