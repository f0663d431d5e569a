"""Results schema: validation, jsonl/csv round trips, clear errors, run folders."""

import json

import pytest

from analysis import schema
from handx_jax.infra.errors import DataError


def _rows():
    return [
        schema.make_row(run_id="a", family="diffusion", layers=4, dim=256, heads=4, ff=1024, data_fraction=0.05,
                        params=4_630_000, flops_per_sample=3.83e9, train_flops=1.2e17, rprec_top3=0.295,
                        rprec_top3_ci=0.091, fid=5.342),
        schema.make_row(run_id="b", family="ar", codebook=1024, params=29_630_000, rprec_top3=0.438,
                        label="AR 8L"),
        schema.make_row(run_id="gt", family="ground_truth", rprec_top3=0.948, diversity=6.887),
    ]


@pytest.mark.parametrize("suffix", [".jsonl", ".csv"])
def test_round_trip(tmp_path, suffix):
    rows = _rows()
    path = schema.save_results(tmp_path / f"results{suffix}", rows)
    assert schema.load_results(path) == rows


def test_load_several_files_and_sweep_folder(tmp_path):
    rows = _rows()
    schema.save_results(tmp_path / "one.jsonl", rows[:1])
    schema.save_results(tmp_path / "two.csv", rows[1:])
    assert schema.load_results(tmp_path / "one.jsonl", tmp_path / "two.csv") == rows
    with pytest.raises(DataError, match="appears twice"):
        schema.load_results(tmp_path / "one.jsonl", tmp_path / "one.jsonl")


def test_csv_types_comments_and_missing(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("# a comment\nrun_id,family,layers,data_fraction,fid,fid_ci\nx,diffusion,12,1.0,1.5,\n")
    (row,) = schema.load_results(p)
    assert row["layers"] == 12 and isinstance(row["layers"], int)
    assert row["fid"] == 1.5 and row["fid_ci"] is None and row["rprec_top1"] is None


@pytest.mark.parametrize("content,needle", [
    ("run_id,family,layerz\nx,diffusion,4\n", "column 'layerz': unknown column (did you mean 'layers'?)"),
    ("run_id,family,layers\nx,diffusion,4.5\n", "row 1, column 'layers': expected an integer"),
    ("run_id,family,fid\nx,diffusion,abc\n", "row 1, column 'fid': expected a number"),
    ("run_id,family,data_fraction\nx,diffusion,1.5\n", "column 'data_fraction': must be in (0, 1]"),
    ("run_id,family\nx,transformer\n", "column 'family': unknown family"),
    ("run_id,family,fid_ci\nx,diffusion,0.1\n", "fid_ci is given but fid is not"),
    ("run_id,family\n,diffusion\n", "column 'run_id': required value is missing"),
    ("run_id,family\nx,diffusion,3\n", "row 1: has 3 cells"),
])
def test_csv_errors_name_file_row_column(tmp_path, content, needle):
    p = tmp_path / "bad.csv"
    p.write_text(content)
    with pytest.raises(DataError) as e:
        schema.load_results(p)
    assert str(p) in str(e.value) and needle in str(e.value)


def test_jsonl_errors(tmp_path):
    p = tmp_path / "bad.jsonl"
    p.write_text('{"run_id": "a", "family": "ar"}\n{"run_id": "b", "family": "ar", "params": true}\n')
    with pytest.raises(DataError, match=r"bad.jsonl, row 2, column 'params': expected a number"):
        schema.load_results(p)
    (tmp_path / "x.txt").write_text("")
    with pytest.raises(DataError, match="unsupported results file"):
        schema.load_results(tmp_path / "x.txt")
    with pytest.raises(DataError, match="no such file"):
        schema.load_results(tmp_path / "missing.csv")


def _run_dir(tmp_path, config, logs, ev=None, name="run-1"):
    d = tmp_path / name
    d.mkdir()
    (d / "config.json").write_text(json.dumps(config))
    (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in logs))
    if ev is not None:
        (d / "eval.json").write_text(json.dumps(ev))
    return d


def test_row_from_run_dir(tmp_path):
    cfg = {"family": "diffusion", "seed": 0, "lr": 1e-4,
           "model": {"layers": 8, "dim": 384, "heads": 6, "ff": 1536, "flops_per_sample": 6.98e9},
           "data": {"data_fraction": 0.05}, "train": {"seed": 7, "steps": 200}}
    logs = [{"step": 0, "loss": 1.0, "params": 1_234_567, "params_non_embedding": 1_000_000},
            {"step": 100, "loss": 0.5, "samples_seen": 6400, "train_flops": 1.3e14},
            {"step": 200, "loss": 0.4, "samples_seen": 12800}]
    ev = {"rprec_top3": {"mean": 0.5, "ci": 0.1}, "fid": 2.0, "mm_dist": {"mean": 5.9},
          "contact_f1_intra_ci": 0.01, "contact_f1_intra": 0.6, "_meta": {"step": 200},
          "diversity": [6.1, 0.05]}
    d = _run_dir(tmp_path, cfg, logs, ev)
    with open(d / "metrics.jsonl", "a") as f:
        f.write('{"step": 300, "loss"')  # torn last line of a killed run
    row = schema.row_from_run_dir(d)
    assert row["run_id"] == "run-1" and row["family"] == "diffusion" and row["seed"] == 7  # the training seed
    assert (row["layers"], row["dim"], row["heads"], row["ff"], row["data_fraction"]) == (8, 384, 6, 1536, 0.05)
    assert row["params"] == 1_234_567 and row["params_non_embedding"] == 1_000_000
    assert row["steps"] == 200 and row["samples_seen"] == 12800 and row["train_flops"] == 1.3e14
    assert (row["rprec_top3"], row["rprec_top3_ci"], row["fid"], row["mm_dist"]) == (0.5, 0.1, 2.0, 5.9)
    assert row["contact_f1_intra_ci"] == 0.01
    assert (row["diversity"], row["diversity_ci"]) == (6.1, 0.05)  # json of metrics.mean_ci's tuple
    # A folder of run folders loads as a sweep; a run folder loads directly.
    assert schema.load_results(tmp_path) == [row] == schema.load_results(d)


def test_run_dir_estimates_train_flops_and_errors(tmp_path):
    d = _run_dir(tmp_path, {"family": "ar", "run_id": "x", "flops_per_sample": 1e9},
                 [{"step": 10, "samples_seen": 100}])
    assert schema.row_from_run_dir(d)["train_flops"] == 3e11
    d2 = _run_dir(tmp_path, {"family": "ar", "layers": 4, "model": {"layers": 8}}, [{"step": 1}], name="r2")
    with pytest.raises(DataError, match=r"config.json, field 'layers': conflicting values"):
        schema.row_from_run_dir(d2)
    d3 = _run_dir(tmp_path, {"family": "ar"}, [{"step": 1}], {"fdi": 1.0}, name="r3")
    with pytest.raises(DataError, match=r"eval.json, field 'fdi': unknown metric"):
        schema.row_from_run_dir(d3)
    d4 = _run_dir(tmp_path, {"layers": 2}, [{"step": 1}], name="r4")
    with pytest.raises(DataError, match="field 'family'"):
        schema.row_from_run_dir(d4)
    d5 = _run_dir(tmp_path, {"family": "ar"}, [{"loss": 1}], name="r5")
    with pytest.raises(DataError, match="no integer 'step'"):
        schema.row_from_run_dir(d5)
    d6 = _run_dir(tmp_path, {"family": "ar", "layers": "many"}, [{"step": 1}], name="r6")
    with pytest.raises(DataError, match=r"row r6, column 'layers': expected a number"):
        schema.row_from_run_dir(d6)


def test_column_and_label():
    rows = _rows()
    col = schema.column(rows, "fid")
    assert col[0] == 5.342 and col[1] != col[1]  # NaN where missing
    assert schema.config_label(rows[0]) == "L4 d256 H4 5%"
    assert schema.config_label(rows[1]) == "AR 8L" and schema.config_label(rows[2]) == "GT"
    with pytest.raises(KeyError):
        schema.column(rows, "family")


def test_a_family_axis_is_a_column_while_its_family_is_registered(tmp_path):
    """The schema's family columns are the registry's (``Family.axes``), read when a row is checked: a family
    registered later adds its axis to rows, run folders and labels, and the axis is no column without it."""
    from handx_jax.families import Axis, Family, register

    toy = Family("tests.not_imported", "a toy family", axes=(Axis("width_mult", "model.width_mult", "W", "Width ×"),))
    assert "width_mult" not in schema.column_by_name()
    with register("toy-axes", toy):
        row = schema.make_row(run_id="a", family="toy-axes", layers=2, width_mult=3)
        assert row["width_mult"] == 3 and schema.config_label(row) == "L2 W3"
        names = list(schema.column_by_name())  # the families' axes sit between the shared ones, in registry order
        assert names.index("ff") < names.index("width_mult") < names.index("data_fraction")
        with pytest.raises(DataError, match="must be > 0"):
            schema.make_row(run_id="b", family="toy-axes", width_mult=0)
        run = tmp_path / "run"
        run.mkdir()
        (run / "config.json").write_text(json.dumps({"family": "toy-axes", "model": {"width_mult": 4}}))
        (run / "metrics.jsonl").write_text('{"step": 1}\n')
        assert schema.row_from_run_dir(run)["width_mult"] == 4
    with pytest.raises(DataError, match="unknown column"):
        schema.make_row(run_id="a", family="diffusion", width_mult=3)
