"""The standard evaluator: one yardstick, shipped with the package (issue 13 item 1).

The text-to-motion line of work scores every model with the same released evaluator (paper E.2;
Guo et al.'s T2M evaluator for HumanML3D), so numbers from different people compare. This module is
that for handx-jax. Its **identity is the corpus recipe** — the built-in generator (its version), the
seed, the clip count and the build options of :data:`RECIPE` — not the bytes of a corpus: the same
recipe rebuilt with another numpy/jax build gives the same clip ids, splits and captions, and motion
equal up to float rounding, and it is accepted.

Packaged assets (``handx_jax/assets/standard/``, a few MB, see ``CARD.md``):

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
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from handx_jax.io import DataError, atomic_write_json, atomic_write_text, sha256_file, verify_checksum, \
    write_checksum

VERSION = 5  # of the packaged assets; bumped whenever the recipe or any weight changes
STANDARD_ANNOTATION = "stable"  # the standard corpus's annotation reading (Recipe.annotation; v1-v4 "reference")
ASSETS = Path(__file__).resolve().parent / "assets" / "standard"
CARD_JSON, CARD_MD, MANIFEST = "card.json", "CARD.md", "test_manifest.npz"
CARD_SHA = CARD_JSON + ".sha256"  # io.write_checksum's sidecar: the card's own checksum
ENCODER_DIR, EVALUATOR_DIR = "encoder", "evaluator"
NAME = "standard"  # `handx eval run --evaluator standard` (the default)

# Per-clip motion moments of the test clips are compared with the dataset identity's tolerance
# (data.dataset.MOTION_ATOL, 10 µm): float rounding of another numpy/jax build moves them by ~1e-7 m; any
# change to the generator moves them by millimetres.
from handx_jax.data.dataset import MOTION_ATOL  # noqa: E402


@dataclasses.dataclass(frozen=True)
class Recipe:
    """The standard corpus: ``handx standard corpus`` = ``handx data synth --clips CLIPS --seed SEED
    --annotation ANNOTATION`` with the default build options, from generator version ``generator``."""

    # v4: 120k clips (v1-v3: 20k). On 17.9k train clips the small evaluator overfits below GT top-1 0.73 at
    # block 32 (v3); on 108k it does not (docs/results/evaluator_120k_gt_rows.json, and v4's card). The first
    # 20k clips of this recipe are v3's corpus (the prefix property: same ids, captions and motion), so v3-era
    # prefixes are prefixes of v4's.
    clips: int = 120_000
    seed: int = 0
    generator: str = ""  # filled by :func:`code_recipe` from the data package
    # The annotation reading (data.events.ANNOTATIONS, with its captioner wording, data.build.WORDING).
    # v1-v4: "reference" (the default here, so their cards, which predate the field, read back unchanged);
    # v5 (corpus v2): "stable", issue 40.
    annotation: str = "reference"

    def build_config(self, clips: int | None = None, workers: int = 0):
        from handx_jax.data.build import BuildConfig, with_reading

        return with_reading(BuildConfig(clips=self.clips if clips is None else int(clips), seed=self.seed,
                                        workers=workers), self.annotation)


def generator_version() -> str:
    """The generator's version as the data package states it (bumped by any change to its output)."""
    from handx_jax.data.synth import GENERATOR_VERSION

    return str(GENERATOR_VERSION)


def code_recipe() -> Recipe:
    """The recipe this code builds as the standard corpus (standard corpus v2 since evaluator v5: the
    stable annotation reading, issue 40)."""
    return Recipe(generator=generator_version(), annotation=STANDARD_ANNOTATION)


def build_options(recipe: Recipe) -> dict:
    """The build options of the recipe as ``meta.json``'s ``recipe.options`` records them
    (``data.build.recipe``: everything but the clip count, seed and worker count)."""
    from handx_jax.data.build import recipe as build_recipe

    return json.loads(json.dumps(build_recipe(recipe.build_config())["options"]))


# ------------------------------------------------------------------------------------------------
# The test manifest: the standard test split's identity, small enough to ship


def _caption_digest(t: Mapping[str, Any]) -> str:
    blob = json.dumps([t["left"], t["right"], t["interaction"]], ensure_ascii=False, separators=(",", ":"))
    return hashlib.blake2b(blob.encode(), digest_size=8).hexdigest()


def _moments(motion_NxTx2x21x3: np.ndarray) -> np.ndarray:
    """(N, 2, 3, 2) per clip, hand and axis: mean and root-mean-square of the joint coordinates (metres)."""
    m = np.asarray(motion_NxTx2x21x3, np.float64)
    mean = m.mean(axis=(1, 3))
    rms = np.sqrt((m ** 2).mean(axis=(1, 3)))
    return np.stack([mean, rms], -1)


def test_manifest(ds) -> dict[str, np.ndarray]:
    """ids, caption digests and motion moments of ``ds``'s test split, in clip order."""
    clips = np.sort(ds.split("test"))
    moments = np.concatenate([_moments(ds.motion[clips[s:s + 512]]) for s in range(0, len(clips), 512)]) \
        if len(clips) else np.zeros((0, 2, 3, 2))
    return {"ids": np.array([ds.texts[int(c)]["id"] for c in clips]),
            "captions": np.array([_caption_digest(ds.texts[int(c)]) for c in clips]),
            "moments": moments.astype(np.float64)}


def read_manifest(assets: Path | None = None) -> dict[str, np.ndarray]:
    with np.load(Path(assets or ASSETS) / MANIFEST, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


# ------------------------------------------------------------------------------------------------
# Identity check


def recipe_of(ds) -> tuple[Recipe | None, dict]:
    """(recipe, build options) from ``meta.json``'s ``recipe`` of a corpus built by the generator
    (``data synth`` / ``standard corpus``); (None, {}) for anything else (imports, older corpora)."""
    from handx_jax.data.build import reading_of_options

    r = ds.meta.get("recipe") or {}
    if r.get("kind") != "synth":
        return None, {}
    opts = dict(r.get("options", {}))
    return (Recipe(clips=int(r["clips"]), seed=int(r["seed"]), generator=str(r["generator_version"]),
                   annotation=reading_of_options(opts) or "custom"), opts)


def check_reference(ds, card: Mapping[str, Any] | None = None, assets: Path | None = None) -> dict:
    """Raise ``DataError`` unless ``ds`` is the standard corpus or a prefix of it; return what was found.

    Accepted: the card's recipe (generator, seed, build options) with at most its clip count, whose
    test clips are the first test clips of the standard split (same ids and captions, motion moments
    within :data:`MOTION_ATOL`) and whose train/val clips include no standard test clip. A content
    hash that differs (another numpy/jax build) is reported, not refused.
    """
    assets = Path(assets or ASSETS)
    card = card if card is not None else read_card(assets)
    want = Recipe(**card["recipe"])
    got, opts = recipe_of(ds)
    fix = (f"build it with `handx standard corpus --out DIR` (or `--clips M` for a prefix), or score with "
           f"your own evaluator (`--evaluator E`)")
    if got is None:
        raise DataError(f"not the standard corpus: its recipe {(ds.meta.get('recipe') or {}).get('kind')!r} is "
                        f"not the built-in generator's; {fix}", path=ds.root / "meta.json")
    for name, a, b in (("generator version", got.generator, want.generator), ("seed", got.seed, want.seed)):
        if a != b:
            raise DataError(f"not the standard recipe: {name} {a} where the standard evaluator (v{card['version']}) "
                            f"was trained on {b}; {fix}", path=ds.root / "meta.json")
    want_opts = card["recipe_options"]
    diff = sorted(k for k in set(opts) | set(want_opts) if opts.get(k) != want_opts.get(k))
    if diff:
        raise DataError(f"not the standard recipe: build option(s) {diff} differ from the standard's; {fix}",
                        path=ds.root / "meta.json")
    if got.clips > want.clips:
        raise DataError(f"{got.clips} clips: more than the standard corpus's {want.clips}, so its test split is not "
                        f"the standard one; {fix}", path=ds.root / "meta.json")
    man = read_manifest(assets)
    mine = test_manifest(ds)
    k = len(mine["ids"])
    if k == 0:
        raise DataError("the test split is empty", path=ds.root / "splits.json")
    if k > len(man["ids"]) or not np.array_equal(mine["ids"], man["ids"][:k]):
        bad = next((i for i in range(min(k, len(man["ids"]))) if mine["ids"][i] != man["ids"][i]), k)
        raise DataError(f"test split is not the standard one: test clip {bad} is {mine['ids'][min(bad, k - 1)]!r}, "
                        f"expected {man['ids'][bad] if bad < len(man['ids']) else 'none'}; {fix}",
                        path=ds.root / "splits.json")
    if got.clips == want.clips:  # the whole corpus: the data package's identity check (every split, caption)
        from handx_jax.data.dataset import check_compatible

        check_compatible(card["corpus"]["record"], ds, what=f"the standard evaluator v{card['version']}", fix=fix)
    cap = np.flatnonzero(mine["captions"] != man["captions"][:k])
    if cap.size:
        raise DataError(f"captions differ from the standard corpus's ({cap.size} test clips; first "
                        f"{mine['ids'][cap[0]]}); {fix}", path=ds.root / "texts.jsonl", clip=mine["ids"][cap[0]])
    dev = np.abs(mine["moments"] - man["moments"][:k]).reshape(k, -1).max(1)
    if (dev > MOTION_ATOL).any():
        i = int(np.argmax(dev))
        raise DataError(f"motion differs from the standard corpus's by {dev[i]:.2e} m (tolerance {MOTION_ATOL:g}); "
                        f"{fix}", path=ds.root / "motion.npy", clip=mine["ids"][i])
    test_ids = set(man["ids"].tolist())
    for split in ("train", "val"):
        overlap = [ds.texts[int(c)]["id"] for c in ds.split(split) if ds.texts[int(c)]["id"] in test_ids]
        if overlap:
            raise DataError(f"{len(overlap)} {split} clip(s) are standard test clips (first {overlap[0]}): the "
                            f"standard evaluator would score clips it may have been trained beside; {fix}",
                            path=ds.root / "splits.json")
    return {"prefix": got.clips < want.clips, "clips": got.clips, "test_clips": k,
            "fingerprint": ds.fingerprint, "standard_fingerprint": card["corpus"]["fingerprint"],
            "same_bytes": ds.fingerprint == card["corpus"]["fingerprint"] and got.clips == want.clips,
            "max_motion_deviation_m": float(dev.max())}


# ------------------------------------------------------------------------------------------------
# Loading


def read_card(assets: Path | None = None) -> dict:
    p = Path(assets or ASSETS) / CARD_JSON
    if not p.exists():
        raise DataError(f"the standard evaluator's card is missing (is the package installed with its assets? "
                        f"see pyproject package-data)", path=p)
    return json.loads(p.read_text())


def asset_files(assets: Path) -> list[str]:
    """Files covered by the card's checksums (everything but the card, its checksum and CARD.md), sorted."""
    return sorted(str(p.relative_to(assets)) for p in Path(assets).rglob("*")
                  if p.is_file() and p.name not in (CARD_JSON, CARD_SHA, CARD_MD) and "__pycache__" not in p.parts)


def verify_assets(assets: Path | None = None) -> dict:
    """Check the assets before anything reads them, and return the card: card.json against its sidecar
    ``card.json.sha256`` (the card holds the recipe, the Ground Truth rows and every other file's sha256,
    so it is covered first), then each file against the card. A changed or missing file is a DataError
    naming it. :func:`load` runs this on every load, packaged assets or ``assets=`` another folder."""
    assets = Path(assets or ASSETS)
    if not (assets / CARD_JSON).exists():
        read_card(assets)  # the "is the package installed with its assets?" message
    try:
        verify_checksum(assets / CARD_JSON, required=True)
    except DataError as e:
        raise DataError(f"standard evaluator card changed or unverifiable: {str(e).split(': ', 1)[-1]} "
                        "(reinstall the package)", path=assets / CARD_JSON) from None
    card = read_card(assets)
    for rel, want in card["sha256"].items():
        p = Path(assets) / rel
        if not p.exists():
            raise DataError("standard evaluator file missing (reinstall the package)", path=p)
        if sha256_file(p) != want:
            raise DataError("standard evaluator file corrupt: sha256 differs from card.json (reinstall the "
                            "package)", path=p)
    return card


def reference_cache_dir(assets: Path | None = None) -> Path:
    """Where a standard evaluator (the current one, or the archived one of ``assets``) caches reference
    embeddings: the package folder may be read-only (and an editable install should not collect cache
    files), so a user cache folder, one per version."""
    base = os.environ.get("HANDX_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "handx-jax")
    version = VERSION if assets is None or Path(assets) == ASSETS else read_card(assets)["version"]
    return Path(base) / f"standard-v{version}" / "reference_cache"


def load(assets: Path | None = None, *, batch_size: int = 256):
    """The packaged standard evaluator (a :class:`StandardEvaluator`; ``assets``: another assets folder),
    its checksums verified first (:func:`verify_assets`): a yardstick that changed is refused, always."""
    from handx_jax.evaluation import load_evaluator

    assets = Path(assets or ASSETS)
    card = verify_assets(assets)
    ev = load_evaluator(assets / EVALUATOR_DIR, encoder=assets / ENCODER_DIR, batch_size=batch_size)
    fields = {f.name: getattr(ev, f.name) for f in dataclasses.fields(ev)}
    return __getattr__("StandardEvaluator")(**fields, card=card, assets=assets)


def evaluator_dir(assets: Path | None = None) -> Path:
    """The packaged evaluator folder. Passing it as ``--evaluator`` (e.g. to ``handx sweep run``, which
    reads its ``evaluator.json`` for the caption level) selects the standard evaluator."""
    return Path(assets or ASSETS) / EVALUATOR_DIR


def archived(version: int) -> Path:
    """The assets folder of an earlier standard evaluator, kept so that old numbers can be re-scored and
    compared: ``handx_jax/assets/standard-v{version}/`` (``--evaluator standard-v{version}``)."""
    return ASSETS.with_name(f"{ASSETS.name}-v{int(version)}")


def versions() -> list[int]:
    """Every standard evaluator this package ships: the current one and the archived ones."""
    old = [int(p.name.rsplit("-v", 1)[1]) for p in ASSETS.parent.glob(f"{ASSETS.name}-v*")
           if p.name.rsplit("-v", 1)[1].isdigit() and (p / CARD_JSON).exists()]
    return sorted(set(old) | {VERSION})


def assets_for(evaluator: str | os.PathLike | None) -> Path | None:
    """The assets folder an ``--evaluator`` value names, or None for any other evaluator: omitted,
    ``standard`` or ``standard-v{VERSION}`` is the current one; ``standard-vN`` an archived one (an
    unknown N is a one-line error listing the versions); an evaluator folder of either is itself."""
    if evaluator is None or str(evaluator) in (NAME, f"{NAME}-v{VERSION}"):
        return ASSETS
    e = str(evaluator)
    if e.startswith(f"{NAME}-v") and e[len(NAME) + 2:].isdigit():
        folder = archived(int(e[len(NAME) + 2:]))
        if not (folder / CARD_JSON).exists():
            raise DataError(f"--evaluator {e}: no such standard evaluator; this package has "
                            f"{', '.join(f'{NAME}-v{v}' for v in versions())}")
        return folder
    p = Path(evaluator).resolve()
    for v in versions():
        folder = ASSETS if v == VERSION else archived(v)
        if p == (folder / EVALUATOR_DIR).resolve():
            return folder
    return None


def is_standard(evaluator: str | os.PathLike | None) -> bool:
    """``--evaluator`` omitted, ``standard``, ``standard-vN``, or a packaged evaluator folder itself."""
    return assets_for(evaluator) is not None


def evaluator_meta(evaluator: str | os.PathLike | None) -> dict:
    """``evaluator.json`` of an evaluator folder, or of a standard evaluator (see :func:`is_standard`)."""
    assets = assets_for(evaluator)
    folder = evaluator_dir(assets) if assets is not None else Path(evaluator)
    return json.loads((folder / "evaluator.json").read_text())


def encoder_dir(assets: Path | None = None) -> Path:
    """The packaged T5 encoder folder (pass it as ``--encoder`` to train models on the standard corpus)."""
    return Path(assets or ASSETS) / ENCODER_DIR


def _standard_evaluator_class():
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


def __getattr__(name: str):  # StandardEvaluator is built lazily: importing this module must not import jax
    if name == "StandardEvaluator":
        if name not in globals():
            globals()[name] = _standard_evaluator_class()
        return globals()[name]
    raise AttributeError(name)


# ------------------------------------------------------------------------------------------------
# Building the corpus and packaging the assets


def build_standard_corpus(out: str | os.PathLike, clips: int | None = None, *, workers: int = 0,
                          overwrite: bool = False, progress: bool = True, recipe: Recipe | None = None,
                          assets: Path | None = None) -> Path:
    """``handx standard corpus``: the standard recipe, or its first ``clips`` clips (a prefix)."""
    from handx_jax.data.build import build_corpus

    rec = recipe or code_recipe()
    assets = Path(assets or ASSETS)
    card = read_card(assets) if (assets / CARD_JSON).exists() else None
    if card is not None and Recipe(**card["recipe"]) != rec:
        raise DataError(f"this code's generator builds recipe {dataclasses.asdict(rec)}, but the packaged standard "
                        f"evaluator was trained on {card['recipe']}; its corpus cannot be rebuilt with this code "
                        f"(rebuild the assets: see {assets / CARD_MD})")
    n = rec.clips if clips is None else int(clips)
    if not 0 < n <= rec.clips:
        raise ValueError(f"--clips must be in [1, {rec.clips}] (the standard corpus has {rec.clips}), got {n}")
    return build_corpus(out, rec.build_config(n, workers), overwrite=overwrite, progress=progress)


def _copy_folder(src: Path, dst: Path, names: Sequence[str]) -> None:
    dst.mkdir(parents=True, exist_ok=True)
    for n in names:
        if not (src / n).exists():
            raise DataError(f"missing {n}", path=src)
        shutil.copy2(src / n, dst / n)


def package(data: str | os.PathLike, encoder: str | os.PathLike, evaluator: str | os.PathLike,
            out: str | os.PathLike | None = None, *, training: Mapping[str, Any] | None = None,
            replications: int = 20, blocks: Sequence[int] = (32, 16), recipe: Recipe | None = None,
            validity: Mapping[str, Any] | None = None, log=print) -> Path:
    """Copy the encoder and evaluator trained on the standard corpus ``data`` into ``out``, score the
    Ground Truth rows (blocks 32 and 16) on the full test split, and write the manifest and the card."""
    from handx_jax.data.dataset import Dataset
    from handx_jax.evaluation import EVAL_FILE, META_FILE, PARAMS_FILE, STATS_FILE, evaluate_ground_truth, \
        read_meta
    from handx_jax.metrics import MetricConfig

    ds = Dataset.open(data)
    rec, opts = recipe_of(ds)
    want = recipe or code_recipe()
    if rec != want or opts != build_options(want):
        raise DataError(f"{data} is not this code's standard corpus: recipe {rec}, expected {want}"
                        + ("" if opts == build_options(want) else " (build options differ)"), path=data)
    meta = read_meta(evaluator)
    if meta["dataset"]["fingerprint"] != ds.fingerprint:
        raise DataError(f"the evaluator was trained on dataset {meta['dataset']['fingerprint']}, not {data} "
                        f"({ds.fingerprint})", path=evaluator)
    out = Path(out or ASSETS)
    tmp = out.with_name(f".{out.name}.packaging")
    if tmp.exists():
        shutil.rmtree(tmp)
    enc_src = Path(encoder)
    _copy_folder(enc_src, tmp / ENCODER_DIR, sorted(p.name for p in enc_src.iterdir() if p.is_file()))
    _copy_folder(Path(evaluator), tmp / EVALUATOR_DIR, [PARAMS_FILE, STATS_FILE])
    # evaluator.json: paths made relative to the package (they pointed into the maintainer's machine).
    meta = dict(meta)
    meta["dataset"] = {**meta["dataset"], "path": f"standard corpus v{VERSION} (handx standard corpus)"}
    meta["encoder"] = {**meta["encoder"], "path": ENCODER_DIR}
    atomic_write_json(tmp / EVALUATOR_DIR / META_FILE, meta)
    man = test_manifest(ds)
    np.savez_compressed(tmp / MANIFEST, **man)
    from handx_jax.data.dataset import dataset_record

    card = {"version": VERSION, "recipe": dataclasses.asdict(rec), "recipe_options": opts,
            "corpus": {"record": dataset_record(ds), "fingerprint": ds.fingerprint, "clips": len(ds), "split_sizes": ds.meta["split_sizes"],
                       "build_seconds": ds.report.get("seconds"), "test_clips": len(man["ids"])},
            "evaluator": {"preset": meta["preset"], "params": meta["params"], "config": meta["evaluator_config"],
                          "text": meta["text"], "training": meta["training"],
                          "encoder_fingerprint": meta["encoder"]["fingerprint"],
                          "tokenizer_fingerprint": meta["encoder"]["tokenizer_fingerprint"]},
            "training_run": dict(training or {}),
            "validity": validity_summary(validity) if validity else None,
            "packaged": {"machine": f"{platform.machine()}, {os.cpu_count()} CPU cores, "
                                    f"{_accelerator() or 'no accelerator'}",
                         "python": sys.version.split()[0], "numpy": np.__version__, "jax": _jax_version(),
                         "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime())},
            "sha256": {}}
    card["sha256"] = {rel: sha256_file(tmp / rel) for rel in asset_files(tmp)}
    atomic_write_json(tmp / CARD_JSON, card)
    write_checksum(tmp / CARD_JSON)
    # Score the GT rows with the packaged copy, through the same check users go through.
    ev = load(tmp)
    rows = {}
    for block in blocks:
        t0 = time.perf_counter()
        res = evaluate_ground_truth(ev, ds, MetricConfig(rprec_block=block, replications=replications), cache=False)
        rows[str(block)] = {**res.flat(), "prompts": res.meta["prompts"], "replications": replications,
                            "ci_method": res.meta.get("ci_method", {}).get("rprec_top1"),
                            "bootstrap": res.meta.get("bootstrap"), "seconds": round(time.perf_counter() - t0, 1)}
        log(f"GT block {block}: top-1 {rows[str(block)]['rprec_top1']:.3f} top-3 {rows[str(block)]['rprec_top3']:.3f}")
    card["ground_truth"] = rows
    atomic_write_json(tmp / CARD_JSON, card)
    atomic_write_json(tmp / EVALUATOR_DIR / EVAL_FILE,
                      {**rows[str(blocks[0])], "_meta": {"split": "test", "block": blocks[0]}})
    card["sha256"] = {rel: sha256_file(tmp / rel) for rel in asset_files(tmp)}
    atomic_write_json(tmp / CARD_JSON, card)
    write_checksum(tmp / CARD_JSON)
    atomic_write_text(tmp / CARD_MD, card_markdown(card))
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)
    return out


def _accelerator() -> str | None:
    """The accelerator JAX runs on (e.g. 'NVIDIA H200'), or None on CPU."""
    try:
        import jax

        if jax.default_backend() == "cpu":
            return None
        return str(jax.devices()[0].device_kind)
    except Exception:  # noqa: BLE001 - packaging must not fail on a missing backend
        return None


def _jax_version() -> str:
    try:
        import jax

        return jax.__version__
    except Exception:  # noqa: BLE001
        return "?"


def _row(r: Mapping[str, Any]) -> str:
    f = lambda k: f"{r[k]:.3f} ± {r[k + '_ci']:.3f}"  # noqa: E731
    return f"{f('rprec_top1')} | {f('rprec_top2')} | {f('rprec_top3')} | {f('mm_dist')} | {f('diversity')}"


def _ci_note(gt: Mapping[str, Any]) -> str:
    """What the rows' ± is (``metrics.ci_method``): the GT row is one group, so a prompt bootstrap."""
    r = next(iter(gt.values()), {})
    reps, boot = r.get("replications", "?"), r.get("bootstrap") or 200
    if r.get("ci_method", "bootstrap_prompts") == "bootstrap_prompts":
        return (f"Point values average {reps} re-blockings of the prompts; ± is a 95% interval for the mean: 1.96 × "
                f"the spread over {boot} bootstrap resamples of the test prompts (`handx_jax/metrics.py`, "
                f"`ci_method` `bootstrap_prompts`).")
    return f"± is a 95% interval (`ci_method` `{r.get('ci_method')}`, `handx_jax/metrics.py`)."


def add_validity(assets: Path, report: Mapping[str, Any]) -> dict:
    """Put a validity report's figures (``handx standard validity`` with this very evaluator, which
    accepts prefixes of its corpus only once packaged) on an assets folder's card: card.json, its
    checksum and CARD.md. The other files, and so their checksums, are untouched."""
    assets = Path(assets)
    card = verify_assets(assets)
    card["validity"] = validity_summary(report)
    atomic_write_json(assets / CARD_JSON, card)
    write_checksum(assets / CARD_JSON)
    atomic_write_text(assets / CARD_MD, card_markdown(card))
    return card


def validity_summary(report: Mapping[str, Any]) -> dict:
    """What the card keeps of a validity report (``handx standard validity``): per case, the top-3
    ratio to the ground truth's, FID and the level-0 captions left unchanged."""
    rows = []
    for c in list(report.get("cases", [])) + list(report.get("tokenizers", [])):
        name = c.get("label") or f"tokenizer {Path(str(c.get('tokenizer'))).name} reconstruction"
        if c.get("amplitude_mm"):
            name += f", {c['amplitude_mm']:g} mm"
        rows.append({"case": name, "mean_shift_mm": round(c["mean_shift_mm"], 2),
                     "top3_ratio": round(c["top3_ratio"], 3) if "top3_ratio" in c else None,
                     "fid": round(c["eval_fid"], 3) if "eval_fid" in c else None,
                     "level0_unchanged": round(c["captions_unchanged"][0], 3),
                     "events_unchanged": round(c["events_unchanged"], 3)})
    gt = report.get("ground_truth") or {}
    return {"test_clips": report.get("test_clips"), "block": report.get("block"), "annotation": report.get("annotation"),
            "ground_truth_top3": gt.get("rprec_top3"), "rows": rows}


def card_markdown(card: Mapping[str, Any]) -> str:
    """CARD.md from card.json (one source of truth)."""
    rec, c, e, tr = card["recipe"], card["corpus"], card["evaluator"], card.get("training_run", {})
    t = e["training"]
    gt = card.get("ground_truth", {})
    lines = [
        f"# Standard evaluator v{card['version']}",
        "",
        "The evaluator `handx eval run` uses when no `--evaluator` is given. Its identity is the corpus recipe:",
        "",
        f"- generator version **{rec['generator']}**, seed **{rec['seed']}**, **{rec['clips']:,}** clips, default "
        f"build options (`handx standard corpus --out DIR` = `handx data synth --clips {rec['clips']} --seed "
        f"{rec['seed']} --annotation {rec.get('annotation', 'reference')}`)",
        f"- splits {c['split_sizes']}; content hash on the packaging machine `{c['fingerprint']}` (another "
        f"numpy/jax build may give other float bytes: the check compares ids, captions and motion within "
        f"{MOTION_ATOL:g} m instead)",
        f"- a corpus of the first M clips (`--clips M`) is a *prefix*: its train split lies inside the standard "
        f"train split and its test split is the first test clips of the standard one; it is accepted, so small "
        f"experiments (`make demo`) are scored on a subset of the same test split",
        "",
        "## Training",
        "",
        f"- evaluator preset `{e['preset']}`, {e['params']:,} parameters, motion input "
        f"`{e['config'].get('motion_input')}`, latent {e['config'].get('latent')}; frozen tiny T5 text encoder "
        f"(`encoder/`, fingerprint `{e['encoder_fingerprint']}`, tokenizer `{e['tokenizer_fingerprint']}`)",
        f"- {t['steps']:,} steps × batch {t['batch_size']}, AdamW lr {t['lr']:g}, warm-up {t['warmup']}, "
        f"{t['schedule']} decay, weight decay {t['weight_decay']:g}, caption level(s) "
        f"{e['text'].get('train_levels')}, scored at level {e['text'].get('eval_level')}",
    ]
    for k, v in tr.items():
        lines.append(f"- {k}: {v}")
    lines += [
        f"- packaged on: {card['packaged']['machine']}; python {card['packaged']['python']}, numpy "
        f"{card['packaged']['numpy']}, jax {card['packaged']['jax']}; {card['packaged']['date_utc']} UTC",
        "",
        f"## Ground Truth rows (standard test split, level-{e['text'].get('eval_level', 0)} captions)",
        "",
        _ci_note(gt),
        "",
        "| block | top-1 | top-2 | top-3 | MM-Dist | Diversity |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for b, r in gt.items():
        lines.append(f"| {b} | {_row(r)} |")
    lines += ["", f"{c['test_clips']:,} test prompts. Reproduce: `handx eval run --ground-truth --data DIR "
              f"[--block 16]` on the standard corpus.", ""]
    v = card.get("validity")
    if v:
        lines += ["## Validity (`handx standard validity`, docs/validity.md)", "",
                  f"{v['test_clips']} test clips of a prefix, block {v['block']}, annotation `{v['annotation']}`; ground "
                  f"truth top-3 {v['ground_truth_top3']:.3f}.", "",
                  "| ground truth, perturbed | mean shift (mm) | top-3 × GT | FID | level-0 captions unchanged |",
                  "| --- | ---: | ---: | ---: | ---: |"]
        for r in v["rows"]:
            ratio = "–" if r["top3_ratio"] is None else f"{r['top3_ratio']:.2f}"
            fid = "–" if r["fid"] is None else f"{r['fid']:.2f}"
            lines.append(f"| {r['case']} | {r['mean_shift_mm']:.1f} | {ratio} | {fid} | {r['level0_unchanged']:.2f} |")
        lines.append("")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------
# CLI: handx standard ...


def _info(a: argparse.Namespace) -> int:
    card = read_card()
    if a.json:
        json.dump({k: v for k, v in card.items() if k != "sha256"}, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(card_markdown(card))
        print(f"assets: {ASSETS}")
    return 0


def _usage_error(e: Exception) -> int:
    print(f"handx: error: {e}", file=sys.stderr)
    return 2


def _corpus(a: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    try:
        out = build_standard_corpus(a.out, a.clips, workers=a.workers, overwrite=a.force, progress=not a.quiet)
    except ValueError as e:  # a --clips outside the recipe: one line, no traceback
        return _usage_error(e)
    print(f"wrote {out} ({time.perf_counter() - t0:.0f} s)")
    return 0


def _check(a: argparse.Namespace) -> int:
    from handx_jax.data.dataset import Dataset

    found = check_reference(Dataset.open(a.data))
    if a.json:
        json.dump(found, sys.stdout)
        sys.stdout.write("\n")
    else:
        kind = "a prefix of the standard corpus" if found["prefix"] else "the standard corpus"
        note = "" if found["same_bytes"] or found["prefix"] else (
            f" (content hash {found['fingerprint']} differs from the packaging machine's "
            f"{found['standard_fingerprint']}: float rounding of another build, within tolerance)")
        print(f"{a.data}: {kind}, {found['clips']} clips, {found['test_clips']} standard test clips; max motion "
              f"deviation {found['max_motion_deviation_m']:.1e} m{note}")
    return 0


def _package(a: argparse.Namespace) -> int:
    training = dict(kv.split("=", 1) for kv in a.note)
    recipe = None
    if a.recipe_clips is not None:
        if a.out is None:
            return _usage_error("--recipe-clips packages a dry run: give --out (the package's own assets are "
                                "the standard recipe's)")
        if a.recipe_clips < 1:
            return _usage_error(f"--recipe-clips must be 1 or more, got {a.recipe_clips}")
        recipe = dataclasses.replace(code_recipe(), clips=int(a.recipe_clips))
    validity = None
    if a.validity:
        try:
            validity = json.loads(Path(a.validity).read_text())
        except (OSError, json.JSONDecodeError) as e:
            return _usage_error(f"--validity {a.validity}: {e}")
    if a.validity_only:  # the figures of an already packaged evaluator (the suite needs it packaged)
        if validity is None:
            return _usage_error("--validity-only needs --validity FILE")
        add_validity(Path(a.out or ASSETS), validity)
        print(f"wrote the validity figures on {Path(a.out or ASSETS) / CARD_JSON}")
        return 0
    missing = [f"--{k}" for k in ("data", "encoder", "evaluator") if not getattr(a, k)]
    if missing:
        return _usage_error(f"handx standard package needs {', '.join(missing)} (or --validity-only)")
    out = package(a.data, a.encoder, a.evaluator, a.out, training=training, replications=a.replications,
                  recipe=recipe, validity=validity)
    print(f"wrote {out}")
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("standard", help="the packaged standard evaluator and its corpus",
                              description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="standard_command", metavar="SUBCOMMAND")
    sub.required = True
    i = sub.add_parser("info", help="print the standard evaluator's card (recipe, training, GT rows)")
    i.add_argument("--json", action="store_true")
    i.set_defaults(func=_info)
    c = sub.add_parser("corpus", help="build the standard corpus, or its first --clips M clips (a prefix)")
    c.add_argument("--out", required=True, help="dataset directory to create")
    c.add_argument("--clips", type=int, help="build only the first M clips (default: the whole standard corpus)")
    c.add_argument("--workers", type=int, default=0, help="processes (0 = one per core)")
    c.add_argument("--force", action="store_true", help="replace an existing dataset directory")
    c.add_argument("--quiet", action="store_true", help="no progress bar")
    c.set_defaults(func=_corpus)
    k = sub.add_parser("check", help="is a dataset the standard corpus (or a prefix)? if not, say why and exit 2")
    from handx_jax.cliargs import deprecated_positional

    deprecated_positional(k, k.add_argument("--data", required=True, metavar="DIR", help="dataset directory"), "data")
    k.add_argument("--json", action="store_true")
    k.set_defaults(func=_check)
    g = sub.add_parser("package", help="(maintainers) copy a trained encoder + evaluator into the package assets")
    g.add_argument("--data", help="the standard corpus the evaluator was trained on (required but with --validity-only)")
    g.add_argument("--encoder", help="its T5 encoder folder (required but with --validity-only)")
    g.add_argument("--evaluator", help="its evaluator folder (required but with --validity-only)")
    g.add_argument("--out", help="assets folder (default: the package's)")
    g.add_argument("--replications", type=int, default=20)
    g.add_argument("--note", action="append", default=[], metavar="KEY=VALUE",
                   help="a line for the card's training section, e.g. 'corpus build=612 s on 2 cores'")
    g.add_argument("--recipe-clips", type=int, metavar="N",
                   help="(dry runs of the pipeline) package against the first N clips of the recipe instead of the "
                        "whole standard corpus; needs --out")
    g.add_argument("--validity", metavar="FILE", help="a validity.json of this evaluator (handx standard validity): "
                                                      "its figures go on the card")
    g.add_argument("--validity-only", action="store_true",
                   help="only put --validity's figures on the card of the already packaged assets (--out)")
    g.set_defaults(func=_package)
