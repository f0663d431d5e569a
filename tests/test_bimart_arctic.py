"""Object to motion from ARCTIC's layout, end to end (issue 53 item 4): a procedural clip written as an ARCTIC release
(interop/arctic.py: the object template, a 130-frame trajectory, ARCTIC's processed joints), a tiny trained BimArt
run (contact step and motion run, 2 steps each), ``handx generate --task object2motion --arctic ROOT --seq S`` over
its 60-frame windows, and ``handx eval objects`` scoring the file with the ARCTIC folder gone (the file carries the
mesh). Marked e2e: it trains two models and scores hands against a mesh (make test-e2e)."""

import shutil

import numpy as np
import pytest

from handx_jax.cli import main
from handx_jax.evaluation import object_clips
from handx_jax.interop import arctic as A

SEQ = "s01/cabinet_use_01"
TINY = ("model.block.layers=1", "model.block.dim=32", "model.block.heads=2", "model.block.ff=64", "model.keypoints=8",
        "model.steps=4", "train.steps=2", "train.batch_size=2", "train.log_every=1", "train.ckpt_every=2",
        "train.wandb=disabled")


@pytest.fixture(scope="module")
def arctic_run(tmp_path_factory):
    from handx_jax.dataset.format import Dataset
    from handx_jax.synthesis.object_build import (ObjectBuildConfig, build_object_corpus, clip_object,
                                                  open_object_annotations)
    from handx_jax.synthesis.object_motion import ObjectSynthConfig

    tmp = tmp_path_factory.mktemp("bimart_arctic")
    # test_bimart.py's one-clip corpus, its clip in the train split (the same motion: the split does not seed it).
    cfg = ObjectBuildConfig(clips=1, seed=5, workers=1, bps_k=16, val_fraction=0.01, test_fraction=0.01,
                            synth=ObjectSynthConfig(chunk_size=2))
    obj = build_object_corpus(tmp / "obj", cfg, progress=False)
    sets = [x for kv in TINY for x in ("--set", kv)]
    assert main(["train", "bimart-contact", "--data", str(obj), "--preset", "tiny", *sets, "--set", "model.k=16",
                 "--out", str(tmp / "contact")]) == 0
    assert main(["train", "bimart", "--data", str(obj), "--bimart-contact", str(tmp / "contact"), "--preset", "tiny",
                 *sets, "--out", str(tmp / "run")]) == 0
    ann, ds = open_object_annotations(obj), Dataset.open(obj)
    record = ann["objects"][0]
    root = tmp / "arctic"
    A.write_object(root, record["category"], clip_object(record), k=24)
    s, j = np.asarray(ann["object_state"][0], np.float64), np.asarray(ds.motion[0], np.float64)
    states, joints = np.concatenate([s, s[::-1], s[:10]]), np.concatenate([j, j[::-1], j[:10]])  # 130 frames
    T = len(states)
    mano = {h: {"rot": np.zeros((T, 3)), "pose": np.zeros((T, 45)), "trans": np.zeros((T, 3)), "shape": np.zeros(10)}
            for h in ("right", "left")}
    seq = SEQ.replace("cabinet", record["category"])
    A.write_sequence(root, seq, states, mano)
    A.write_processed_joints(root, seq, joints)
    return tmp / "run", root, seq, states, joints


@pytest.mark.e2e
def test_generate_from_arctic_and_score_without_it(arctic_run, tmp_path, capsys):
    from handx_jax.families.bimart import common as C

    run, root, seq, states, joints = arctic_run
    base = ["generate", "--run", str(run), "--task", "object2motion", "--arctic", str(root)]
    g = tmp_path / "g.npz"
    # Bad input: one line each, exit 2, nothing written.
    for extra, msg in ((["--seq", seq, "--no-refine", "--start", "71"], "--start 71: the sequence has 130 frames"),
                       (["--seq", seq.replace("01", "07"), "--no-refine"], "no object trajectory for sequence"),
                       ([], "--arctic needs --seq")):
        assert main([*base, *extra, "--out", str(g)]) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and err.count("\n") == 0, err
    assert not g.exists()
    assert main([*base, "--seq", seq, "--no-refine", "--out", str(g)]) == 0
    out = capsys.readouterr().out
    assert f"2 motion(s) of 2 window(s) of 60 frames of ARCTIC {seq} starting at frame(s) 0, 60" in out
    gen = object_clips.read(g)
    np.testing.assert_allclose(gen["object_state"], np.stack([states[:60], states[60:120]]), atol=1e-6)
    np.testing.assert_allclose(gen["gt_joints"], np.stack([joints[:60], joints[60:120]]), atol=1e-6)
    mesh = A.mesh_arrays(A.read_object(root, gen["records"][0]["category"]))
    assert np.array_equal(gen["mesh_tri"][0], mesh["tri"]) and gen["joints"].shape == (2, 1, 60, 2, 21, 3)
    assert [r["start"] for r in gen["records"]] == [0, 60] and np.isfinite(gen["joints"]).all()

    # The ground truth's hands as the generation, with their own contact maps: on the mesh they score as on the
    # corpus's primitive object (no penetration, contact and articulation on every frame, F1 1, CM 0).
    data = C.arctic_windows(root, seq, C.BM.BimArtConfig(k=16), limit=1)
    truth = {**{k: v[:1] for k, v in gen.items() if k not in ("records", "source", "path", "mesh_tri", "mesh_part",
                                                                 "mesh_angle_range")},
             "joints": gen["gt_joints"][:1, None], "records": gen["records"][:1], "source": gen["source"],
             "contact": np.asarray(C.unit_to_contact(data.contact)).reshape(1, 1, 60, 2, 2, 16),
             **{k: gen[k] for k in ("mesh_tri", "mesh_part", "mesh_angle_range")}}
    s = object_clips.score(truth, object_clips.ground_truth(truth))
    assert s["obj_pen_1cm"] == 0.0 and s["obj_con"] == 100.0 and s["obj_art"] == 100.0
    assert s["obj_part_f1"] == 1.0 and s["obj_cm_cm"] < 0.01

    shutil.rmtree(root)  # the file carries what scoring needs
    assert main(["eval", "objects", "--generated", str(g), "--evaluator", "standard", "--json"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    scores = __import__("json").loads(lines[-1])
    assert scores["clips"] == 2 and scores["samples"] == 1 and 0 <= scores["obj_part_f1"] <= 1
    assert 0 <= scores["obj_con"] <= 100 and "rprec_top1" not in scores and "ARCTIC" in scores["text"]
