"""``handx text …``: SentencePiece training, encoding and the embedding cache; T5 pretraining's flags
(``handx train t5``).

Registered by ``handx_jax.cli`` through ``add_parser(subparsers)``; every command sets ``args.func``.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from handx_jax.cliargs import deprecated_command, deprecated_flag
from handx_jax.config import add_config_args
from handx_jax.infra.errors import DataError
from handx_jax.text.prompts import EMPTY_HELP


def _encode(args: argparse.Namespace) -> int:
    from handx_jax.text.prompts import check_texts
    from handx_jax.text.hf import load_hf_t5_encoder

    check_texts(args.texts, "TEXT")
    if args.max_len is not None and args.max_len < 2:
        raise DataError(f"--max-len must be at least 2 (one token and the end-of-sequence id), got {args.max_len}")
    enc = load_hf_t5_encoder(args.encoder)
    e, h = enc.encode(args.texts, args.max_len)
    lens = e.lengths_B.tolist()
    if args.json:
        json.dump({"ids": [e.ids_BxL[i, :n].tolist() for i, n in enumerate(lens)],
                   "hidden": [h[i, :n].astype(float).tolist() for i, n in enumerate(lens)]}, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print(f"encoder {args.encoder}: d_model {enc.cfg.d_model}, {enc.cfg.num_layers} layers, "
          f"{enc.cfg.feed_forward_proj}, vocab {enc.cfg.vocab_size}, fingerprint {enc.fingerprint}")
    if e.num_truncated:
        print(f"{e.num_truncated} text(s) truncated to {args.max_len} tokens")
    for i, (t, n) in enumerate(zip(args.texts, lens)):
        pooled = h[i, :n].mean(0)
        print(f"[{i}] {n} tokens {e.ids_BxL[i, :n].tolist()}  hidden ({n}, {h.shape[-1]})  "
              f"mean-pooled norm {np.linalg.norm(pooled):.4f}  {t!r}")
    return 0


def _sentencepiece(args: argparse.Namespace) -> int:
    from handx_jax.dataset.format import Dataset
    from handx_jax.text import tokenizer as tk

    tok = tk.train_for_dataset(args.data, vocab_size=args.vocab_size, num_extra_ids=args.num_extra_ids,
                               overwrite=args.force)
    caps = tk.dataset_captions(Dataset.open(args.data))
    lens = np.array([len(tok.encode_one(c)) for c in caps])
    print(f"tokenizer {tok.path}: {tok.vocab_size} ids ({tok.num_sentinels} sentinels <extra_id_0..>), "
          f"fingerprint {tok.fingerprint}; {len(caps)} captions: tokens (with eos) mean {lens.mean():.1f}, "
          f"p99 {np.percentile(lens, 99):.0f}, max {lens.max()}")
    return 0


TRAIN_HELP = "a small T5 pretrained on the captions with span corruption (when no pretrained T5 is on disk)"
TRAIN_DESCRIPTION = ("Train encoder + small decoder with T5 span corruption (15%% noise, mean span 3); resumes from "
                     "RUN/checkpoints; exports the frozen encoder to RUN/encoder. --set takes the keys of "
                     "handx_jax.text.pretrain.PretrainConfig (e.g. noise_density=0.15, warmup_frac=0.05).")


def add_train_args(r: argparse.ArgumentParser) -> None:
    """``handx train t5``'s flags (a trainable of the registry, ``families.TRAINABLES``)."""
    from handx_jax.text.pretrain import PRESETS

    r.add_argument("--data", required=True, metavar="DIR", help="dataset directory (tokenizer trained if absent)")
    r.add_argument("--out", required=True, metavar="RUN", help="run folder")
    r.add_argument("--preset", required=True, choices=tuple(PRESETS), help="model size")
    add_config_args(r, None, example="noise_density=0.2")
    r.add_argument("--steps", type=int, default=0, help="training steps (default: the preset's)")
    r.add_argument("--batch-size", type=int, default=0, help="captions per step (default: the preset's)")
    r.add_argument("--lr", type=float, default=0.0, help="peak learning rate (default: the preset's)")
    r.add_argument("--max-len", type=int, default=128, help="encoder input tokens (default 128)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--log-every", type=int, default=10)
    r.add_argument("--ckpt-every", type=int, default=500)
    r.add_argument("--eval-every", type=int, default=500)


def train_from_args(args: argparse.Namespace) -> int:
    from handx_jax.config import apply_overrides, print_config
    from handx_jax.text.pretrain import PretrainConfig, pretrain

    try:
        cfg = apply_overrides(PretrainConfig(preset=args.preset, steps=args.steps, batch_size=args.batch_size,
                                             lr=args.lr, max_len=args.max_len, seed=args.seed,
                                             log_every=args.log_every, ckpt_every=args.ckpt_every,
                                             eval_every=args.eval_every), args.set)
    except ValueError as e:
        print(f"handx train t5: error: {e}", file=sys.stderr)
        return 2
    if args.print_config:
        print_config(cfg)
        return 0
    pretrain(args.data, args.out, cfg)
    return 0


def _cache(args: argparse.Namespace) -> int:
    from handx_jax.dataset.format import Dataset
    from handx_jax.text.cache import TextCache, build_cache, neighbour_accuracy

    levels = None
    if args.levels is not None:
        try:
            levels = [int(v) for v in args.levels.split(",") if v.strip()]
        except ValueError:
            print(f"handx: error: --levels {args.levels!r}: expected comma-separated caption levels, e.g. 0 or 0,4",
                  file=sys.stderr)
            return 2
    try:
        root = build_cache(args.data, args.encoder, max_len=args.max_len, dtype=args.dtype,
                           batch_size=args.batch_size, overwrite=args.force, joined=args.joined, levels=levels)
    except ValueError as e:  # a level out of range: one line, no traceback
        print(f"handx: error: --levels: {e}", file=sys.stderr)
        return 2
    cache = TextCache.open(root)
    m = cache.meta
    print(json.dumps({"cache": str(root), "rows": m["num_rows"], "captions": m["num_captions"], "Lmax": m["Lmax"],
                      "truncated": m["num_truncated"], "dtype": m["dtype"],
                      "encoder_flops_per_caption": m["encoder_flops_per_caption"]["mean"],
                      "captions_per_s": m["captions_per_s"]}))
    if args.nn_check:
        ds = Dataset.open(args.data)
        split = next((s for s in ("val", "test", "train") if len(ds.split(s))), None)
        if split is not None:
            print(json.dumps({"nearest_neighbour_check": split, **neighbour_accuracy(cache, ds.split(split),
                                                                                     args.nn_check)}))
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("text", help="SentencePiece model, T5 encoding, embedding cache",
                              description="Text stack: SentencePiece tokenizer, T5 encoder (Hugging Face folders "
                                          "or pretrained here), and the frozen-encoder embedding cache.")
    p.set_defaults(func=lambda a: (p.print_help(), 0)[1])
    sub = p.add_subparsers(title="commands", metavar="COMMAND")

    e = sub.add_parser("encode", help="encode texts with an encoder folder",
                       description="Tokenize with the folder's spiece.model (plus eos) and run the T5 encoder.")
    deprecated_flag(e, "--weights", e.add_argument(
        "--encoder", required=True, metavar="DIR",
        help="encoder folder, Hugging Face format: config.json, model.safetensors (or shards), spiece.model"))
    e.add_argument("--json", action="store_true",
                   help='print {"ids": [[...]], "hidden": [[[...]]]}: ids and last hidden states per text')
    e.add_argument("--max-len", type=int, default=None, help="truncate to this many tokens (default: none)")
    e.add_argument("texts", nargs="+", metavar="TEXT", help="texts to encode; each " + EMPTY_HELP)
    e.set_defaults(func=_encode)

    # "sentencepiece", not "tokenizer": `handx train tokenizer` is the FSQ motion tokenizer (a model
    # family); this one splits captions into word pieces. The old name stays one release.
    for name, func, helptext in (
            ("sentencepiece", _sentencepiece, "train a SentencePiece (word-piece) model on a dataset's captions"),
            ("tokenizer", deprecated_command(_sentencepiece, "handx text tokenizer", "handx text sentencepiece"),
             "(deprecated: handx text sentencepiece)")):
        t = sub.add_parser(name, help=helptext,
                           description="Train a unigram SentencePiece model (pad 0, eos 1, unk 2, <extra_id_N> "
                                       "sentinels) on the train-split captions; writes DIR/tokenizer/spiece.model.")
        t.add_argument("--data", required=True, metavar="DIR", help="dataset directory")
        t.add_argument("--vocab-size", type=int, default=4000, help="upper bound on pieces (default 4000)")
        t.add_argument("--num-extra-ids", type=int, default=32, help="sentinels <extra_id_0..N-1>, N >= 4 (default 32)")
        t.add_argument("--force", action="store_true", help="replace an existing SentencePiece model")
        t.set_defaults(func=func)

    r = sub.add_parser("pretrain", help="(deprecated: handx train t5)",
                       description=f"Deprecated spelling of `handx train t5`. {TRAIN_DESCRIPTION}")
    add_train_args(r)
    r.set_defaults(func=deprecated_command(train_from_args, "handx text pretrain", "handx train t5"))

    c = sub.add_parser("cache", help="encode every caption once into a memory-mapped cache",
                       description="Encode all captions (3 fields x all levels) with a frozen encoder folder into "
                                   "DIR/text_cache/<fingerprint>/.")
    c.add_argument("--data", required=True, metavar="DIR", help="dataset directory")
    c.add_argument("--encoder", required=True, metavar="E", help="encoder folder (HF format, e.g. RUN/encoder)")
    c.add_argument("--max-len", type=int, default=128, help="truncate captions to this many tokens (default 128)")
    c.add_argument("--dtype", choices=("float16", "float32"), default="float16")
    c.add_argument("--batch-size", type=int, default=128)
    c.add_argument("--force", action="store_true", help="rebuild even if an up-to-date cache exists")
    c.add_argument("--joined", action="store_true",
                   help="cache the three prompts joined by separators, one row per (clip, level) (evaluator text)")
    c.add_argument("--levels", metavar="L[,L...]",
                   help="cache only these caption levels (e.g. 0: an evaluator trained and scored at level 0 reads "
                        "no other); default all")
    c.add_argument("--nn-check", type=int, default=1000, metavar="N",
                   help="report nearest-neighbour self-retrieval on N validation captions (0: skip)")
    c.set_defaults(func=_cache)
    return p
