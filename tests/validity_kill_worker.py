"""The validity suite's report writer killed with SIGKILL while it moves the report into place, for the kill -9
test of tests/test_bad_input_validity.py:

    python tests/validity_kill_worker.py OUT REPORT_JSON MOVES

writes the report held in REPORT_JSON into the folder OUT (``suite.write_report``) and kills its own process
with SIGKILL (as ``kill -9`` does) just before the move number MOVES + 1 of a report file into OUT: 0 kills
it after the three files are rendered and before any is moved, 1 after ``validity.png`` is in place.
"""

import json
import os
import signal
import sys
from pathlib import Path

from handx_jax.validity import suite

out, report, moves = Path(sys.argv[1]), json.loads(Path(sys.argv[2]).read_text()), int(sys.argv[3])
done = []
replace = os.replace


def killed_replace(src, dst):
    if Path(dst).parent == out and Path(dst).name in suite.REPORT_FILES:
        if len(done) == moves:
            os.kill(os.getpid(), signal.SIGKILL)
        done.append(dst)
    replace(src, dst)


suite.os.replace = killed_replace
suite.write_report(out, report)
