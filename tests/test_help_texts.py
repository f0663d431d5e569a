"""Terms printed in reports are defined in the --help of the commands that print them (issue 14.7)."""

import re

import pytest

from handx_jax.cli import main as handx_main
from handx_jax.demo import main as demo_main


@pytest.mark.parametrize("argv", [["data", "synth", "--help"], ["data", "import-handx", "--help"], None])
def test_cut_report_terms_are_defined_in_help(argv, capsys):
    with pytest.raises(SystemExit) as e:
        handx_main(argv) if argv else demo_main(["--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for term, definition in [("nonfinite", "NaN"), ("jump", "0.15 m between consecutive frames"),
                             ("broken_pose", "50% off its median length"), ("hands_apart", "more than 1.5 m apart")]:
        assert re.search(rf"{term} = [^;]*{re.escape(definition)}", text), (term, text[-600:])
