"""``handx import …`` / ``handx export …``: the released HandX weights in and out (handx_jax.interop).

    handx import handx-diffusion MODEL.pt [--config config.yaml | --heads N] --encoder T5_DIR
                                 (--data DATA | --stats FILE) --out RUN
    handx import handx-evaluator EPOCH.ckpt --mean mean_can_pos.npy --std std_can_pos.npy --encoder T5_DIR
                                 [--heads 4] --out EV
    handx export handx-diffusion RUN --out MODEL.pt [--config config.yaml] [--stats DIR] [--raw] [--force]
"""

from __future__ import annotations

import argparse
import json


def _import_diffusion(args: argparse.Namespace) -> int:
    from handx_jax.interop import official_diffusion as od

    s = od.import_checkpoint(args.model, args.out, encoder=args.encoder, config=args.config, heads=args.heads,
                             data=args.data, stats=args.stats, overwrite=args.force)
    m = s["model"]
    print(f"wrote {s['run']}: diffusion run, L{m['layers']} d{m['dim']} H{m['heads']} FF{m['ff']} (text "
          f"{m['text_dim']}-d), {s['params']:,} parameters, from {args.model} (sha256 {s['sha256'][:16]}…); "
          f"PE tables within {s['pe_max_abs_diff']:.1e} of ours")
    print(f"sample it: handx generate --run {s['run']} …  (guidance 2.5 with the null text, as the paper; the "
          "official code's guidance is a no-op, which --guidance 1 reproduces exactly)")
    return 0


def _import_evaluator(args: argparse.Namespace) -> int:
    from handx_jax.interop import official_evaluator as oe

    s = oe.import_checkpoint(args.ckpt, args.out, mean=args.mean, std=args.std, encoder=args.encoder,
                             heads=args.heads, overwrite=args.force)
    c = s["config"]
    print(f"wrote {s['evaluator']}: official evaluator, latent {c['latent']}, {c['layers']} layers, {c['heads']} "
          f"heads, FF {c['ff']}, T5 from the checkpoint (sha256 {s['sha256'][:16]}…)")
    print(f"score with it: handx eval run --evaluator {s['evaluator']} --generated G.npz --data DATA")
    return 0


def _export_diffusion(args: argparse.Namespace) -> int:
    from handx_jax.interop import official_diffusion as od

    s = od.export_run(args.run, args.out, config=args.config, stats=args.stats, ema=not args.raw,
                      overwrite=args.force)
    print(f"wrote {s['out']}: {s['tensors']} tensors in the official layout ({'EMA' if s['ema'] else 'raw'} weights "
          f"at step {s['step']})" + (f"; {args.config}" if args.config else ""))
    print("not in the official checkpoint format:")
    for d in s["dropped"]:
        print(f"  - {d}")
    if args.json:
        print(json.dumps(s))
    return 0


def add_parser(subparsers) -> None:
    imp = subparsers.add_parser("import", help="read the released HandX weights (no PyTorch needed)",
                                description="Import the official HandX checkpoints: a diffusion model as a run "
                                            "folder, the evaluator as an evaluator folder.")
    isub = imp.add_subparsers(dest="what", metavar="WHAT")
    isub.required = True
    d = isub.add_parser("handx-diffusion", help="a released model.pt → a diffusion run folder",
                        description="Write a diffusion run folder from an official model.pt, for `handx generate` "
                                    "and `handx params`.")
    d.add_argument("model", help="the official model.pt ({'state_dict': …})")
    d.add_argument("--config", help="its config.yaml (sizes checked against the tensors; num_heads)")
    d.add_argument("--heads", type=int, help="attention heads (required without --config: no shape reveals them)")
    d.add_argument("--encoder", required=True, help="Hugging Face T5 folder the model conditions on (t5-base)")
    g = d.add_mutually_exclusive_group(required=True)
    g.add_argument("--data", help="handx-jax dataset whose train-split statistics normalise the motion")
    g.add_argument("--stats", help="mean/std: an official mean_std_joint_pos_w_scalar_rot/ folder or an .npz")
    d.add_argument("--out", required=True, help="the run folder to write")
    d.add_argument("--force", action="store_true", help="replace an existing --out")
    d.set_defaults(func=_import_diffusion)
    e = isub.add_parser("handx-evaluator", help="the released epoch=269.ckpt → an evaluator folder",
                        description="Write an evaluator folder from the official Lightning checkpoint, for "
                                    "`handx eval run --evaluator EV` with the official preprocessing.")
    e.add_argument("ckpt", help="the official evaluator checkpoint (epoch=269.ckpt)")
    e.add_argument("--mean", required=True, help="mean_can_pos.npy")
    e.add_argument("--std", required=True, help="std_can_pos.npy")
    e.add_argument("--encoder", required=True, help="a T5 folder for the tokenizer and config (t5-base); the "
                                                     "weights come from the checkpoint")
    e.add_argument("--heads", type=int, default=4, help="attention heads (default 4, what the official code builds)")
    e.add_argument("--out", required=True, help="the evaluator folder to write")
    e.add_argument("--force", action="store_true", help="replace an existing --out")
    e.set_defaults(func=_import_evaluator)

    exp = subparsers.add_parser("export", help="write a run in the released HandX format",
                                description="Export a diffusion run as an official model.pt.")
    esub = exp.add_subparsers(dest="what", metavar="WHAT")
    esub.required = True
    x = esub.add_parser("handx-diffusion", help="a diffusion run folder → an official model.pt",
                        description="Write the run's weights as an official model.pt (readable by torch.load and "
                                    "the official MotionDiffusionModel with strict=False).")
    x.add_argument("run", help="diffusion run folder")
    x.add_argument("--out", required=True, help="model.pt to write")
    x.add_argument("--config", help="also write the official config.yaml (model: section) here")
    x.add_argument("--stats", help="also write the normalisation statistics as DIR/mean.npy, DIR/std.npy")
    x.add_argument("--raw", action="store_true", help="export the raw weights instead of the EMA ones")
    x.add_argument("--force", action="store_true", help="replace existing --out, --config and --stats files")
    x.add_argument("--json", action="store_true", help="also print the summary as JSON")
    x.set_defaults(func=_export_diffusion)
