"""The released HandX evaluator (``epoch=269.ckpt`` + ``mean_can_pos.npy`` / ``std_can_pos.npy``) → an
evaluator folder that ``handx eval run --evaluator EV`` scores with, with the official preprocessing.

The official encoders (TEMOS, reference §5.1) are the architecture of ``models.evaluator.Evaluator``:
a Linear input (motion: 126 → d; text: ReLU → Linear(T5 → d)), μ and logvar tokens in front, the
sinusoidal PE, a post-LN ``nn.TransformerEncoder`` (GELU, no final norm); the embedding is the output
at the μ token. So the state dict maps onto that tree one to one (``textencoder.projection.1`` →
``text_in``, ``motionencoder.skel_embedding`` → ``motion_in``, ``{mu,logvar}_token`` → ``dist_tokens``,
``seqTransEncoder.layers.i`` → ``layer{i}``) and what differs is preprocessing, recorded in the folder:

- the T5 is the checkpoint's own ``textencoder.text_model.*`` (written to ``EV/t5`` with ``--encoder``'s
  config and tokenizer): the evaluation loads it strictly over ``from_pretrained('t5-base')`` (§5.5);
- the caption is the official ``<extra_id0> L <extra_id1> R <extra_id2> I <extra_id3>`` (text policy
  ``caption: official``), tokenized as the slow T5Tokenizer does (the markers are plain text), up to
  512 tokens, and the T5 output is kept in float32 (``cache_dtype: float32``);
- motion: per-frame right-wrist centring, (hand, joint, xyz) flattening, (x − mean_can_pos)/std_can_pos
  (``motion_input: positions`` with the shipped statistics), every frame valid.

Ignored, as the official evaluation ignores them: ``motiondecoder.*``, ``_losses.*``, the optimizer and
loop states, the hyper-parameters (an omegaconf config, NumPy arrays and a function reference, which
the reader keeps as inert placeholders). No tensor's shape gives the head count: the official code
always builds 4 (§5.5), the default of ``--heads``.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from handx_jax.interop import torch_layers as tl
from handx_jax.interop import torch_pickle
from handx_jax.infra.errors import DataError

ENCODERS = {"text": "textencoder", "motion": "motionencoder"}
T5_PREFIX = "textencoder.text_model."
MAX_TEXT_LEN = 512  # the T5 tokenizer's model_max_length: the official call truncates there (§5.5)
PE_TOLERANCE = 2e-3  # see official_diffusion.PE_TOLERANCE
LICENCE = "as the HandX release that links it (the released HandX weights are CC-BY-NC-4.0)"


def caption(left: str, right: str, interaction: str) -> str:
    """The caption string the official ``run_evaluation.py`` builds."""
    from handx_jax.evaluation.features import joined_caption

    return joined_caption(left, right, interaction, "official")


def read_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """The Lightning checkpoint's top-level dict (its ``state_dict`` checked to be there)."""
    obj = torch_pickle.load(path)
    if not isinstance(obj, dict) or not isinstance(obj.get("state_dict"), dict):
        raise DataError("no 'state_dict' in the checkpoint (expected a PyTorch Lightning .ckpt)", path=path)
    return obj


def infer_config(sd: Mapping[str, Any], *, heads: int, text_dim: int, path=None):
    """The evaluator config of the checkpoint's encoders (d, F, L from shapes; ``heads`` given)."""
    from handx_jax.models.evaluator import EvaluatorConfig

    d = tl.tensor(sd, "motionencoder.mu_token", path=path).shape[0]
    sizes = {}
    for side, pre in ENCODERS.items():
        L = tl.layer_count(sd, f"{pre}.seqTransEncoder.layers")
        F = tl.tensor(sd, f"{pre}.seqTransEncoder.layers.0.linear1.weight", path=path).shape[0] if L else 0
        sizes[side] = (L, F)
    if sizes["text"] != sizes["motion"] or sizes["text"][0] == 0:
        raise DataError(f"text and motion encoders have (layers, FF) {sizes['text']} and {sizes['motion']}; the "
                        "official evaluator builds both alike", path=path)
    motion_dim = tl.tensor(sd, "motionencoder.skel_embedding.weight", path=path).shape[1]
    if motion_dim != 126:
        raise DataError(f"motionencoder.skel_embedding takes {motion_dim} features; the official evaluator's "
                        "input is 2 x 21 x 3 = 126", path=path)
    from handx_jax.interop import checks

    heads = checks.whole(heads, "--heads")
    if d % heads:
        raise DataError(f"--heads {heads} does not divide the latent width {d} (motionencoder.mu_token): each head "
                        "takes d / H values", path=path)
    L, F = sizes["text"]
    return EvaluatorConfig(latent=d, layers=L, heads=heads, ff=F, dropout=0.1, motion_input="positions",
                           motion_patch=1, text_dim=text_dim, frames=60, recon=False)


def params_from_official(sd: Mapping[str, Any], cfg, *, path=None) -> dict:
    """``textencoder.*`` / ``motionencoder.*`` → the ``Evaluator`` tree."""
    d, tree = cfg.latent, {}
    for side, pre in ENCODERS.items():
        tree[f"{side}_enc"] = {
            "dist_tokens": np.stack([tl.tensor(sd, f"{pre}.{n}_token", (d,), path=path) for n in ("mu", "logvar")]),
            **{f"layer{i}": tl.encoder_layer_from(sd, f"{pre}.seqTransEncoder.layers.{i}", d, cfg.heads, cfg.ff,
                                                  path=path) for i in range(cfg.layers)}}
    tree["motion_in"] = tl.linear_from(sd, "motionencoder.skel_embedding", 126, d, path=path)
    tree["text_in"] = tl.linear_from(sd, "textencoder.projection.1", cfg.text_dim, d, path=path)
    return {"params": tree}


def check_tables(sd: Mapping[str, Any], d: int, *, path=None) -> float:
    from handx_jax.models.layers import sinusoidal_table

    ours, worst = sinusoidal_table(1024, d), 0.0
    for pre in ENCODERS.values():
        name = f"{pre}.sequence_pos_encoding.pe"
        if name in sd:
            a = tl.tensor(sd, name, path=path).reshape(-1, d)[:len(ours)]
            gap = float(np.max(np.abs(a - ours[:len(a)])))
            if gap > PE_TOLERANCE:
                raise DataError(f"{name} differs from the sinusoidal table by {gap:.2e}", path=path)
            worst = max(worst, gap)
    return worst


def t5_from_checkpoint(sd: Mapping[str, Any], encoder, *, path=None):
    """The checkpoint's T5 (``textencoder.text_model.*``) with ``encoder``'s config and tokenizer."""
    from handx_jax.text.hf import hf_param_names, set_path
    from handx_jax.text.t5 import FrozenEncoder

    params: dict = {}
    for hf, p, transpose in hf_param_names(encoder.cfg, encoder_only=True):
        want = np.asarray(_get(encoder.params, p)).shape
        a = tl.tensor(sd, T5_PREFIX + hf, want[::-1] if transpose else want, path=path)
        set_path(params, p, np.ascontiguousarray(a.T if transpose else a))
    return FrozenEncoder(encoder.cfg, params, encoder.tokenizer)


def _get(tree, path):
    for k in path:
        tree = tree[k]
    return tree


def read_stats(mean_path, std_path):
    from handx_jax import representation as rep

    from handx_jax.interop import checks

    arrays = []
    for p in (mean_path, std_path):
        a = checks.load_array_file(p)
        if a.size != 126:
            raise DataError(f"shape {a.shape}: the official evaluator's statistics broadcast as (126,) over the "
                            "(N, 60, 126) motion; a per-frame table is not supported", path=p)
        arrays.append(np.asarray(a, np.float32).reshape(126))
    mean, std = arrays
    checks.norm_stats(mean, std, mean_path=mean_path, std_path=std_path)
    return rep.NormStats(mean=mean, std=std)


def import_checkpoint(ckpt: str | os.PathLike, out: str | os.PathLike, *, mean: str | os.PathLike,
                      std: str | os.PathLike, encoder, heads: int = 4, overwrite: bool = False) -> dict:
    """Write the evaluator folder ``out`` (format ``handx-jax-evaluator``) from the official checkpoint."""
    from handx_jax.evaluation.checkpoint import FORMAT, FORMAT_VERSION, save_evaluator
    from handx_jax.evaluation.features import TextPolicy
    from handx_jax.evaluation.model import TrainedEvaluator, param_shapes
    from handx_jax.infra.checksums import sha256_file as sha256
    from handx_jax.infra.atomic import atomic_dir
    from handx_jax.text.hf import as_encoder, save_hf_t5_encoder

    import jax

    from handx_jax.interop import checks
    from handx_jax.infra.outputs import refuse_existing

    refuse_existing(out, overwrite=overwrite)  # at once, not after reading the weights
    ckpt = Path(ckpt)
    top = read_checkpoint(ckpt)
    sd = top["state_dict"]
    enc = as_encoder(encoder)
    cfg = infer_config(sd, heads=heads, text_dim=enc.cfg.d_model, path=ckpt)
    with checks.sizes_from(f"latent {cfg.latent} from motionencoder.mu_token, FF {cfg.ff} from layer 0's linear1, "
                           f"{cfg.heads} heads from --heads"):
        pe_gap = check_tables(sd, cfg.latent, path=ckpt)
        params = params_from_official(sd, cfg, path=ckpt)
    expected = jax.tree_util.tree_map(lambda a: a.shape, param_shapes(cfg, 8))
    got = jax.tree_util.tree_map(lambda a: a.shape, params)
    if expected != got:
        raise DataError("the mapped parameters do not form the evaluator's tree (internal mapping error)", path=ckpt)
    t5 = t5_from_checkpoint(sd, enc, path=ckpt)
    stats = read_stats(mean, std)
    policy = TextPolicy(max_len=MAX_TEXT_LEN, train_levels=None, eval_level=0, cache_dtype="float32",
                        caption="official")
    meta = {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "evaluator_config": dataclasses.asdict(cfg),
        "text": dataclasses.asdict(policy),
        "encoder": {"path": "t5", "fingerprint": t5.fingerprint, "tokenizer_fingerprint": enc.tokenizer.fingerprint,
                    "note": "the checkpoint's textencoder.text_model.* with the config and tokenizer of "
                            f"{enc.path}"},
        "source": {"format": "official HandX evaluator (TEMOS, PyTorch Lightning checkpoint)",
                   "file": str(ckpt.absolute()), "sha256": sha256(ckpt), "mean": str(Path(mean).absolute()),
                   "mean_sha256": sha256(mean), "std": str(Path(std).absolute()), "std_sha256": sha256(std),
                   "epoch": _plain(top.get("epoch")), "heads": heads,
                   "heads_from": "--heads (no tensor's shape reveals it; the official code builds 4)",
                   "licence": LICENCE, "pe_max_abs_diff": pe_gap},
    }
    out = Path(out)
    with atomic_dir(out, overwrite=overwrite) as tmp:
        save_hf_t5_encoder(tmp / "t5", t5.cfg, t5.params, enc.tokenizer)
        save_evaluator(tmp, TrainedEvaluator(cfg=cfg, params=params, stats=stats, encoder=t5, policy=policy,
                                             meta=meta))
    return {"evaluator": str(out), "config": dataclasses.asdict(cfg), "sha256": meta["source"]["sha256"],
            "pe_max_abs_diff": pe_gap}


def _plain(v):
    return v if isinstance(v, (int, float, str, type(None))) else str(v)


def load(ev: str | os.PathLike, **kw):
    """An imported evaluator folder, loaded (``evaluation.load_evaluator``)."""
    from handx_jax.evaluation import load_evaluator

    return load_evaluator(ev, **kw)
