import json

import numpy as np
import pytest

from handx_jax.dataset.format import Dataset, nested_fractions, write_dataset
from handx_jax.infra.errors import DataError


def _texts(n, levels=5):
    return [{"id": f"c{i}", **{k: [f"{k} {i} level {lv}" for lv in range(levels)]
                                for k in ("left", "right", "interaction")}} for i in range(n)]


def _motion(n, seed=0):
    return np.random.default_rng(seed).normal(size=(n, 60, 2, 21, 3)).astype(np.float32) * 0.05


def test_write_open_roundtrip(tmp_path):
    m, t = _motion(20), _texts(20)
    splits = {"train": list(range(14)), "val": [14, 15, 16], "test": [17, 18, 19]}
    write_dataset(tmp_path / "d", m, t, splits=splits, events=[{"frame_count": 60}] * 20, stats=False)
    ds = Dataset.open(tmp_path / "d")
    assert len(ds) == 20 and isinstance(ds.motion, np.memmap)
    np.testing.assert_array_equal(ds.motion, m)
    assert ds.texts == t and ds.events[3] == {"frame_count": 60}
    assert ds.split("val").tolist() == [14, 15, 16]
    assert ds.meta["levels"] == 5 and ds.meta["split_sizes"] == {"train": 14, "val": 3, "test": 3}
    assert ds.captions(-1)[2] == ("left 2 level 4", "right 2 level 4", "interaction 2 level 4")
    ds.verify()


def test_fractions_nested_and_val_fixed(tmp_path):
    fr = nested_fractions(np.arange(1000), (0.05, 0.2, 1.0), seed=3)
    a, b, c = (set(fr[k]) for k in ("0.05", "0.2", "1"))
    assert len(a) == 50 and len(b) == 200 and len(c) == 1000 and a < b < c
    # Uniform: the 5% subset is spread over the range, not a prefix.
    assert 300 < np.mean(sorted(a)) < 700
    assert nested_fractions(np.arange(1000), (0.05,), seed=3)["0.05"] == fr["0.05"]  # deterministic
    m, t = _motion(40), _texts(40)
    write_dataset(tmp_path / "d", m, t, splits={"train": list(range(30)), "val": list(range(30, 40))}, stats=False)
    ds = Dataset.open(tmp_path / "d")
    assert set(ds.split("train", 0.2)) <= set(ds.split("train"))
    assert ds.split("val").tolist() == list(range(30, 40))
    with pytest.raises(KeyError, match="0.5"):
        ds.split("train", 0.5)


def test_fingerprint_changes_with_content_and_verify_detects_tamper(tmp_path):
    m, t = _motion(5), _texts(5)
    write_dataset(tmp_path / "a", m, t, stats=False)
    t2 = _texts(5)
    t2[0]["left"][0] = "different"
    write_dataset(tmp_path / "b", m, t2, stats=False)
    assert Dataset.open(tmp_path / "a").fingerprint != Dataset.open(tmp_path / "b").fingerprint
    p = tmp_path / "a" / "texts.jsonl"
    p.write_text(p.read_text().replace("level 0", "level 9", 1))
    with pytest.raises(DataError, match="modified"):
        Dataset.open(tmp_path / "a").verify()


@pytest.mark.parametrize("case", ["nan", "shape", "empty_list", "unequal", "count", "dup_split"])
def test_bad_input_is_named_and_nothing_written(tmp_path, case):
    m, t = _motion(4), _texts(4)
    kw = {}
    if case == "nan":
        m[2, 10, 1, 5, 0] = np.nan
        match = "clip c2"
    elif case == "shape":
        m = m[:, :, :, :20]
        match = "shape"
    elif case == "empty_list":
        t[1]["interaction"] = []
        match = "clip c1.*interaction"
    elif case == "unequal":
        t[3]["right"] = t[3]["right"][:2]
        match = "clip c3.*differ"
    elif case == "count":
        t = t[:3]
        match = "4 motion clips but 3"
    else:
        kw["splits"] = {"train": [0, 1, 2], "val": [2], "test": [3]}
        match = "clip c2 appears in more than one split"
    with pytest.raises(DataError, match=match):
        write_dataset(tmp_path / "d", m, t, stats=False, **kw)
    assert not (tmp_path / "d").exists() and list(tmp_path.iterdir()) == []


def test_open_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        Dataset.open(tmp_path / "nope")
    write_dataset(tmp_path / "d", _motion(3), _texts(3), stats=False)
    mp = tmp_path / "d" / "motion.npy"
    mp.write_bytes(mp.read_bytes()[:1000])  # truncated
    with pytest.raises(DataError, match="motion.npy"):
        Dataset.open(tmp_path / "d")
    write_dataset(tmp_path / "e", _motion(3), _texts(3), stats=False)
    meta = json.loads((tmp_path / "e" / "meta.json").read_text())
    meta["format_version"] = 99
    (tmp_path / "e" / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match="format_version 99"):
        Dataset.open(tmp_path / "e")
    write_dataset(tmp_path / "f", _motion(3), _texts(3), stats=False)
    lines = (tmp_path / "f" / "texts.jsonl").read_text().splitlines()
    (tmp_path / "f" / "texts.jsonl").write_text("\n".join(lines[:2]) + "\n")
    with pytest.raises(DataError, match="texts.jsonl.*2 text records for 3"):
        Dataset.open(tmp_path / "f")


def test_existing_dataset_is_not_overwritten(tmp_path):
    write_dataset(tmp_path / "d", _motion(3), _texts(3), stats=False)
    fp = Dataset.open(tmp_path / "d").fingerprint
    with pytest.raises(FileExistsError):
        write_dataset(tmp_path / "d", _motion(3, seed=1), _texts(3), stats=False)
    assert Dataset.open(tmp_path / "d").fingerprint == fp


def test_stats_npz_same_bits_for_any_worker_count(tmp_path, monkeypatch):
    """stats.npz is summed from fixed clip chunks in chunk order: 1 or 3 processes give the same bytes,
    and the values are the train split's mean/std computed in one piece."""
    from handx_jax import representation as rep
    from handx_jax.dataset import format as dataset_mod
    from handx_jax.dataset.stats import dataset_stats

    monkeypatch.setattr(dataset_mod, "STATS_CHUNK", 4)  # 11 train clips → chunks of 4, 4, 3
    m = _motion(14, seed=4)
    splits = {"train": list(range(11)), "val": [11], "test": [12, 13]}
    for w in (1, 3):
        write_dataset(tmp_path / f"w{w}", m, _texts(14), splits=splits, workers=w)
    assert (tmp_path / "w1/stats.npz").read_bytes() == (tmp_path / "w3/stats.npz").read_bytes()
    ds = Dataset.open(tmp_path / "w3")
    with np.load(tmp_path / "w3/stats.npz") as z:
        for kind, fn in (("diffusion", rep.to_diffusion), ("ar", rep.to_ar), ("evaluator", rep.to_evaluator)):
            whole = rep.compute_preset_stats(kind, fn(m[:11].astype(np.float64)), chunk_size=10 ** 6)
            np.testing.assert_allclose(z[f"{kind}_mean"], whole.mean, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(z[f"{kind}_std"], whole.std, rtol=1e-10, atol=1e-12)
    assert dataset_stats(ds, chunk=5, workers=1) == dataset_stats(ds, chunk=5, workers=3) == dataset_stats(ds)


def _recipe(seed=0):
    return {"kind": "synth", "generator_version": 2, "seed": seed, "clips": 12, "options": {"noise_deg": 2.0}}


def _build(path, motion, texts, splits, recipe):
    write_dataset(path, motion, texts, splits=splits, recipe=recipe, stats=False)
    return Dataset.open(path)


def test_check_compatible_accepts_rounding_and_refuses_other_data(tmp_path, capsys):
    """Issue 14.5: the recipe + discrete content is a dataset's identity. A rebuild whose motion differs by
    float rounding (1e-6 m here) gets another content hash but is accepted and reported; another recipe,
    a changed (overlapping) test split, other captions or motion beyond rounding are refused."""
    from types import SimpleNamespace

    from handx_jax.dataset.format import check_compatible, dataset_record
    from handx_jax.evaluation import TrainedEvaluator

    m, t = _motion(12), _texts(12)
    splits = {"train": list(range(8)), "val": [8, 9], "test": [10, 11]}
    a = _build(tmp_path / "a", m, t, splits, _recipe())
    trained = dataset_record(a)
    assert trained["recipe"]["seed"] == 0 and set(trained["identity"]["splits"]) == {"train", "val", "test"}
    assert check_compatible(trained, a).status == "identical"

    jitter = np.random.default_rng(1).choice([-1e-6, 1e-6], size=m.shape).astype(np.float32)
    b = _build(tmp_path / "b", m + jitter, t, splits, _recipe())
    assert b.fingerprint != a.fingerprint
    c = check_compatible(trained, b, what="this evaluator")
    assert c.status == "rounding" and 0 < c.max_motion_diff_m <= 2e-6 and "float rounding" in c.message
    # The evaluator uses the same check: accepted, and the note goes to stderr.
    TrainedEvaluator.check_dataset(SimpleNamespace(meta={"dataset": trained}), b)
    assert "only by float rounding" in capsys.readouterr().err

    refused = {
        "different recipe": _build(tmp_path / "r", m + jitter, t, splits, _recipe(seed=1)),
        "test split": _build(tmp_path / "s", m, t, {"train": list(range(7)), "val": [8, 9], "test": [7, 10, 11]},
                             _recipe()),
        "captions differ": _build(tmp_path / "c", m, [dict(x, left=["other"] * 5) if i == 3 else x
                                                      for i, x in enumerate(t)], splits, _recipe()),
        "beyond float rounding": _build(tmp_path / "m", m + np.float32(1e-3), t, splits, _recipe()),
    }
    for why, ds in refused.items():
        with pytest.raises(DataError, match=why):
            check_compatible(trained, ds)
        with pytest.raises(DataError, match=why):
            TrainedEvaluator.check_dataset(SimpleNamespace(meta={"dataset": trained}), ds)
    # Without a recorded identity (artefacts made before recipes existed) only identical bytes pass.
    with pytest.raises(DataError, match="only identical bytes"):
        check_compatible({"fingerprint": a.fingerprint}, b)


def test_uneven_caption_levels_are_refused_naming_the_clip(tmp_path):
    t = _texts(4)
    t[2] = {k: v[:3] for k, v in t[2].items() if k != "id"} | {"id": "c2"}
    with pytest.raises(DataError, match="clip c2.*3 caption levels, but clip c0 has 5"):
        write_dataset(tmp_path / "d", _motion(4), t, stats=False)
    assert not (tmp_path / "d").exists()
