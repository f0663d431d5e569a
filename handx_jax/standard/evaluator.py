"""Loading the standard evaluator: a ``TrainedEvaluator`` that accepts the standard corpus and its prefixes
only, built lazily so that importing the package does not import JAX."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

from handx_jax.standard.assets import EVALUATOR_DIR, assets_folder, encoder_dir, verify_assets
from handx_jax.standard.identity import check_reference


def load(assets: Path | None = None, *, batch_size: int = 256):
    """The packaged standard evaluator (a :class:`StandardEvaluator`; ``assets``: another assets folder),
    its checksums verified first (:func:`verify_assets`): a yardstick that changed is refused, always."""
    from handx_jax.evaluation import load_evaluator

    assets = assets_folder(assets)
    card = verify_assets(assets)
    ev = load_evaluator(assets / EVALUATOR_DIR, encoder=encoder_dir(assets), batch_size=batch_size)
    fields = {f.name: getattr(ev, f.name) for f in dataclasses.fields(ev)}
    return standard_evaluator_class()(**fields, card=card, assets=assets)


@functools.cache
def standard_evaluator_class() -> type:
    """``StandardEvaluator``, defined on first use (its base class imports JAX); one class per process, so
    ``isinstance`` holds for every evaluator :func:`load` returns."""
    from handx_jax.evaluation import TrainedEvaluator

    @dataclasses.dataclass
    class StandardEvaluator(TrainedEvaluator):
        """The packaged evaluator; accepts the standard corpus and its prefixes (:func:`check_reference`)."""

        card: dict = dataclasses.field(default_factory=dict)
        assets: Path | None = None

        def check_dataset(self, ds) -> None:
            found = check_reference(ds, self.card, self.assets)
            self.meta.setdefault("reference_check", {})[str(ds.root)] = found

    return StandardEvaluator
