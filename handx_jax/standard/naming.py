"""One way to name an evaluator (issue 51 item 5): every command that takes ``--evaluator`` resolves its value
with :func:`resolve_evaluator`, before any training, generation or scoring starts (issue 54 item 2).

A value is one of

    (omitted), standard, standard-v8   the packaged standard evaluator (handx_jax/assets/standard/)
    standard-vN                         an earlier standard evaluator, in a clone's evaluators/standard-vN/
    a path                              an evaluator folder (``handx train evaluator`` or ``handx import
                                        handx-evaluator``), or a standard evaluator's assets folder or its
                                        evaluator/ subfolder (then it is that standard evaluator)

A path that is not an evaluator is refused in one line that says what it is (a dataset, a training run of a
model family, an evaluator whose training has not finished). :meth:`Evaluator.check_data` is the one place
where a dataset–evaluator pair is refused (a corpus-v4 prefix under v8, a v5 prefix under standard-v7, a
dataset other than the one an evaluator was trained on), so every command refuses the same pairs.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

from handx_jax.infra.errors import DataError
from handx_jax.standard import assets as _assets  # ASSETS and ARCHIVE read when called (a test's copy moves them)
from handx_jax.standard.assets import (CARD_JSON, EVALUATOR_DIR, NAME, VERSION, evaluator_dir, read_card,
                                       reference_cache_dir, version_folder, versions)


@dataclasses.dataclass(frozen=True)
class Evaluator:
    """A resolved ``--evaluator``: the evaluator folder (``evaluator.json``, weights, statistics) and, for a
    standard evaluator, its assets folder (card, test manifest); nothing is loaded yet."""

    folder: Path
    assets: Path | None = None  # a standard evaluator's assets folder, else None

    @property
    def standard(self) -> bool:
        return self.assets is not None

    @property
    def name(self) -> str:
        """``standard-vN`` for a standard evaluator, else its folder."""
        return f"{NAME}-v{read_card(self.assets)['version']}" if self.standard else str(self.folder)

    @property
    def meta(self) -> dict:
        """Its ``evaluator.json`` (the caption level it scores, its training dataset, its encoder)."""
        return json.loads((self.folder / "evaluator.json").read_text())

    def reference_cache(self, default=True):
        """Where scoring caches reference embeddings: a user folder per standard version (the package may be
        read-only), else ``default`` (True: the evaluator's own ``reference_cache/``; False: none)."""
        return reference_cache_dir(self.assets) if self.standard else default

    def check_data(self, ds) -> None:
        """Refuse a dataset this evaluator does not score (``DataError``, one line): a standard evaluator
        accepts its recipe's corpus and prefixes of it (naming the version whose recipe it is otherwise),
        any other evaluator the dataset it was trained on. Reads JSON and the test clips; loads no weights."""
        if self.standard:
            from handx_jax.standard.identity import check_reference

            check_reference(ds, read_card(self.assets), self.assets)
        else:
            from handx_jax.evaluation.model import check_trained_dataset

            check_trained_dataset(self.meta, ds)

    def load(self, *, encoder=None, batch_size: int = 256):
        """The loaded evaluator (a ``StandardEvaluator`` with its checksums verified, or a ``TrainedEvaluator``;
        ``encoder``: another folder holding the encoder an evaluator folder was trained with)."""
        if self.standard:
            if encoder is not None:
                raise DataError(f"--encoder applies to an evaluator folder; standard evaluator {self.name} carries "
                                f"its own")
            from handx_jax.standard.evaluator import load

            return load(self.assets, batch_size=batch_size)
        from handx_jax.evaluation import load_evaluator

        return load_evaluator(self.folder, encoder=encoder, batch_size=batch_size)


def _standard(assets: Path) -> Evaluator:
    return Evaluator(folder=evaluator_dir(assets), assets=assets)


def _what_it_is(p: Path) -> str:
    """What a folder without ``evaluator.json`` is, for the refusal."""
    cfg = p / "config.json"
    if cfg.is_file():
        try:
            c = json.loads(cfg.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError):
            c = None
        if isinstance(c, dict) and (c.get("trainable") == "evaluator" or c.get("family") == "evaluator"):
            return ("an evaluator whose training has not finished (no evaluator.json): rerun the same "
                    "`handx train evaluator` command to finish it")
        if isinstance(c, dict) and c.get("family"):
            return f"a training run of model family {c['family']!r}, not an evaluator"
        if isinstance(c, dict) and c.get("trainable"):
            return f"a {c['trainable']} training run, not an evaluator"
        return "a run folder (config.json), not an evaluator"
    if (p / "meta.json").is_file() and (p / "motion.npy").exists():
        return "a dataset, not an evaluator"
    return "not an evaluator folder (no evaluator.json)"


def _archived_names() -> str:
    return ", ".join(f"{NAME}-v{v}" for v in versions())


def resolve_evaluator(value: str | os.PathLike | None) -> Evaluator:
    """The evaluator an ``--evaluator`` value names (see the module docstring), checked to be a finished
    evaluator; a ``DataError`` in one line otherwise. Nothing is loaded: call it first, before any work."""
    if value is None or str(value) in (NAME, f"{NAME}-v{VERSION}"):
        return _standard(_assets.ASSETS)
    text = str(value)
    if text.startswith(f"{NAME}-v") and text[len(NAME) + 2:].isdigit():
        v = int(text[len(NAME) + 2:])
        folder = version_folder(v)
        if not (folder / CARD_JSON).is_file():
            where = (f"; the earlier ones are kept in a clone's {_assets.ARCHIVE.name}/ folder (pass its path, "
                     f"e.g. --evaluator evaluators/{NAME}-v6)" if not _assets.ARCHIVE.is_dir() else "")
            raise DataError(f"--evaluator {text}: no such standard evaluator; at hand: {_archived_names()}{where}")
        return _standard(folder)
    p = Path(value)
    if not p.exists():
        raise DataError(f"--evaluator {text}: no such folder (give `standard`, a version such as "
                        f"{NAME}-v{VERSION}, or an evaluator folder)")
    if not p.is_dir():
        raise DataError(f"--evaluator {text}: a file, not an evaluator folder")
    r = p.resolve()
    for folder in (r, r.parent):  # a standard evaluator's assets folder, or its evaluator/ subfolder
        if (folder / CARD_JSON).is_file() and (folder == r or r.name == EVALUATOR_DIR):
            return _standard(folder)
    from handx_jax.evaluation.checkpoint import META_FILE, PARAMS_FILE, STATS_FILE, read_meta

    if not (p / META_FILE).is_file():
        raise DataError(f"--evaluator {text}: {_what_it_is(p)}")
    read_meta(p)  # format and version: one line naming the file
    for f in (PARAMS_FILE, STATS_FILE):
        if not (p / f).is_file():
            raise DataError(f"--evaluator {text}: an incomplete evaluator folder (no {f})")
    return Evaluator(folder=p.absolute())


__all__ = ["Evaluator", "resolve_evaluator"]
