"""The standard evaluator (issue 13 item 1): packaging, the recipe identity check (prefix corpora
accepted, float rounding accepted, another recipe / moved test clip / changed caption refused), and
`handx eval run` without --evaluator resolving to it. A 120-clip stand-in recipe and the tiny T5
fixture keep this to seconds; the last test checks the assets the package really ships."""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from handx_jax import standard
from handx_jax.standard import assets as standard_assets
from handx_jax.dataset.format import Dataset
from handx_jax.evaluation import evaluate_ground_truth, make_evaluator_config, train_evaluator
from handx_jax.infra.checksums import sha256_file, write_checksum
from handx_jax.infra.errors import DataError
from handx_jax.metrics import MetricConfig

ENCODER = Path(__file__).parent / "fixtures" / "t5_tiny_gated"
# The recipe these tests package their own assets from: corpus v1's reading and motion, named (they were
# Recipe()'s defaults when the seed was picked: test sequences 0 and 3).
RECIPE = standard.Recipe(clips=120, seed=48, generator=standard.generator_version(), annotation="reference",
                         motion="oscillate")


@pytest.fixture(scope="module")
def std(tmp_path_factory):
    root = tmp_path_factory.mktemp("standard")
    full = standard.build_standard_corpus(root / "full", recipe=RECIPE, assets=root / "none", workers=1,
                                          progress=False)
    prefix = standard.build_standard_corpus(root / "prefix", 70, recipe=RECIPE, assets=root / "none", workers=1,
                                            progress=False)
    cfg = make_evaluator_config("tiny", ["train.steps=20", "train.batch_size=8", "train.optim.lr=1e-3",
                                         "train.optim.warmup_steps=0", "train.wandb=disabled", "final_eval=false",
                                         "text.max_len=64", "text.train_levels=0", "text.eval_level=0"],
                                data=str(full), encoder=str(ENCODER))
    E = train_evaluator(root / "E", cfg, log=lambda s: None)
    assets = standard.package(full, ENCODER, E, root / "assets", recipe=RECIPE, replications=3, blocks=(4, 2),
                              training={"steps": "20 (test)"}, log=lambda s: None)
    return root, Dataset.open(full), Dataset.open(prefix), assets


def _copy(ds, dst: Path) -> Path:
    shutil.copytree(ds.root, dst)
    return dst


def test_package_writes_card_manifest_and_relative_paths(std):
    root, full, prefix, assets = std
    card = standard.read_card(assets)
    assert card["recipe"] == dataclasses.asdict(RECIPE)
    assert card["corpus"]["fingerprint"] == full.fingerprint and card["corpus"]["clips"] == 120
    assert set(card["ground_truth"]) == {"4", "2"}
    # GT rows: a finite R-Precision, top-3 ≥ top-1, smaller block easier (fewer distractors)
    g4, g2 = card["ground_truth"]["4"], card["ground_truth"]["2"]
    assert 0 < g4["rprec_top1"] <= g4["rprec_top3"] <= 1 and g2["rprec_top1"] >= g4["rprec_top1"] - 0.15
    man = standard.read_manifest(assets)
    test_ids = [full.texts[int(c)]["id"] for c in np.sort(full.split("test"))]
    assert man["ids"].tolist() == test_ids and man["moments"].shape == (len(test_ids), 2, 3, 2)
    meta = json.loads((assets / "evaluator" / "evaluator.json").read_text())
    assert meta["encoder"]["path"] == "encoder"  # nothing points into the packaging machine
    assert card["packaged"]["machine"].endswith("CPU cores, no accelerator")  # JAX_PLATFORMS=cpu
    standard.verify_assets(assets)
    assert (assets / "card.json.sha256").read_text().split()[0] == sha256_file(assets / "card.json")
    (assets / "test_manifest.npz").write_bytes((assets / "test_manifest.npz").read_bytes() + b"x")
    with pytest.raises(DataError, match="corrupt"):
        standard.verify_assets(assets)
    np.savez_compressed(assets / "test_manifest.npz", **man)  # restore (same content, maybe other bytes)
    card["sha256"]["test_manifest.npz"] = sha256_file(assets / "test_manifest.npz")
    (assets / "card.json").write_text(json.dumps(card))
    with pytest.raises(DataError, match="card.json: standard evaluator card changed"):
        standard.verify_assets(assets)  # the card is covered too (issue 31)
    write_checksum(assets / "card.json")
    standard.verify_assets(assets)
    assert "| 4 |" in standard.card_markdown(card) and "generator version" in standard.card_markdown(card)


def test_prefix_is_a_subset_with_the_first_standard_test_clips(std):
    root, full, prefix, assets = std
    ids = full.ids
    assert prefix.ids == ids[:70]  # chunks depend on (seed, chunk) only
    for split in ("train", "val", "test"):
        assert set(prefix.split(split).tolist()) == {int(c) for c in full.split(split) if c < 70}
    found = standard.check_reference(prefix, assets=assets)
    assert found["prefix"] and found["test_clips"] == int((full.split("test") < 70).sum()) > 0
    assert found["max_motion_deviation_m"] == 0.0
    assert standard.check_reference(full, assets=assets)["same_bytes"]


def test_float_rounding_accepted_other_content_refused(std, tmp_path):
    root, full, prefix, assets = std
    d = _copy(prefix, tmp_path / "rounded")
    m = np.load(d / "motion.npy")
    np.save(d / "motion.npy", m + np.float32(2e-6))  # another build's rounding: new bytes, same content
    found = standard.check_reference(Dataset.open(d), assets=assets)
    assert 0 < found["max_motion_deviation_m"] < standard.MOTION_ATOL
    np.save(d / "motion.npy", m + np.float32(5e-3))  # 5 mm: a different generator
    with pytest.raises(DataError, match="motion differs"):
        standard.check_reference(Dataset.open(d), assets=assets)


def test_other_recipe_moved_test_clip_or_changed_caption_refused(std, tmp_path):
    root, full, prefix, assets = std
    d = _copy(prefix, tmp_path / "seed")
    meta = json.loads((d / "meta.json").read_text())
    meta["recipe"]["seed"] = 4
    (d / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match="seed 4"):
        standard.check_reference(Dataset.open(d), assets=assets)
    d = _copy(prefix, tmp_path / "opts")
    meta = json.loads((d / "meta.json").read_text())
    meta["recipe"]["options"]["test_fraction"] = 0.1
    (d / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match="test_fraction"):
        standard.check_reference(Dataset.open(d), assets=assets)
    d = _copy(prefix, tmp_path / "split")  # one standard test clip moved into train
    sp = json.loads((d / "splits.json").read_text())
    sp["train"].append(sp["test"].pop(0))
    (d / "splits.json").write_text(json.dumps(sp))
    with pytest.raises(DataError, match="test split is not the standard one"):
        standard.check_reference(Dataset.open(d), assets=assets)
    d = _copy(prefix, tmp_path / "caption")
    lines = (d / "texts.jsonl").read_text().splitlines()
    i = int(prefix.split("test")[0])
    t = json.loads(lines[i])
    t["left"][0] = "The left hand waves."
    lines[i] = json.dumps(t)
    (d / "texts.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match="captions differ"):
        standard.check_reference(Dataset.open(d), assets=assets)


def test_eval_run_without_evaluator_uses_the_standard_one(std, monkeypatch, tmp_path, capsys):
    from handx_jax.cli import main

    root, full, prefix, assets = std
    monkeypatch.setattr(standard_assets, "ASSETS", assets)
    monkeypatch.setenv("HANDX_CACHE_DIR", str(tmp_path / "cache"))
    assert main(["eval", "run", "--ground-truth", "--data", str(prefix.root), "--block", "2",
                 "--replications", "3", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)
    ev = standard.load()
    assert isinstance(ev, standard.StandardEvaluator)
    want = evaluate_ground_truth(ev, prefix, MetricConfig(rprec_block=2, replications=3), cache=False).flat()
    assert row["rprec_top1"] == pytest.approx(want["rprec_top1"]) and row["fid"] == pytest.approx(want["fid"])
    assert list((tmp_path / "cache" / f"standard-v{standard.VERSION}" / "reference_cache").glob("*.npz"))
    # eval.json names the yardstick: standard-vN and the packaged folder's id
    assert main(["eval", "run", "--ground-truth", "--data", str(prefix.root), "--block", "2",
                 "--replications", "3", "--json", "--out", str(tmp_path / "run")]) == 0
    meta = json.loads((tmp_path / "run" / "eval.json").read_text())["_meta"]
    from handx_jax.evaluation import evaluator_id

    assert meta["evaluator_name"] == f"standard-v{standard.VERSION}"
    assert meta["evaluator_id"] == evaluator_id(assets / "evaluator")
    # the same call on a corpus of another seed is refused with the reason, exit non-zero
    d = _copy(prefix, tmp_path / "other")
    meta = json.loads((d / "meta.json").read_text())
    meta["recipe"]["seed"] = 9
    (d / "meta.json").write_text(json.dumps(meta))
    assert main(["eval", "run", "--ground-truth", "--data", str(d), "--json"]) != 0
    assert "not the standard recipe" in capsys.readouterr().err


def test_packaged_standard_evaluator_matches_this_code():
    """The assets the package ships: present, intact, trained on the recipe this code builds."""
    card = standard.read_card()
    assert standard.Recipe.from_card(card["recipe"]) == standard.code_recipe()
    assert card["recipe_options"] == standard.build_options(standard.code_recipe())
    rec = standard.code_recipe()  # the card's reproduction command builds this recipe
    assert (f"`handx data synth --clips {rec.clips} --seed {rec.seed} --annotation {rec.annotation} --motion {rec.motion}`"
            in (standard.ASSETS / standard.CARD_MD).read_text())
    standard.verify_assets()
    assert {"32", "16"} <= set(card["ground_truth"])
    total = sum(p.stat().st_size for p in standard.ASSETS.rglob("*") if p.is_file())
    assert total < 10e6, f"standard assets are {total / 1e6:.1f} MB"
    ev = standard.load()
    man = standard.read_manifest()
    assert ev.cfg.latent > 0 and len(man["ids"]) == card["corpus"]["test_clips"]


def test_package_recipe_clips_is_a_dry_run_of_a_prefix(std, monkeypatch, tmp_path, capsys):
    """`handx standard package --recipe-clips N` packages against the first N clips of this code's recipe (a
    dry run of the maintainers' pipeline, e.g. scripts/gpu_lease.sh on a CPU), never into the package's own
    assets; bad uses are one line and exit 2, not a traceback."""
    from handx_jax.cli import main

    root, full, prefix, assets = std
    seen = {}
    monkeypatch.setattr(standard, "code_recipe", lambda: RECIPE)
    monkeypatch.setattr(standard, "package", lambda *a, **k: seen.update(args=a, **k) or Path(a[3]))
    base = ["standard", "package", "--data", str(full.root), "--encoder", str(ENCODER), "--evaluator", str(root / "E")]
    assert main([*base, "--recipe-clips", "70", "--out", str(tmp_path / "dry")]) == 0
    assert seen["recipe"] == dataclasses.replace(RECIPE, clips=70) and seen["args"][3] == str(tmp_path / "dry")
    assert seen["version"] is None  # the card says this code's VERSION
    seen.clear()
    # The next evaluator before the code names it the standard one (scripts/build_standard_v8.sh): v8 on corpus v5.
    assert main([*base, "--corpus", "v5", "--version", "8", "--recipe-clips", "70", "--out", str(tmp_path / "dry")]) == 0
    assert seen["recipe"] == dataclasses.replace(standard.corpus_recipe("v5"), clips=70) and seen["version"] == 8
    seen.clear()
    assert main(base + ["--recipe-clips", "70"]) == 2 and not seen
    assert "give --out" in capsys.readouterr().err
    assert main([*base, "--recipe-clips", "0", "--out", str(tmp_path / "dry")]) == 2 and not seen
    err = capsys.readouterr().err
    assert err.startswith("handx: error: --recipe-clips must be 1 or more") and "Traceback" not in err
    # and the real packaging of a recipe that is not the corpus's is refused, naming both
    monkeypatch.undo()
    with pytest.raises(DataError, match="clips=70"):
        standard.package(full.root, ENCODER, root / "E", tmp_path / "x", recipe=dataclasses.replace(RECIPE, clips=70))


def test_standard_corpus_outside_the_recipe_is_one_line(tmp_path, capsys):
    from handx_jax.cli import main

    n = standard.code_recipe().clips
    assert main(["standard", "corpus", "--clips", str(n + 1), "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"handx: error: --clips must be in [1, {n}]") and "Traceback" not in err
    assert not (tmp_path / "c").exists()
