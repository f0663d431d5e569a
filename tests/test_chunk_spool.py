"""A corpus build killed midway resumes from its chunk spool (dataset/chunk_spool.py) and writes the same bytes as a
build made in one go; a spool of another recipe is refused in one line; chunks round-trip exactly, with no pickle."""

import collections
import dataclasses
import json
import os

import numpy as np
import pytest

import handx_jax.dataset.build as build
from handx_jax.cli import main as handx
from handx_jax.dataset.build import BuildConfig, build_corpus
from handx_jax.dataset.chunk_spool import ChunkSpool
from handx_jax.dataset.clips import ClipReport
from handx_jax.dataset.format import Dataset
from handx_jax.synthesis.bimanual import SynthConfig

# 8 sequences a chunk, so 60 clips take several chunks (the default 64 make 160 clips in one).
CFG = BuildConfig(clips=60, seed=5, workers=1, val_fraction=0.2, test_fraction=0.2,
                  synth=SynthConfig(chunk_size=8))


class Killed(BaseException):
    """What a kill looks like from inside the loop: nothing after it runs (BaseException: no handler catches it)."""


def _killing_after(k, real):
    def chunk(cfg, i):
        if i >= k:
            raise Killed
        return real(cfg, i)
    return chunk


def _files(root):
    return {p: (root / p).read_bytes() for p in sorted(os.listdir(root)) if p not in ("meta.json", "report.json")}  # their timings differ


def test_a_killed_build_resumes_from_its_spool_and_writes_the_same_corpus(tmp_path, monkeypatch):
    whole = build_corpus(tmp_path / "whole", CFG, progress=False, stats=False)
    chunks = Dataset.open(whole).report["chunks"]
    assert chunks >= 3

    out = tmp_path / "ds"
    real = build.process_chunk
    monkeypatch.setattr(build, "process_chunk", _killing_after(2, real))
    with pytest.raises(Killed):
        build_corpus(out, CFG, progress=False, stats=False)
    spool = tmp_path / ".ds.chunks"
    assert not out.exists() and sorted(os.listdir(spool)) == ["chunk-0000000.npz", "chunk-0000001.npz", "recipe.json"]

    computed = []
    monkeypatch.setattr(build, "process_chunk", lambda cfg, i: computed.append(i) or real(cfg, i))
    build_corpus(out, CFG, progress=False, stats=False)
    assert computed[:1] == [2] and len(computed) == chunks - 2  # chunks 0 and 1 were read back, not computed
    assert not spool.exists()  # removed once the dataset is written
    a, b = Dataset.open(whole), Dataset.open(out)
    assert a.fingerprint == b.fingerprint and a.meta["recipe"] == b.meta["recipe"]
    assert _files(whole) == _files(out)  # motion, texts, events and splits byte for byte
    rep_a, rep_b = a.report, b.report
    assert (rep_a["chunks_resumed"], rep_b["chunks_resumed"]) == (0, 2)
    assert rep_a["clips"] == rep_b["clips"] and rep_a["program_counts"] == rep_b["program_counts"]


def test_a_spool_of_another_recipe_is_refused_in_one_line_and_force_discards_it(tmp_path, monkeypatch, capsys):
    out = tmp_path / "ds"
    monkeypatch.setattr(build, "process_chunk", _killing_after(1, build.process_chunk))
    with pytest.raises(Killed):
        build_corpus(out, dataclasses.replace(CFG, seed=6), progress=False, stats=False)
    monkeypatch.undo()
    spool = tmp_path / ".ds.chunks"
    before = {p: (spool / p).read_bytes() for p in os.listdir(spool)}
    rc = handx(["data", "synth", "--clips", "60", "--seed", "5", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1, err
    assert str(spool) in err and "another recipe (seed 6" in err and "--force" in err
    assert {p: (spool / p).read_bytes() for p in os.listdir(spool)} == before and not out.exists()  # nothing lost
    # --force (overwrite) starts the other recipe afresh
    sp = ChunkSpool(out, {"kind": "synth", "seed": 5}, (), discard_other=True)
    assert os.listdir(spool) == ["recipe.json"] and sp.load(0) is None


@dataclasses.dataclass
class _Inner:
    counts: collections.Counter
    x: np.ndarray


@dataclasses.dataclass
class _Result:
    chunk_index: int
    arrays: dict
    rows: list
    inner: _Inner
    pair: tuple
    scale: np.float32


def test_a_chunk_reads_back_exactly_and_without_pickle(tmp_path):
    r = _Result(3, {"a": np.arange(6, dtype=np.float16).reshape(2, 3), "b": np.array([1e-8, np.pi], np.float64)},
                [{"id": "c-1", "v": [1.5, None, True]}, {"id": "c-2", "v": []}],
                _Inner(collections.Counter({"nan": 2, "jump": 1}), np.full((2, 2), -1, np.int8)),
                (0.1, "x"), np.float32(1 / 3))
    sp = ChunkSpool(tmp_path / "out", {"kind": "test"}, (_Result, _Inner))
    sp.save(3, r)
    back = sp.load(3)
    assert type(back) is _Result and type(back.inner) is _Inner and isinstance(back.inner.counts, collections.Counter)
    assert back.inner.counts == r.inner.counts and back.rows == r.rows and back.pair == r.pair
    assert back.scale == r.scale and back.scale.dtype == np.float32
    for k in r.arrays:
        assert back.arrays[k].dtype == r.arrays[k].dtype
        np.testing.assert_array_equal(back.arrays[k], r.arrays[k])
    np.testing.assert_array_equal(back.inner.x, r.inner.x)
    with np.load(sp.path(3), allow_pickle=False) as z:  # every entry is a plain array
        assert all(z[name].dtype != object for name in z.files)
    json.loads(bytes(np.load(sp.path(3))["__json__"]))
    with pytest.raises(TypeError, match="cannot be spooled"):
        sp.save(4, _Result(4, {1: np.zeros(1)}, [], r.inner, (), np.float32(0)))
    sp.path(5).write_bytes(b"PK\x03\x04 torn")  # unreadable: computed again, said in one line
    assert sp.load(5) is None
