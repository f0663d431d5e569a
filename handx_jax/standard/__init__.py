"""The standard evaluator: one yardstick, shipped with the package (issue 13 item 1).

The text-to-motion line of work scores every model with the same released evaluator (paper E.2;
Guo et al.'s T2M evaluator for HumanML3D), so numbers from different people compare. This module is
that for handx-jax. Its **identity is the corpus recipe** — the built-in generator (its version), the
seed, the clip count and the build options of :data:`RECIPE` — not the bytes of a corpus: the same
recipe rebuilt with another numpy/jax build gives the same clip ids, splits and captions, and motion
equal up to float rounding, and it is accepted.

Packaged assets (``handx_jax/assets/standard/``, a few MB, see ``CARD.md``; the earlier versions v4-v6 are kept
out of the package, in a clone's ``evaluators/``, without the encoder they share with it):

    card.json, CARD.md   recipe, how the evaluator was trained (steps, batch, lr, wall time, machine),
                         its Ground Truth rows at R-Precision blocks 32 and 16, sha256 of every file
    encoder/             the tiny T5 text encoder + SentencePiece tokenizer (Hugging Face layout)
    evaluator/           the contrastive evaluator (``handx_jax.evaluation`` checkpoint format)
    test_manifest.npz    the standard test split: clip ids in build order, a digest of each clip's
                         captions, per-clip motion moments (for the float-tolerance identity check)

Scoring without the whole standard corpus. Synthesis runs in chunks that depend only on
``(seed, chunk)`` and a clip's split is a hash of ``(seed, sequence)`` (``data.build``), so the first
M clips of the recipe are the same whatever the clip count: a *prefix* corpus (``handx standard
corpus --clips M``) has a train split inside the standard train split and a test split equal to the
first test clips of the standard one. :meth:`StandardEvaluator.check_dataset` accepts the standard
corpus and any prefix of it — after checking its test clips against the manifest (ids, captions,
motion within tolerance) and that no train clip is a standard test clip — and refuses anything else.
``make demo`` trains on a 2,400-clip prefix and is scored on its ~120 standard test clips; the card's
rows are on the full test split.

    handx standard info [--json]                    the card
    handx standard corpus --out DIR [--clips M]     build the standard corpus (or its first M clips)
    handx standard check --data DIR                 is DIR the standard corpus or a prefix of it?
    handx standard package --data DIR --encoder ENC --evaluator E --out ASSETS   (maintainers)
    handx eval run --generated G.npz --data DIR         (no --evaluator: the standard one)

One concern per module:

    assets.py     version, folders (packaged and archived), the card, checksums
    naming.py     ``--evaluator`` values: ``resolve_evaluator`` (standard, standard-vN, a path) and the
                  dataset–evaluator pair check every command makes before its work
    recipe.py     the corpus recipe, read back from a corpus, and the corpus build
    identity.py   the test manifest and the check that a corpus is the standard one or a prefix
    evaluator.py  loading the standard evaluator (``StandardEvaluator``, built lazily)
    card.py       CARD.md from card.json, and what the card keeps of a validity report
    packaging.py  (maintainers) packaging the assets and putting validity figures on the card
    cli.py        ``handx standard …`` (not imported here: the CLI imports the package, not the reverse)

The names below are the package's public surface (``from handx_jax import standard``; ``standard.X``).
"""

from handx_jax.dataset.format import MOTION_ATOL
from handx_jax.standard.assets import (ARCHIVE, ASSETS, CARD_JSON, CARD_MD, CARD_SHA, ENCODER_DIR, EVALUATOR_DIR,
                                       MANIFEST, NAME, VERSION, archived, asset_files, assets_folder, encoder_dir,
                                       evaluator_dir, read_card, reference_cache_dir, verify_assets, versions)
from handx_jax.standard.card import card_markdown, validity_summary
from handx_jax.standard.evaluator import load, standard_evaluator_class
from handx_jax.standard.identity import check_reference, read_manifest, test_manifest
from handx_jax.standard.naming import Evaluator, resolve_evaluator
from handx_jax.standard.packaging import add_validity, package
from handx_jax.standard.recipe import (CORPUS_VERSIONS, STANDARD_ANNOTATION, STANDARD_MOTION, Recipe, build_options,
                                       build_standard_corpus, code_recipe, corpus_recipe, generator_version, recipe_of)

__all__ = ["MOTION_ATOL", "ARCHIVE", "ASSETS", "CARD_JSON", "CARD_MD", "CARD_SHA", "ENCODER_DIR", "EVALUATOR_DIR",
           "MANIFEST", "NAME", "VERSION", "archived", "asset_files", "assets_folder", "encoder_dir", "evaluator_dir",
           "read_card", "reference_cache_dir", "verify_assets", "versions", "Evaluator", "resolve_evaluator",
           "card_markdown", "validity_summary", "load", "check_reference", "read_manifest", "test_manifest",
           "add_validity", "package", "STANDARD_ANNOTATION", "STANDARD_MOTION", "Recipe", "build_options",
           "build_standard_corpus", "code_recipe", "corpus_recipe", "generator_version", "recipe_of", "StandardEvaluator",
           "CORPUS_VERSIONS"]


def __getattr__(name: str):  # StandardEvaluator is built on first use: importing the package must not import jax
    if name == "StandardEvaluator":
        return standard_evaluator_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
