"""``handx params diffusion``: trainable parameters and analytic forward FLOPs of a configuration.

FLOPs are per sample and per forward pass, 2 per multiply-add, matrix products and attention only
(``models.dit.forward_flops``). The frozen text encoder is reported separately
(``text_flops_per_sample``: three prompts of ``--text-len`` tokens), from ``--encoder`` if given, else
for T5-base (d 768, 12 layers, 12 heads, d_ff 3072, the reference's encoder, §3.1).
"""

from __future__ import annotations

import argparse
import json

T5_BASE = dict(vocab_size=32128, d_model=768, d_kv=64, d_ff=3072, num_layers=12, num_heads=12)


def diffusion_numbers(layers: int, dim: int, heads: int, ff: int, text_dim: int, text_len: int,
                      encoder: str | None = None) -> dict:
    from handx_jax.models.dit import DiTConfig, forward_flops, param_count
    from handx_jax.text.t5 import T5Config, encoder_flops

    cfg = DiTConfig(layers=layers, dim=dim, heads=heads, ff=ff, text_dim=text_dim)
    if encoder:
        from handx_jax.text.t5 import load_hf_t5_encoder

        enc_cfg = load_hf_t5_encoder(encoder).cfg
    else:
        enc_cfg = T5Config(**T5_BASE)
    return {"params": param_count(cfg), "flops_per_sample": forward_flops(cfg, text_len),
            "text_flops_per_sample": 3 * int(encoder_flops(enc_cfg, text_len))}


def paper_numbers(layers: int, dim: int, heads: int, ff: int, text_dim: int, text_tokens: int | None,
                  encoder_tokens: int | None) -> dict:
    """Table B's convention (handx_jax.flops): MACs of the denoiser's Linear layers + the T5 encoder's."""
    from handx_jax import flops
    from handx_jax.models.dit import DiTConfig, param_count

    cfg = DiTConfig(layers=layers, dim=dim, heads=heads, ff=ff, text_dim=text_dim)
    mem = flops.PAPER_MEM_TOKENS if text_tokens is None else text_tokens
    enc = flops.PAPER_ENCODER_TOKENS if encoder_tokens is None else encoder_tokens
    return {"params": param_count(cfg), "convention": "paper", **flops.paper_flops(cfg, mem, enc)}


def _diffusion(args: argparse.Namespace) -> int:
    if args.dim % args.heads:
        print(f"handx params diffusion: error: --dim {args.dim} is not divisible by --heads {args.heads}")
        return 2
    if args.convention == "paper":
        out = paper_numbers(args.layers, args.dim, args.heads, args.ff, args.text_dim, args.text_tokens,
                            args.encoder_tokens)
        if args.json:
            print(json.dumps(out))
        else:
            print(f"diffusion L{args.layers} d{args.dim} H{args.heads} FF{args.ff}: {out['params']:,} params; "
                  f"{out['flops_per_sample_paper'] / 1e9:.3f} G (paper convention: Linear-layer MACs of the denoiser "
                  f"with {out['mem_tokens']} text tokens per branch, {out['denoiser_macs'] / 1e9:.3f} G, + T5-base on "
                  f"{out['encoder_tokens']} tokens, {out['text_encoder_macs'] / 1e9:.3f} G)")
        return 0
    out = diffusion_numbers(args.layers, args.dim, args.heads, args.ff, args.text_dim, args.text_len, args.encoder)
    if args.json:
        print(json.dumps(out))
    else:
        print(f"diffusion L{args.layers} d{args.dim} H{args.heads} FF{args.ff} (text {args.text_dim}-d, "
              f"{args.text_len} tokens): {out['params']:,} params ({out['params'] / 1e6:.2f}M), "
              f"{out['flops_per_sample'] / 1e9:.3f} GFLOPs/sample forward; text encoder "
              f"{out['text_flops_per_sample'] / 1e9:.3f} GFLOPs/sample (3 prompts)")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("params", help="parameter count and analytic FLOPs of a model configuration")
    p.set_defaults(func=lambda a: (p.print_help(), 0)[1])
    sub = p.add_subparsers(dest="family", metavar="FAMILY")
    d = sub.add_parser("diffusion", help="treble-residual denoiser", description=__doc__)
    d.add_argument("--layers", type=int, required=True)
    d.add_argument("--dim", type=int, required=True)
    d.add_argument("--heads", type=int, required=True)
    d.add_argument("--ff", type=int, required=True)
    d.add_argument("--text-dim", type=int, default=768, help="text feature width (768 for T5-base)")
    d.add_argument("--text-len", type=int, default=32, help="tokens per prompt for the FLOPs count")
    d.add_argument("--encoder", help="encoder folder for text_flops_per_sample (default: T5-base)")
    d.add_argument("--convention", choices=("analytic", "paper"), default="analytic",
                   help="analytic: 2 FLOPs per multiply-add of every matmul, denoiser only (default); paper: "
                        "multiply-adds of the Linear layers (as fvcore/thop count them) plus the frozen T5-base "
                        "encoder, which reproduces the paper's Table B FLOPs column (handx_jax/flops.py)")
    d.add_argument("--text-tokens", type=int, default=None,
                   help="paper convention: text tokens per branch the denoiser attends to (default 63, fitted to "
                        "Table B)")
    d.add_argument("--encoder-tokens", type=int, default=None,
                   help="paper convention: tokens through the T5 encoder per sample (default 40, fitted to Table B)")
    d.add_argument("--json", action="store_true", help="print {params, flops_per_sample, text_flops_per_sample}")
    d.set_defaults(func=_diffusion)
    return p
