"""Damaged and crafted files given to the project's one reader (``handx_jax/infra/readers.py``, issue 54) and to the
readers routed through it: every failure is one ``DataError`` naming the file and, where there is one, the
field; none suggests unpickling (NumPy's own message says to load with ``allow_pickle``), and no crafted file
runs code. Plain files, no model: milliseconds each."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from handx_jax.infra.readers import get_field, read_json, read_npy, read_npz, require_dir
from handx_jax.infra.errors import DataError


def _err(fn, *a, **kw) -> str:
    with pytest.raises(DataError) as e:
        fn(*a, **kw)
    msg = str(e.value)
    assert "allow_pickle" not in msg and "pickle.load" not in msg and "\n" not in msg, msg
    return msg


class _Canary:  # a pickle that would create a file if anything unpickled it
    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


def test_npz_missing_keys_wrong_dtypes_object_arrays_and_garbage(tmp_path):
    p = tmp_path / "n.npz"
    np.savez(p, mean=np.ones(3, np.float32), count=np.arange(3))
    assert read_npz(p, keys=("mean",), kind="f")["mean"].tolist() == [1.0, 1.0, 1.0]
    assert _err(read_npz, p, keys=("mean", "std")) == f"file {p}, field 'std': missing (the archive holds count, mean)"
    assert _err(read_npz, p, keys=("count",), kind="f") == \
        f"file {p}, field 'count': dtype int64; expected floating-point numbers"
    canary = tmp_path / "ran"
    obj = tmp_path / "o.npz"
    np.savez(obj, mean=np.array([_Canary(str(canary))], dtype=object))
    assert _err(read_npz, obj).startswith(f"file {obj}, field 'mean': holds Python objects (dtype object), not numbers")
    assert not canary.exists()
    bad = tmp_path / "nan.npz"
    np.savez(bad, std=np.array([1.0, np.nan]))
    assert _err(read_npz, bad, finite=True) == f"file {bad}, field 'std': holds 1 non-finite value(s) (NaN or inf) of 2"
    g = tmp_path / "g.npz"
    g.write_text("garbage")
    assert _err(read_npz, g).startswith(f"file {g}: not a .npz file (it starts with b'garbag'")
    t = tmp_path / "t.npz"
    t.write_bytes(p.read_bytes()[:200])
    assert _err(read_npz, t).startswith(f"file {t}: corrupt or truncated .npz archive")
    assert _err(read_npz, tmp_path / "absent.npz") == f"file {tmp_path}: missing absent.npz"
    assert _err(read_npz, tmp_path) == f"file {tmp_path}: is a folder, not a file"


def test_npy_truncated_objects_and_dimensions(tmp_path):
    p = tmp_path / "a.npy"
    np.save(p, np.ones((2, 3), np.float32))
    assert read_npy(p, kind="f", ndim=2, mmap=True).shape == (2, 3)
    assert _err(read_npy, p, ndim=5) == f"file {p}: has 2 dimension(s) (shape (2, 3)); expected 5"
    t = tmp_path / "t.npy"
    t.write_bytes(p.read_bytes()[:-4])
    assert _err(read_npy, t).startswith(f"file {t}: corrupt or truncated array")
    assert _err(read_npy, t, mmap=True).startswith(f"file {t}: corrupt or truncated array")
    o = tmp_path / "o.npy"
    np.save(o, np.array([{}], dtype=object), allow_pickle=True)
    assert _err(read_npy, o).startswith(f"file {o}: holds Python objects (dtype object)")
    txt = tmp_path / "x.npy"
    txt.write_text("0.1 0.2")
    assert _err(read_npy, txt) == f"file {txt}: not a .npy file (it starts with b'0.1 0.'; NumPy array files start " \
                                  "with b'\\x93NUMPY')"


@pytest.mark.parametrize("text, words", [
    ("[]", "expected an object ({...}) at the top level, found a list ([...])"),
    ('"x"', "expected an object ({...}) at the top level, found a string"),
    ('{"a": [1,', "corrupt JSON (Expecting value at line 1 column 10: truncated or damaged)"),
    ("", "empty"),
])
def test_json_of_the_wrong_shape_or_truncated(tmp_path, text, words):
    p = tmp_path / "doc.json"
    p.write_text(text)
    assert _err(read_json, p, expect=dict) == f"file {p}: {words}"


def test_json_fields_binary_files_defaults_and_symlink_loops(tmp_path):
    p = tmp_path / "meta.json"
    p.write_text(json.dumps({"num_clips": True, "text": {"eval_level": 2}, "n": 3}))
    doc = read_json(p, expect=dict)
    assert get_field(doc, "text.eval_level", int, path=p) == 2
    assert _err(get_field, doc, "num_clips", int, path=p) == \
        f"file {p}, field 'num_clips': expected an integer, found true or false true"
    assert _err(get_field, doc, "text.level", int, path=p) == \
        f"file {p}, field 'text.level': missing (the object 'text' holds eval_level)"
    assert _err(get_field, doc, "n", int, path=p, check=lambda v: v >= 5, must="at least 5") == \
        f"file {p}, field 'n': is 3; it must be at least 5"
    b = tmp_path / "b.json"
    b.write_bytes(b"\x80\x81\xff")
    assert _err(read_json, b) == f"file {b}: not a JSON file (its bytes are not UTF-8 text)"
    assert read_json(tmp_path / "absent.json", expect=dict, default={}) == {}
    loop = tmp_path / "loop"
    os.symlink(loop, loop)
    words = "is a symlink loop (a link that points back to itself); point it at a real file or folder"
    assert _err(read_json, loop) == f"file {loop}: {words}"
    assert _err(read_npz, loop) == f"file {loop}: {words}"
    assert _err(require_dir, loop, "dataset directory") == f"file {loop}: dataset directory {words}"
    dangling = tmp_path / "dangling"
    os.symlink(tmp_path / "gone", dangling)
    assert _err(require_dir, dangling, "run folder") == f"file {dangling}: run folder is a symlink to " \
                                                        f"{tmp_path / 'gone'}, which does not exist"


@pytest.mark.parametrize("case", ["garbage", "no_std", "objects", "shape"])
def test_ghtt_norm_file_is_named(tmp_path, case):
    from handx_jax.families.ghtt.common import NORM_FILE, Norm

    p = tmp_path / NORM_FILE
    if case == "garbage":
        p.write_text("garbage")
    elif case == "no_std":
        np.savez(p, mean=np.zeros(153, np.float32))
    elif case == "objects":
        np.savez(p, mean=np.zeros(153, np.float32), std=np.array([None], dtype=object))
    else:
        np.savez(p, mean=np.zeros(153, np.float32), std=np.ones(12, np.float32))
    words = {"garbage": f"file {p}: not a .npz file (it starts with b'garbag'",
             "no_std": f"file {p}, field 'std': missing (the archive holds mean)",
             "objects": f"file {p}, field 'std': holds Python objects",
             "shape": f"file {p}, field 'std': shape (12,); a G-HTT frame has 153 values"}[case]
    assert _err(Norm.load, tmp_path).startswith(words)


def test_an_evaluator_norm_stats_of_object_arrays_is_named(tmp_path):
    from handx_jax import standard
    from handx_jax.evaluation.checkpoint import STATS_FILE, evaluator_id

    src = standard.evaluator_dir(standard.assets_folder())
    ev = tmp_path / "EV"
    shutil.copytree(src, ev)
    np.savez(ev / STATS_FILE, evaluator_mean=np.array([None], dtype=object), evaluator_std=np.ones(3))
    assert _err(evaluator_id, ev).startswith(f"file {ev / STATS_FILE}, field 'evaluator_mean': holds Python objects")


def test_an_object_array_npz_as_stats_is_named(tmp_path, capsys):
    from handx_jax.cli import main

    diff = Path(__file__).parent / "fixtures" / "official_diffusion"
    obj = tmp_path / "stats.npz"
    np.savez(obj, mean=np.array([None] * 168, dtype=object), std=np.ones(168, np.float32))
    rc = main(["import", "handx-diffusion", str(diff / "model.pt"), "--encoder", str(diff / "t5"), "--stats", str(obj),
               "--out", str(tmp_path / "R"), "--heads", "4"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith(f"handx: error: file {obj}, field 'mean': holds Python objects") and \
        "allow_pickle" not in err
    assert not (tmp_path / "R").exists()
