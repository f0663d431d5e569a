"""`handx eval objects --evaluator E` (issue 53 item 4): the text evaluator's metrics of generated hands against their
clips' three-text captions, beside the ground truth's own row on the same clips (evaluation/object_clips.py). The
captioned corpus here is the tests' shared 32-clip corpus (the functions read only its motion, ids and captions), the
evaluator the packaged standard one."""

import numpy as np
import pytest

from diffusion_fixtures import make_dataset
from handx_jax.dataset.format import Dataset
from handx_jax.evaluation import object_clips
from handx_jax.metrics import MetricConfig
from handx_jax.standard.naming import resolve_evaluator


def test_text_metrics_beside_the_ground_truth(tmp_path):
    data = make_dataset(tmp_path)
    ds = Dataset.open(data)
    clips = np.sort(ds.split("test"))
    gt = np.asarray(ds.motion[clips], np.float32)

    def gen(joints, clip_ids=clips, records=None, source=str(data)):
        return {"joints": joints[:, None], "clips": clip_ids, "source": source,
                "records": records or [{"category": "box", "instance_seed": 0}] * len(clip_ids)}

    src = object_clips.caption_source(gen(gt))
    assert src[0].root == ds.root and np.array_equal(src[1], clips)
    ev = resolve_evaluator("standard").load()
    cfg = MetricConfig(replications=2)
    same, truth = object_clips.text_scores(ev, gen(gt), ds, clips, cfg)
    # The ground truth given as the generation scores the ground truth's row: the same R-Precision and matching
    # score, FID 0 (the same embeddings), on one block of all the clips.
    for k in ("rprec_top1", "rprec_top2", "rprec_top3", "mm_dist", "diversity"):
        assert same.metrics[k][0] == pytest.approx(truth.metrics[k][0], abs=1e-6), k
    assert abs(same.metrics["fid"][0]) < 1e-3 and truth.meta["rprec_block"] == len(clips)
    assert truth.meta["out_of_domain"] and not same.meta["ground_truth"] and truth.meta["ground_truth"]
    # Each clip's hands under the next clip's captions: the same set of motions (FID 0) read against the wrong
    # texts, so R-Precision falls below the ground truth's.
    rolled, _ = object_clips.text_scores(ev, gen(np.roll(gt, 1, axis=0)), ds, clips, cfg)
    assert abs(rolled.metrics["fid"][0]) < 1e-3
    assert rolled.metrics["rprec_top1"][0] < truth.metrics["rprec_top1"][0]
    # Files without captions say why in one line.
    arctic = gen(gt, records=[{"source": "arctic", "seq": "s01/box_use_01", "start": 0, "mesh": 0}] * len(clips))
    assert "ARCTIC" in object_clips.caption_source(arctic)
    assert "one clip" in object_clips.caption_source(gen(gt[:1], clip_ids=clips[:1]))
    assert "is not there" in object_clips.caption_source(gen(gt, source=str(tmp_path / "moved")))
