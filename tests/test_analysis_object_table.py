"""`handx analyze table` on a BimArt sweep's results (issue 53 item 4): the default layout shows the hand-object
metrics (BimArt's Tab. 3 columns) with their intervals, read from the committed size sweep's results.csv, and a text
sweep's table keeps its own columns."""

import csv
from pathlib import Path

from analysis import tables
from analysis.schema import load_results
from handx_jax.cli import main

SWEEP = Path(__file__).parents[1] / "docs" / "results" / "bimart" / "size_sweep" / "results.csv"


def test_bimart_rows_show_the_object_metrics(capsys):
    assert main(["analyze", "table", str(SWEEP)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == ("| Layers | FLOPs (G) | Pen 1cm (%) ↓ | Con (%) ↑ | Art (%) ↑ | Part F1 ↑ | CM (cm) ↓ | "
                        "Mul (cm) ↑ |")
    with open(SWEEP) as f:
        raw = {int(r["layers"]): r for r in csv.DictReader(f)}
    # Each cell is the CSV's value at the column's digits, the best per column in bold (lower Pen and CM).
    by_layers = {int(line.split("|")[1]): [c.strip() for c in line.split("|")[3:-1]] for line in lines[2:]}
    for layers, cells in by_layers.items():
        r = raw[layers]
        want = [f"{float(r['obj_pen_1cm']):.1f}", f"{float(r['obj_con']):.1f}", f"{float(r['obj_art']):.1f}",
                f"{float(r['obj_part_f1']):.3f}", f"{float(r['obj_cm_cm']):.2f}", f"{float(r['obj_mul_cm']):.2f}"]
        assert [c.strip("*") for c in cells] == want
    assert by_layers[3][0] == "**22.1**" and by_layers[1][4] == "**3.99**" and by_layers[2][2] == "**27.1**"


def test_object_intervals_and_text_rows():
    rows = load_results(SWEEP)
    for i, r in enumerate(rows):
        r["obj_art_ci"] = 1.0 + i
    md = tables.render_table(rows, "md")
    assert f"{rows[0]['obj_art']:.1f} ± 1.0" in md and "Pen 5mm" not in md  # Pen 5mm and Accel stay in the CSV
    text_rows = [{"run_id": "a", "family": "diffusion", "layers": 2, "rprec_top3": 0.5},
                 {"run_id": "b", "family": "diffusion", "layers": 4, "rprec_top3": 0.6}]
    assert tables.auto_layout(text_rows).metrics == ("rprec_top3",)
