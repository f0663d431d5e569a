"""The validity suite with the packaged standard evaluator v7 on a corpus-v5 prefix (run.sh).

v7 refuses a corpus other than its own recipe's (corpus v4), rightly: its test split is not v5's. Here the
refusal is skipped, on purpose and nowhere else, so that v7 is measured on the very clips the two small
evaluators are: v5's test clips, whose interaction captions v7 was never trained on (the surface reading words
contacts differently). The weights, statistics and encoder are v7's, loaded as a plain evaluator folder (the same
scoring function: ``evaluation.checkpoint.evaluator_id`` of the folder); everything else is the suite's own code.

    python v7_on_v5.py DATA OUT KINDS
"""

import sys

from handx_jax import standard
from handx_jax.evaluation import load_evaluator
from handx_jax.standard import naming
from handx_jax.validity import suite


class _V7Unchecked(naming.Evaluator):
    """The packaged evaluator folder, without the recipe check (module docstring)."""

    def check_data(self, ds) -> None:
        return None

    def load(self, *, encoder=None, batch_size: int = 256):
        ev = load_evaluator(self.folder, encoder=standard.encoder_dir(), batch_size=batch_size)
        ev.check_dataset = lambda ds: None  # the same refusal, at scoring time
        return ev


assert standard.read_card()["version"] == 7, "run this where the packaged standard evaluator is v7"
naming.resolve_evaluator = lambda value: _V7Unchecked(folder=standard.evaluator_dir())
data, out, kinds = sys.argv[1:4]
suite.run(data, out, evaluator="standard-v7", kinds=kinds.split(","), log=lambda *_: None)
print(f"wrote {out}/validity.json")
