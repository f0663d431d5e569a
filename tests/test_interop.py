"""handx_jax.interop: PyTorch checkpoints read and written without PyTorch, the official HandX diffusion
model and evaluator imported (parity with the official code's outputs), a run exported back.

The parity oracles are tests/fixtures/official_{diffusion,evaluator}/ (copies of
shared/reference/official_*_case/): checkpoints written by the official PyTorch code and its outputs.
"""

from __future__ import annotations

import dataclasses
import io
import os
import pickle
import sys
import types
import zipfile
from pathlib import Path

import ml_dtypes
import numpy as np
import pytest

from handx_jax.interop import torch_pickle as tp
from handx_jax.infra.errors import DataError

FIX = Path(__file__).parent / "fixtures"
DIFF, EVAL = FIX / "official_diffusion", FIX / "official_evaluator"


# --------------------------------------------------------------------------------------------------
# The reader and writer


def _tree_equal(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return (isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
                and a.tobytes() == b.tobytes())
    if isinstance(a, dict):
        return isinstance(b, dict) and list(a) == list(b) and all(_tree_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(_tree_equal(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def test_writer_reader_round_trip_dtypes_shapes_containers(tmp_path):
    rng = np.random.default_rng(0)
    obj = {
        "state_dict": {
            "f32": rng.normal(size=(2, 3, 4)).astype(np.float32),
            "f32_transposed": np.asarray(rng.normal(size=(3, 5)).astype(np.float32).T),  # written contiguous
            "f64": rng.normal(size=(7,)), "f16": rng.normal(size=(3, 1)).astype(np.float16),
            "bf16": rng.normal(size=(4,)).astype(ml_dtypes.bfloat16),
            "i64": np.array(12345678901, np.int64), "i32": np.arange(6, dtype=np.int32).reshape(2, 3),
            "i8": np.array([-3, 4], np.int8), "u8": np.array([0, 255], np.uint8), "bool": np.array([True, False]),
            "empty": np.zeros((0, 3), np.float32),
        },
        "nested": [1, 2 ** 40, -7, 3.25, None, True, "text é", (1, "a", [np.float32(2.5)])],
        "epoch": 269,
    }
    path = tp.save(tmp_path / "x.pt", obj)
    back = tp.load(path)
    want = {**obj, "nested": [1, 2 ** 40, -7, 3.25, None, True, "text é", (1, "a", [2.5])]}
    assert _tree_equal(back, want)
    assert tp.dumps(obj) == path.read_bytes()  # deterministic bytes
    with zipfile.ZipFile(path) as zf:  # PyTorch's layout: one folder, records aligned to 64 bytes
        names = zf.namelist()
        assert names[0] == "archive/data.pkl" and "archive/byteorder" in names and "archive/version" in names
        for info in zf.infolist():
            start = info.header_offset + 30 + len(info.filename) + len(info.extra)
            assert start % 64 == 0, info.filename
    with pytest.raises(TypeError):
        tp.dumps({"bad": object()})


def _fake_modules(monkeypatch):
    """``torch``/``omegaconf``/``tma`` stand-ins in sys.modules, so the test can pickle what a real
    checkpoint names with the ordinary pickle module (which imports each global to name it)."""
    def mod(name, **attrs):
        for i in range(1, name.count(".") + 1):  # parent packages, so pickle can import the module
            parent = name.rsplit(".", i)[0]
            if parent not in sys.modules:
                monkeypatch.setitem(sys.modules, parent, types.ModuleType(parent))
        m = types.ModuleType(name)
        for k, v in attrs.items():
            setattr(m, k, v)
            if callable(v):
                v.__module__, v.__qualname__ = name, k
        monkeypatch.setitem(sys.modules, name, m)
        return m

    class FloatStorage:
        pass

    class QUInt8Storage:
        pass

    def _rebuild_tensor_v2(*args):
        raise AssertionError("never called when pickling")

    class DictConfig:
        def __init__(self, content):  # pickled as omegaconf's are: NEWOBJ, then BUILD with the state
            self._content = content

    def tma_collate_interact(batch):
        return batch

    torch = mod("torch", FloatStorage=FloatStorage, QUInt8Storage=QUInt8Storage)
    utils = mod("torch._utils", _rebuild_tensor_v2=_rebuild_tensor_v2)
    oc = mod("omegaconf.dictconfig", DictConfig=DictConfig)
    tma = mod("tma.data.utils", tma_collate_interact=tma_collate_interact)
    return types.SimpleNamespace(torch=torch, utils=utils, DictConfig=oc.DictConfig, collate=tma.tma_collate_interact)


def _craft(tmp_path, obj, storages: dict[str, bytes], *, byteorder=b"little", name="crafted.pt") -> Path:
    """A torch-layout zip whose data.pkl is ``pickle.dumps(obj)``; ``("storage", cls, key, loc, n)`` tuples
    wrapped in ``_Pid`` become persistent ids."""
    class P(pickle.Pickler):
        def persistent_id(self, o):
            return o.pid if isinstance(o, _Pid) else None

    buf = io.BytesIO()
    P(buf, protocol=2).dump(obj)
    path = tmp_path / name
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("archive/data.pkl", buf.getvalue())
        zf.writestr("archive/byteorder", byteorder)
        for k, v in storages.items():
            zf.writestr(f"archive/data/{k}", v)
    return path


class _Pid:
    def __init__(self, *pid):
        self.pid = pid


class _Tensor:
    """Pickles as _rebuild_tensor_v2(storage, offset, size, stride, False, OrderedDict())."""

    def __init__(self, fake, storage_cls, key, numel, offset, size, stride):
        self.args = (_Pid("storage", storage_cls, key, "cpu", numel), offset, size, stride, False, {})
        self.fn = fake.utils._rebuild_tensor_v2

    def __reduce__(self):
        return (self.fn, self.args)


def test_reader_strided_views_placeholders_and_shared_storage(tmp_path, monkeypatch):
    fake = _fake_modules(monkeypatch)
    base = np.arange(12, dtype=np.float32)
    obj = {
        "state_dict": {
            # a transposed (3, 4) view and an offset slice of the same storage
            "t": _Tensor(fake, fake.torch.FloatStorage, "0", 12, 0, (4, 3), (1, 4)),
            "tail": _Tensor(fake, fake.torch.FloatStorage, "0", 12, 8, (4,), (1,)),
        },
        "datamodule_hyper_parameters": {"cfg": fake.DictConfig({"model": {"num_head": 6}}),
                                        "collate_fn": fake.collate, "mean": np.ones((42, 3))},
    }
    path = _craft(tmp_path, obj, {"0": base.tobytes()})
    back = tp.load(path)
    np.testing.assert_array_equal(back["state_dict"]["t"], base.reshape(3, 4).T)
    np.testing.assert_array_equal(back["state_dict"]["tail"], base[8:])
    hp = back["datamodule_hyper_parameters"]
    assert tp.inert_name(hp["cfg"]) == "omegaconf.dictconfig.DictConfig"
    assert hp["cfg"].state == {"_content": {"model": {"num_head": 6}}}  # kept, inert
    assert tp.inert_name(hp["collate_fn"]) == "tma.data.utils.tma_collate_interact"
    np.testing.assert_array_equal(hp["mean"], np.ones((42, 3)))  # NumPy's own reconstructors


def test_crafted_pickle_is_refused_and_nothing_runs(tmp_path):
    marker = tmp_path / "ran"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    path = _craft(tmp_path, {"state_dict": Evil()}, {})
    with pytest.raises(DataError) as e:
        tp.load(path)
    msg = str(e.value)
    assert str(path) in msg and "system" in msg and "nothing was run" in msg and "\n" not in msg
    assert not marker.exists()

    class Evil2:
        def __reduce__(self):
            return (eval, ("1",))

    with pytest.raises(DataError, match=r"__builtin__\.eval"):  # protocol 2 names builtins so
        tp.load(_craft(tmp_path, [Evil2()], {}, name="evil2.pt"))


def test_refusals_name_the_file(tmp_path, monkeypatch):
    fake = _fake_modules(monkeypatch)
    good = (DIFF / "model.pt").read_bytes()
    cut = tmp_path / "truncated.pt"
    cut.write_bytes(good[: len(good) // 2])
    short = _craft(tmp_path, {"w": _Tensor(fake, fake.torch.FloatStorage, "0", 12, 0, (12,), (1,))},
                   {"0": b"\0" * 20}, name="short.pt")
    unknown = _craft(tmp_path, {"w": _Tensor(fake, fake.torch.QUInt8Storage, "0", 4, 0, (4,), (1,))},
                     {"0": b"\0" * 4}, name="quint.pt")
    big = _craft(tmp_path, {"w": 1}, {}, byteorder=b"big", name="big.pt")
    legacy = tmp_path / "legacy.pt"
    legacy.write_bytes(pickle.dumps({"a": 1}, protocol=2))
    cases = {cut: "truncated", short: "truncated", unknown: "unknown storage type torch.QUInt8Storage",
             big: "big-endian", legacy: "legacy"}
    for path, what in cases.items():
        with pytest.raises(DataError) as e:
            tp.load(path)
        assert str(path) in str(e.value) and what in str(e.value), str(e.value)


def test_lightning_checkpoint_reads_inert_and_counts_match():
    """The official evaluator checkpoint: hyper-parameters stay inert; the parameter counts Lightning's
    BaseModel stored equal those of the state dict's tensors, counted here independently."""
    ck = tp.load(EVAL / "epoch=269.ckpt")
    assert ck["epoch"] == 269 and ck["global_step"] == 270
    sd = ck["state_dict"]
    assert len(sd) == 143
    shared = sd["textencoder.text_model.shared.weight"]
    np.testing.assert_array_equal(shared, sd["textencoder.text_model.encoder.embed_tokens.weight"])
    dm = ck["datamodule_hyper_parameters"]
    assert tp.inert_name(dm["cfg"]) == "omegaconf.dictconfig.DictConfig"
    assert tp.inert_name(dm["collate_fn"]) == "tma.data.utils.tma_collate_interact"
    assert dm["mean"].shape == (42, 3) and dm["mean"].dtype == np.float32 and isinstance(dm["phase"], str)
    # trainable: every tensor but the frozen T5 (its tied embedding once), the pe buffers and the loss sums
    frozen = sum(v.size for k, v in sd.items() if k.startswith("textencoder.text_model.")
                 and k != "textencoder.text_model.encoder.embed_tokens.weight")
    trainable = sum(v.size for k, v in sd.items() if not k.startswith(("textencoder.text_model.", "_losses."))
                    and not k.endswith("sequence_pos_encoding.pe"))
    hp = ck["hyper_parameters"]
    assert (int(hp["n_params_trainable"]), int(hp["n_params_nontrainable"])) == (trainable, frozen)


# --------------------------------------------------------------------------------------------------
# Diffusion: import, parity, export


def _official_code_t5(folder):
    """The T5 the official model class conditions on: the folder's, with every Linear layer redrawn
    N(0, 0.02) by the class's init pass (reference §3.1, §9.7; the draws are not stored). In the tiny T5
    those layers add less than 1e-5 to the denoiser's output (any seed of the draws is within 7e-6 of the
    case), so they are set to zero here: T5 then returns its final norm of the token embeddings."""
    import jax

    from handx_jax.text.hf import load_hf_t5_encoder
    from handx_jax.text.t5 import FrozenEncoder

    enc = load_hf_t5_encoder(folder)
    params = jax.tree_util.tree_map_with_path(
        lambda p, a: np.zeros_like(a) if "kernel" in jax.tree_util.keystr(p) else a, enc.params)
    return enc, FrozenEncoder(enc.cfg, params, enc.tokenizer)


@pytest.fixture(scope="module")
def imported_diffusion(tmp_path_factory):
    from handx_jax.interop import official_diffusion as od

    root = tmp_path_factory.mktemp("official_diffusion")
    np.savez(root / "stats.npz", mean=np.zeros((42, 4), np.float32), std=np.ones((42, 4), np.float32))
    pretrained, official_t5 = _official_code_t5(DIFF / "t5")
    summary = od.import_checkpoint(DIFF / "model.pt", root / "run", encoder=official_t5,
                                   config=DIFF / "config.yaml", stats=root / "stats.npz")
    return types.SimpleNamespace(root=root, run=root / "run", summary=summary, pretrained=pretrained,
                                 official_t5=official_t5)


def test_diffusion_parity_with_the_official_model(imported_diffusion):
    from handx_jax.families import get_family
    from handx_jax.interop import official

    d = imported_diffusion
    assert d.summary["model"]["heads"] == 4 and d.summary["model"]["layers"] == 2
    run = get_family("diffusion").load(d.run, encoder=d.official_t5)
    case = np.load(DIFF / "case.npz")
    args = (case["x_BxJxFxT"], case["t"], case["left"], case["right"], case["interaction"])
    out = official.denoise(run, *args)
    assert out.shape == case["out_BxJxFxT"].shape
    err = np.abs(out - case["out_BxJxFxT"]).max()
    assert err <= 1e-4, err
    # With the folder's pretrained Linear layers the text features are another function: the gap is the size
    # of the whole text path (what the official init pass changes; the release was trained that way).
    other = official.denoise(dataclasses.replace(run, encoder=d.pretrained), *args)
    assert np.abs(other - case["out_BxJxFxT"]).max() > 1e-3


def test_diffusion_import_records_source_and_refuses_bad_input(imported_diffusion, tmp_path):
    import json

    from handx_jax.interop import official_diffusion as od
    from handx_jax.interop.official_diffusion import sha256

    doc = json.loads((imported_diffusion.run / "config.json").read_text())
    assert doc["family"] == "diffusion" and doc["source"]["sha256"] == sha256(DIFF / "model.pt")
    assert "CC-BY-NC-4.0" in doc["source"]["licence"] and doc["params"] == imported_diffusion.summary["params"]
    stats = imported_diffusion.root / "stats.npz"
    with pytest.raises(DataError, match="number of heads"):
        od.import_checkpoint(DIFF / "model.pt", tmp_path / "r1", encoder=imported_diffusion.official_t5, stats=stats)
    bad = tmp_path / "config.yaml"
    bad.write_text((DIFF / "config.yaml").read_text().replace("layers: 2", "layers: 3"))
    with pytest.raises(DataError, match="model.layers is 3 but the checkpoint's tensors have 2"):
        od.import_checkpoint(DIFF / "model.pt", tmp_path / "r2", encoder=imported_diffusion.official_t5,
                             config=bad, stats=stats)
    assert not (tmp_path / "r1").exists() and not (tmp_path / "r2").exists()


def test_export_round_trip_bit_for_bit(imported_diffusion, tmp_path):
    from handx_jax.interop import official_diffusion as od
    from handx_jax.train import load_params

    d = imported_diffusion
    s = od.export_run(d.run, tmp_path / "model.pt", config=tmp_path / "config.yaml", stats=tmp_path / "stats")
    assert any("normalisation statistics" in x for x in s["dropped"])
    exported, original = od.read_state_dict(tmp_path / "model.pt"), od.read_state_dict(DIFF / "model.pt")
    assert list(exported) == list(original)  # the official names, in the official order
    for k, v in original.items():
        if k in od.PE_NAMES:  # ours (float64 rounded) vs PyTorch's float32 table
            assert np.abs(exported[k] - v).max() < 5e-4
        else:
            assert exported[k].tobytes() == v.tobytes(), k
    assert od.read_config_yaml(tmp_path / "config.yaml") == {**od.read_config_yaml(DIFF / "config.yaml"),
                                                             "max_text_length": None}
    np.testing.assert_array_equal(np.load(tmp_path / "stats" / "std.npy"), np.ones((42, 4), np.float32))
    od.import_checkpoint(tmp_path / "model.pt", tmp_path / "again", encoder=d.official_t5,
                         config=tmp_path / "config.yaml", stats=d.root / "stats.npz")
    a, _ = load_params(d.run)
    b, _ = load_params(tmp_path / "again")
    import jax

    same = jax.tree_util.tree_map(lambda x, y: np.asarray(x).tobytes() == np.asarray(y).tobytes(), a, b)
    assert all(jax.tree_util.tree_leaves(same))


def test_cli_import_export_diffusion(imported_diffusion, tmp_path, capsys):
    from handx_jax.cli import main

    rc = main(["import", "handx-diffusion", str(DIFF / "model.pt"), "--encoder", str(DIFF / "t5"), "--heads", "4",
               "--stats", str(imported_diffusion.root / "stats.npz"), "--out", str(tmp_path / "run")])
    assert rc == 0 and "L2 d64 H4 FF128" in capsys.readouterr().out
    # the imported run samples through the family's own path (handx generate): DDIM + guidance, a masked task
    from handx_jax.families import get_family
    from handx_jax.families.diffusion.sampling import SampleOptions
    from handx_jax.generation import Prompt

    run = get_family("diffusion").load(tmp_path / "run")
    prompts = [Prompt("The index finger curls.", "Fingers spread.", "Both hands move apart.")] * 2
    opts = SampleOptions(sampler="ddim", steps=2, guidance=2.5, batch_size=2)
    joints = run.generate(prompts, opts, samples=1)
    assert joints.shape == (2, 1, 60, 2, 21, 3) and np.isfinite(joints).all()
    assert np.abs(joints[0] - joints[1]).max() > 1e-3  # each row its own noise
    np.testing.assert_array_equal(run.generate(prompts, opts, samples=1), joints)  # same seed, same numbers
    rc = main(["export", "handx-diffusion", str(tmp_path / "run"), "--out", str(tmp_path / "m.pt")])
    assert rc == 0 and "not in the official checkpoint format" in capsys.readouterr().out
    rc = main(["import", "handx-diffusion", str(tmp_path / "m.pt"), "--encoder", str(DIFF / "t5"),
               "--stats", str(imported_diffusion.root / "stats.npz"), "--out", str(tmp_path / "run2")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "m.pt" in err and "--heads" in err


# --------------------------------------------------------------------------------------------------
# Evaluator: import, parity, the metrics of the case


@pytest.fixture(scope="module")
def imported_evaluator(tmp_path_factory):
    from handx_jax.interop import official_evaluator as oe

    out = tmp_path_factory.mktemp("official_evaluator") / "ev"
    oe.import_checkpoint(EVAL / "epoch=269.ckpt", out, mean=EVAL / "mean_can_pos.npy", std=EVAL / "std_can_pos.npy",
                         encoder=EVAL / "t5")
    return out


def test_evaluator_parity_and_metrics(imported_evaluator):
    import jax.numpy as jnp

    from handx_jax import metrics
    from handx_jax.evaluation import load_evaluator
    from handx_jax.interop import official

    case = np.load(EVAL / "case.npz")
    ev = load_evaluator(imported_evaluator)
    text_mu, motion_mu = official.embed(ev, case["motions"], case["left"], case["right"], case["interaction"])
    assert np.abs(text_mu - case["text_mu"]).max() <= 1e-4
    assert np.abs(motion_mu - case["motion_mu"]).max() <= 1e-4
    # `handx eval run` embeds prompts through the text policy: the official caption string
    np.testing.assert_array_equal(ev.embed_text(case["left"], case["right"], case["interaction"]), text_mu)
    n = len(text_mu)
    rp, mm = metrics.r_precision(jnp.asarray(text_mu), jnp.asarray(motion_mu), block=n)
    np.testing.assert_array_equal(np.asarray(rp), case["r_precision"])
    assert abs(float(mm) - float(case["mm_dist"])) < 1e-4
    for g in range(case["pred_motions"].shape[0]):
        pred_mu = ev.embed_motion(case["pred_motions"][g])
        assert np.abs(pred_mu - case["pred_motion_mu"][g]).max() <= 1e-4
        rp, mm = metrics.r_precision(jnp.asarray(text_mu), jnp.asarray(pred_mu), block=n)
        np.testing.assert_array_equal(np.asarray(rp), case["pred_r_precision"][g])
        assert abs(float(mm) - float(case["pred_mm_dist"][g])) < 1e-4


def test_cli_import_evaluator_refuses_bad_statistics(tmp_path, capsys):
    from handx_jax.cli import main

    std = tmp_path / "std.npy"
    s = np.load(EVAL / "std_can_pos.npy").copy()
    s[5] = 0
    np.save(std, s)
    rc = main(["import", "handx-evaluator", str(EVAL / "epoch=269.ckpt"), "--mean", str(EVAL / "mean_can_pos.npy"),
               "--std", str(std), "--encoder", str(EVAL / "t5"), "--out", str(tmp_path / "ev")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and str(std) in err and "[5]" in err
    assert not (tmp_path / "ev").exists()
