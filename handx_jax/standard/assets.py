"""The assets of the standard evaluator: their version and folders (the packaged current one; the earlier
``standard-vN`` ones, kept in a clone's ``evaluators/`` and not installed), the card, and the checksums every
load verifies. Which ``--evaluator`` values name one of them: :mod:`handx_jax.standard.naming`."""

from __future__ import annotations

import os
from pathlib import Path

from handx_jax.infra.checksums import sha256_file, verify_checksum
from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_json

VERSION = 8  # of the packaged assets; bumped whenever the recipe or any weight changes
ASSETS = Path(__file__).resolve().parent.parent / "assets" / "standard"  # handx_jax/assets/standard
CARD_JSON, CARD_MD, MANIFEST = "card.json", "CARD.md", "test_manifest.npz"
CARD_SHA = CARD_JSON + ".sha256"  # infra.checksums.write_checksum's sidecar: the card's own checksum
ENCODER_DIR, EVALUATOR_DIR = "encoder", "evaluator"
NAME = "standard"  # `handx eval run --evaluator standard` (the default)
# The earlier standard evaluators (v4-v7), out of the package (issue 51 item 4): a clone's evaluators/ folder,
# beside handx_jax/. From an installed wheel it does not exist, and their names say where to find them.
ARCHIVE = Path(__file__).resolve().parents[2] / "evaluators"


def assets_folder(assets: Path | None = None) -> Path:
    """``assets``, or the packaged assets folder. ``ASSETS`` is read when called, not imported by the other
    modules, so pointing this module's ``ASSETS`` elsewhere (a test's copy) moves every reader with it."""
    return Path(assets or ASSETS)

def read_card(assets: Path | None = None) -> dict:
    p = assets_folder(assets) / CARD_JSON
    if not p.exists():
        raise DataError(f"the standard evaluator's card is missing (is the package installed with its assets? "
                        f"see pyproject package-data)", path=p)
    return read_json(p, expect=dict)


def asset_files(assets: Path) -> list[str]:
    """Files covered by the card's checksums (everything but the card, its checksum and CARD.md), sorted."""
    return sorted(str(p.relative_to(assets)) for p in Path(assets).rglob("*")
                  if p.is_file() and p.name not in (CARD_JSON, CARD_SHA, CARD_MD) and "__pycache__" not in p.parts)


def verify_assets(assets: Path | None = None) -> dict:
    """Check the assets before anything reads them, and return the card: card.json against its sidecar
    ``card.json.sha256`` (the card holds the recipe, the Ground Truth rows and every other file's sha256,
    so it is covered first), then each file against the card. A changed or missing file is a DataError
    naming it. :func:`load` runs this on every load, packaged assets or ``assets=`` another folder."""
    assets = assets_folder(assets)
    if not (assets / CARD_JSON).exists():
        read_card(assets)  # the "is the package installed with its assets?" message
    try:
        verify_checksum(assets / CARD_JSON, required=True)
    except DataError as e:
        raise DataError(f"standard evaluator card changed or unverifiable: {str(e).split(': ', 1)[-1]} "
                        "(reinstall the package)", path=assets / CARD_JSON) from None
    card = read_card(assets)
    for rel, want in card["sha256"].items():
        p = asset_path(assets, rel)
        if not p.exists():
            raise DataError("standard evaluator file missing (reinstall the package)", path=p)
        if sha256_file(p) != want:
            raise DataError("standard evaluator file corrupt: sha256 differs from card.json (reinstall the "
                            "package)", path=p)
    return card


def asset_path(assets: Path, rel: str) -> Path:
    """Where the file ``rel`` of a card's checksums is: in ``assets``, except the text encoder of an archived
    version, which is the packaged one (byte-identical since v4, so stored once; the card's sha256 of each
    encoder file is still checked against it)."""
    if rel.startswith(ENCODER_DIR + "/"):
        return encoder_dir(assets) / rel[len(ENCODER_DIR) + 1:]
    return Path(assets) / rel


def reference_cache_dir(assets: Path | None = None) -> Path:
    """Where a standard evaluator (the current one, or the archived one of ``assets``) caches reference
    embeddings: the package folder may be read-only (and an editable install should not collect cache
    files), so a user cache folder, one per version."""
    base = os.environ.get("HANDX_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "handx-jax")
    version = VERSION if assets is None or Path(assets) == ASSETS else read_card(assets)["version"]
    return Path(base) / f"standard-v{version}" / "reference_cache"


def evaluator_dir(assets: Path | None = None) -> Path:
    """The packaged evaluator folder. Passing it as ``--evaluator`` (e.g. to ``handx sweep run``, which
    reads its ``evaluator.json`` for the caption level) selects the standard evaluator."""
    return assets_folder(assets) / EVALUATOR_DIR


def archived(version: int) -> Path:
    """The assets folder of an earlier standard evaluator, kept so that old numbers can be re-scored and
    compared: ``evaluators/standard-v{version}/`` of a clone (``--evaluator standard-v{version}``)."""
    return ARCHIVE / f"{NAME}-v{int(version)}"


def version_folder(version: int) -> Path:
    """The assets folder of standard evaluator ``version``: the packaged one for the current version, else
    its archive."""
    return ASSETS if int(version) == VERSION else archived(version)


def versions() -> list[int]:
    """Every standard evaluator at hand: the packaged one and the archived ones a clone holds."""
    old = [int(p.name.rsplit("-v", 1)[1]) for p in ARCHIVE.glob(f"{NAME}-v*")
           if p.name.rsplit("-v", 1)[1].isdigit() and (p / CARD_JSON).exists()]
    return sorted(set(old) | {VERSION})


def encoder_dir(assets: Path | None = None) -> Path:
    """The packaged T5 encoder folder (pass it as ``--encoder`` to train models on the standard corpus); an
    archived version without its own ``encoder/`` uses the packaged one (:func:`asset_path`)."""
    own = assets_folder(assets) / ENCODER_DIR
    return own if own.is_dir() or assets is None else ASSETS / ENCODER_DIR
