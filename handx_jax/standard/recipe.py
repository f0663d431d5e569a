"""The standard corpus's recipe: the generator version, seed, clip count and annotation reading that are the
standard evaluator's identity (not the bytes of a corpus), read back from a corpus's ``meta.json``, and the
build of the corpus or a prefix of it (``handx standard corpus``)."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

from handx_jax.infra.errors import DataError
from handx_jax.standard.assets import CARD_JSON, CARD_MD, assets_folder, read_card

STANDARD_ANNOTATION = "surface"  # the standard corpus's annotation reading (Recipe.annotation; corpus v4 "gist", v3 "gist", v2 "stable", v1 "reference")
STANDARD_MOTION = "surface"  # its generator motion (Recipe.motion; corpus v4 "chain", v3 "transition", v1-v2 "oscillate")


@dataclasses.dataclass(frozen=True)
class Recipe:
    """The standard corpus: ``handx standard corpus`` = ``handx data synth --clips CLIPS --seed SEED
    --annotation ANNOTATION --motion MOTION`` with the default build options, from generator version
    ``generator``."""

    # v4: 120k clips (v1-v3: 20k). On 17.9k train clips the small evaluator overfits below GT top-1 0.73 at
    # block 32 (v3); on 108k it does not (docs/results/evaluator_120k_gt_rows.json, and v4's card). The first
    # 20k clips of this recipe are v3's corpus (the prefix property: same ids, captions and motion), so v3-era
    # prefixes are prefixes of v4's.
    clips: int = 120_000
    seed: int = 0
    generator: str = ""  # filled by :func:`code_recipe` from the data package
    # The annotation reading (data.events.ANNOTATIONS, with its captioner wording, data.build.WORDING) and the
    # generator's motion (data.build.with_motion). The defaults are the standard corpus's (corpus v5, v8:
    # "surface" on "surface" motion, the hands resolved against the hand surface; issue 55). Earlier: v1-v4
    # "reference" on "oscillate", v5 (corpus v2) "stable" on "oscillate", v6 (corpus v3) "gist" on
    # "transition", v7 (corpus v4) "gist" on "chain" (docs/results/validity/corpus-v3/ ... corpus-v5/). A card
    # written before a field existed is read with :meth:`from_card`, not these defaults.
    annotation: str = STANDARD_ANNOTATION
    motion: str = STANDARD_MOTION

    @classmethod
    def from_card(cls, recipe: dict) -> "Recipe":
        """The recipe a card's ``recipe`` records. v4's card predates ``annotation`` and ``motion``, v5's
        ``motion``: a missing field is the value every corpus had when the card was written ("reference",
        "oscillate"), said here explicitly so that a change of the defaults never re-reads an old card."""
        return cls(**{"annotation": "reference", "motion": "oscillate", **recipe})

    def synth_flags(self) -> str:
        """The ``handx data synth`` flags that build this recipe but for its clip count (``--clips``), in one
        place for the card's reproduction command and the maintainers' scripts (scripts/build_standard.sh,
        scripts/gpu_lease.sh). Every field is spelled out, whatever the defaults."""
        return f"--seed {self.seed} --annotation {self.annotation} --motion {self.motion}"

    def build_config(self, clips: int | None = None, workers: int = 0):
        from handx_jax.dataset.build import BuildConfig, with_motion, with_reading

        cfg = BuildConfig(clips=self.clips if clips is None else int(clips), seed=self.seed, workers=workers)
        return with_motion(with_reading(cfg, self.annotation), self.motion)


def generator_version() -> str:
    """The generator's version as the data package states it (bumped by any change to its output)."""
    from handx_jax.synthesis.bimanual import GENERATOR_VERSION

    return str(GENERATOR_VERSION)


def code_recipe() -> Recipe:
    """The recipe this code builds as the standard corpus: corpus v5 since evaluator v8 (surface motion and
    reading; issue 55). v7 was corpus v4 (chain motion, gist reading), v6 corpus v3 (transition motion), v5
    corpus v2 (stable reading), v1-v4 corpus v1 (reference reading)."""
    return Recipe(generator=generator_version())


# Corpus versions a user can build by name (``handx standard corpus --corpus NAME``). The standard one is the
# packaged evaluator's (``code_recipe``: corpus v5, evaluator v8): corpus v4's recipe with its two hands resolved
# against the hand surface and their contacts read from it (motion and annotation "surface", issue 55,
# docs/results/validity/corpus-v5/). v4 stays buildable for the archived evaluator v7 (``--evaluator standard-v7``).
CORPUS_VERSIONS = ("v4", "v5")


def corpus_recipe(name: str) -> Recipe:
    """The recipe of a named corpus version (``CORPUS_VERSIONS``), or a one-line error listing them."""
    if name == "v4":
        return dataclasses.replace(code_recipe(), annotation="gist", motion="chain")
    if name == "v5":
        return dataclasses.replace(code_recipe(), annotation="surface", motion="surface")
    raise ValueError(f"unknown corpus version {name!r}; choose one of {', '.join(CORPUS_VERSIONS)}")


def build_options(recipe: Recipe) -> dict:
    """The build options of the recipe as ``meta.json``'s ``recipe.options`` records them
    (``data.build.recipe``: everything but the clip count, seed and worker count)."""
    from handx_jax.dataset.build import recipe as build_recipe

    return json.loads(json.dumps(build_recipe(recipe.build_config())["options"]))


def recipe_of(ds) -> tuple[Recipe | None, dict]:
    """(recipe, build options) from ``meta.json``'s ``recipe`` of a corpus built by the generator
    (``data synth`` / ``standard corpus``); (None, {}) for anything else (imports, older corpora)."""
    from handx_jax.dataset.build import reading_of_options

    r = ds.meta.get("recipe") or {}
    if r.get("kind") != "synth":
        return None, {}
    opts = dict(r.get("options", {}))
    motion = str((opts.get("synth") or {}).get("motion", "oscillate"))
    return (Recipe(clips=int(r["clips"]), seed=int(r["seed"]), generator=str(r["generator_version"]),
                   annotation=reading_of_options(opts) or "custom", motion=motion), opts)


def build_standard_corpus(out: str | os.PathLike, clips: int | None = None, *, workers: int = 0,
                          overwrite: bool = False, progress: bool = True, recipe: Recipe | None = None,
                          assets: Path | None = None) -> Path:
    """``handx standard corpus``: the standard recipe, or its first ``clips`` clips (a prefix)."""
    from handx_jax.dataset.build import build_corpus

    rec = recipe or code_recipe()
    assets = assets_folder(assets)
    card = read_card(assets) if (assets / CARD_JSON).exists() else None
    # A named corpus version other than the standard one (corpus v5) has no packaged evaluator to match.
    if card is not None and Recipe.from_card(card["recipe"]) != rec and rec == code_recipe():
        raise DataError(f"this code's generator builds recipe {dataclasses.asdict(rec)}, but the packaged standard "
                        f"evaluator was trained on {card['recipe']}; its corpus cannot be rebuilt with this code "
                        f"(rebuild the assets: see {assets / CARD_MD})")
    n = rec.clips if clips is None else int(clips)
    if not 0 < n <= rec.clips:
        raise ValueError(f"--clips must be in [1, {rec.clips}] (the standard corpus has {rec.clips}), got {n}")
    from handx_jax.families import norm_presets

    return build_corpus(out, rec.build_config(n, workers), overwrite=overwrite, progress=progress,
                        stats=tuple(norm_presets().values()))  # every family's statistics, as `handx data synth`
