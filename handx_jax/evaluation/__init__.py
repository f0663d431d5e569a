"""The text–motion evaluator: training, the versioned checkpoint, and evaluation of generated motion.

One module per concern; the public names are re-exported here (``from handx_jax.evaluation import X``):

    features.py    TextPolicy, motion features and their normalisation, the joined caption, training items
    model.py       TrainedEvaluator: embeds motion and captions (jitted), its fingerprint
    checkpoint.py  the checkpoint folder: read_meta, load_evaluator, save_evaluator, evaluator_id
    training.py    EvaluatorRunConfig (+ presets, ``--set`` overrides) and train_evaluator (handx_jax.train)
    reference.py   reference embeddings cached in the evaluator folder
    scoring.py     alignment of generated clips, the Table 2 metrics, the printed table, eval.json

Pipeline (paper E.2; reference §5.1–§5.4):

- **Motion side**: joints ``(N, 60, 2, 21, 3)`` → :func:`representation.to_evaluator` (per-frame
  right-wrist centring, §5.3) → z-scored with the training dataset's ``evaluator_mean/std`` (the
  same preprocessing in training and evaluation; the reference mixes two, §9.17).
- **Text side**: ``<extra_id_0> L <extra_id_1> R <extra_id_2> I <extra_id_3>`` per (clip, level),
  encoded by the frozen T5 (read from the joined text cache in training, encoded on the fly at
  evaluation and rounded to the cache dtype so both paths give the same numbers).
- **Training items** are (clip, level) pairs: each sample draws its level at random from the policy's
  ``train_levels``. The reference draws the three fields independently (§1.2); we keep the three fields
  of one level together because they are encoded as one sequence (one cache row per (clip, level)).
  Levels are a pure function of the batch's clip indices and the seed, so a resumed run sees exactly
  the same (clip, level) items.
- **Evaluation** scores every motion against the reference caption of its source clip at the
  policy's ``eval_level`` ("predictions are scored against the same caption as their GT", §5.3).

The checkpoint folder is described in ``evaluation.checkpoint``.
"""

from handx_jax.evaluation.checkpoint import (EVAL_FILE, FORMAT, FORMAT_VERSION, META_FILE, PARAMS_FILE, STATS_FILE,
                                             evaluator_id, load_evaluator, read_meta, save_evaluator)
from handx_jax.evaluation.features import (JOINED, STATS_CLIPS, TextPolicy, TrainingData, evaluator_stats,
                                           joined_caption, motion_features)
from handx_jax.evaluation.model import TrainedEvaluator, _init_params  # noqa: F401  (tests, benchmarks)
from handx_jax.evaluation.reference import (REFERENCE_CACHE_DIR, REFERENCE_CACHE_VERSION, ReferenceEmbeddings,
                                            read_reference_cache, reference_embeddings, reference_key,
                                            write_reference_cache)
from handx_jax.evaluation.scoring import (TABLE_COLUMNS, EvalResult, Generated, align_generated,
                                          evaluate_embeddings_and_motion, evaluate_generated, evaluate_ground_truth,
                                          format_table, write_eval_json)
from handx_jax.evaluation.training import (EvaluatorDataConfig, EvaluatorRunConfig, make_evaluator_config,
                                           model_config, train_evaluator)

__all__ = [
    "EVAL_FILE", "FORMAT", "FORMAT_VERSION", "META_FILE", "PARAMS_FILE", "STATS_FILE", "evaluator_id", "load_evaluator", "read_meta",
    "save_evaluator", "JOINED", "STATS_CLIPS", "TextPolicy", "TrainingData", "evaluator_stats", "joined_caption",
    "motion_features", "TrainedEvaluator", "REFERENCE_CACHE_DIR", "REFERENCE_CACHE_VERSION", "ReferenceEmbeddings",
    "read_reference_cache", "reference_embeddings", "reference_key", "write_reference_cache", "TABLE_COLUMNS",
    "EvalResult", "Generated", "align_generated", "evaluate_embeddings_and_motion", "evaluate_generated",
    "evaluate_ground_truth", "format_table", "write_eval_json", "EvaluatorDataConfig", "EvaluatorRunConfig",
    "make_evaluator_config", "model_config", "train_evaluator",
]
