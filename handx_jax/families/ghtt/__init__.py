"""G-HTT (Wen et al.): the action block A over a trained pose block P, a run that predicts how hands
continue and recognises which caption fits a motion; it does not generate from text alone.

    handx train ghtt-pose --data DIR --preset tiny --out POSE                     # P first (§3.3)
    handx text cache --data DIR --encoder ENC --joined                            # the captions' features
    handx train ghtt --data DIR --encoder ENC --ghtt-pose POSE --preset tiny --out RUN
    handx eval prediction --run RUN --observed-frames 16                          # K = 20 from N(μ, 5Σ)
    handx eval recognition --run RUN                                              # caption retrieval

Why two runs: P is trained alone on short spans (§3.3: "we first train P ... then we fix the pretrained P
and train A"), and one P serves every A trained on it, so it is a shared step that the registry names
(``Family.needs``), as the AR LM's tokenizer is: the sweep launcher trains it once per P size and passes
``--ghtt-pose STEP``.

Training A (§3.1, App. B.3): items are (clip, caption level) pairs of the train split. The frozen E^P's
μ^P of every span of every train clip, at every span offset 0..t−1, are computed once (the paper's
pre-computed m̄^P); each item draws an offset (HandX clips hold four 15-frame spans at offset 0 and three
at the others, so A sees spans that start where an observation ends, as in prediction) and a split into
observed spans n (1..all) and future ones, and its loss is λ4 L_mid (Eq. 5: L1 of D^A's future latents
against m̄^P) + λ5 L_action (Eqs. 3–4 against FC1 of the clip's caption, the batch's captions the label
set) + λ6 KL. The observed latents get Gaussian noise (App. B.3).

Prediction (§3.2, path P.b by default): with N observed frames, E^P encodes the last n = ⌊N/t⌋ spans
ending at frame N (so an observation of 16 frames, not a multiple of 15, is the span of frames 2–16;
frame 1 is kept but not encoded; the spans are anchored where the observation ends, never padded). D^P
expands m ~ N(μ^P_n, 5Σ^P_n) into the next span; E^A over the observed latents gives α ~ N(μ^A, 5Σ^A) and
D^A the later spans' latents, which D^P expands (``sample.path=pose``: path P.a, P alone, each predicted
span fed back to E^P). The frames are placed from the last observed frame's palm frames and the observed
hand sizes (App. B.2, Eqs. 8–9), and the observed frames are returned as given.

Recognition (§3.2): μ^A of a whole clip (its four spans observed) against FC1 of each candidate caption,
by cosine similarity: "which caption fits this motion" (``embed_motions``/``embed_texts``, scored by
``handx eval recognition`` with the R-Precision of the standard evaluator).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import os
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.config import ConfigError, from_dict, to_dict
from handx_jax.families import run_config
from handx_jax.families.ghtt import common as C
from handx_jax.families.ghtt import pose as PP
from handx_jax.infra.errors import DataError
from handx_jax.models import ghtt as G
# The run configuration and the loaded run have their own modules; the family's names are these:
from handx_jax.families.ghtt.config import (FAMILY, PATHS, PRESETS, TASKS, TRAIN_PRESETS, Config,  # noqa: F401
                                          DataConfig, GHTTRunConfig, LossConfig, SampleConfig, make_config)
from handx_jax.families.ghtt.run import GenerateOptions, GHTTRun, load, predict_frames, rectify  # noqa: F401


def numbers(cfg: GHTTRunConfig, *, text_len: int = 96, encoder_cfg=None) -> dict:
    """The whole model's parameters (P + A) and forward FLOPs of one 60-frame clip through it (E^P and D^P on
    its four spans, E^A and D^A, FC1); the frozen text encoder over the joined caption, apart."""
    from handx_jax.text.t5 import encoder_flops, t5_base

    n, f = G.param_counts(cfg.model), G.forward_flops(cfg.model)
    return {"params": n["params"], "params_non_embedding": n["params_non_embedding"], "flops_per_sample": f["total"],
            "text_flops_per_sample": int(encoder_flops(encoder_cfg if encoder_cfg is not None else t5_base(), text_len))}


# ------------------------------------------------------------------------------------------------
# Training A


def pooled_text(cache, clips, levels, chunk: int = 128) -> np.ndarray:
    """Each (clip, level)'s caption feature: the mean of its joined caption's T5 token states (N, L, 768)."""
    out = np.zeros((len(clips), len(levels), cache.meta["d_model"]), np.float32)
    for li, lv in enumerate(levels):
        for s in range(0, len(clips), chunk):
            h, m = cache.lookup(np.asarray(clips[s:s + chunk]), "joined", lv)
            m = m.astype(np.float32)[..., None]
            out[s:s + chunk, li] = (h.astype(np.float32) * m).sum(1) / np.maximum(m.sum(1), 1.0)
    return out


def offset_latents(pose_params, cfg: G.GHTTConfig, Hn_NxFx153: np.ndarray, chunk: int = 16):
    """m̄^P of every span at every offset 0..t−1: (N, t, S, D) with S = F // t, and which spans are wholly
    inside the clip (t, S). ``chunk`` clips at a time: each is t·S = 60 spans through E^P (at 256 clips, E^P
    of the `small` preset held 7.6 GB of activations and was killed for memory)."""
    t, F = cfg.span, Hn_NxFx153.shape[1]
    S = F // t
    offsets = jnp.arange(t)

    @jax.jit
    def one(H_BxFx153):
        B = H_BxFx153.shape[0]
        o_B = jnp.repeat(offsets, B)
        spans, valid = C.spans_at(jnp.tile(H_BxFx153, (t, 1, 1)), o_B, S, t)
        mu = C.span_latents(pose_params, cfg, spans)
        return mu.reshape(t, B, S, -1).transpose(1, 0, 2, 3), valid.reshape(t, B, S)[:, 0]

    outs, valid = [], None
    # The last chunk padded to a whole one: one compiled shape for the train and the validation clips (each
    # size compiled its own; a clip's latents are the same either way, bit for bit, measured).
    for s in range(0, len(Hn_NxFx153), chunk):
        part = Hn_NxFx153[s:s + chunk]
        m, valid = one(jnp.asarray(C.pad_rows(part, chunk)))
        outs.append(np.asarray(m)[:len(part)])
    return np.concatenate(outs), np.asarray(valid)


def make_loss(cfg: GHTTRunConfig, valid_OxS: np.ndarray):
    lam, mc = cfg.loss, cfg.model
    valid_OxS = jnp.asarray(valid_OxS)
    n_valid_O = valid_OxS.sum(1)

    def loss(params, batch, rng, train: bool):
        M = batch["M"]  # (B, O, S, Dp): m̄^P at every offset
        B, O, S, _ = M.shape
        k_o, k_n, k_noise, k_a = jax.random.split(rng, 4)
        o_B = jax.random.randint(k_o, (B,), 0, O) if train else jnp.zeros((B,), jnp.int32)
        nv_B = n_valid_O[o_B]
        n_B = jax.random.randint(k_n, (B,), 1, nv_B + 1) if train else jnp.maximum(nv_B // 2, 1)  # observed spans
        m_BxSxD = M[jnp.arange(B), o_B]
        j = jnp.arange(S)[None]
        obs, fut = j < n_B[:, None], (j >= n_B[:, None]) & (j < nv_B[:, None])
        m_in = m_BxSxD
        if train and lam.m_noise > 0:  # App. B.3: noisy observed latents
            rms = jnp.sqrt(jnp.mean(m_BxSxD ** 2))
            m_in = m_in + lam.m_noise * rms * jax.random.normal(k_noise, m_in.shape)
        mu, logvar, clips = G.action_encode(params, mc, m_in, obs)
        alpha = G.reparameterize(k_a, mu, logvar) if train else mu
        m_hat = G.action_decode(params, mc, alpha, clips, obs, fut)
        per_span = jnp.mean(jnp.abs(m_hat - m_BxSxD), -1)  # Eq. 5, mean over the latent's dimensions
        mid = jnp.mean(jnp.sum(jnp.where(fut, per_span, 0.0), -1))
        l1, nce = G.action_loss(alpha, G.text_embed(params, batch["text"]))  # Eqs. 3-4
        kl = jnp.mean(G.kl_normal(mu, logvar))
        total = lam.mid * mid + lam.action * (l1 + nce) + lam.kl * kl
        return total, {"mid": mid, "action_l1": l1, "action_nce": nce, "kl": kl}

    return loss


@dataclass
class TrainData:
    clips: np.ndarray
    M: np.ndarray  # (N, O, S, Dp)
    text: np.ndarray  # (N, L, 768)

    @property
    def num_items(self) -> int:
        return len(self.clips) * self.text.shape[1]

    def batch(self, idx):
        L = self.text.shape[1]
        c, lv = np.asarray(idx) // L, np.asarray(idx) % L
        return {"M": self.M[c], "text": self.text[c, lv]}


@functools.partial(jax.jit, static_argnames=("cfg",))
def _recognition_embeddings(params, cfg: G.GHTTConfig, M_first_NxSxD, text_NxD):
    """FC1 of the captions and μ^A of the whole clips, unit-normalised: one program (op by op, every
    validation compiled a few dozen one-op programs)."""
    N, S = M_first_NxSxD.shape[:2]
    mu, _, _ = G.action_encode(params, cfg, M_first_NxSxD, jnp.ones((N, S), bool))
    a = G.text_embed(params, text_NxD)
    unit = lambda x: x / jnp.linalg.norm(x, axis=-1, keepdims=True).clip(1e-6)  # noqa: E731
    return unit(a), unit(mu)


def recognition_scores(params, cfg: G.GHTTConfig, M_first_NxSxD, text_NxD, block: int = 32) -> dict:
    """Top-1/3 caption retrieval (R-Precision, the standard evaluator's code) of μ^A of whole clips."""
    from handx_jax.metrics import r_precision

    a, mu = _recognition_embeddings(params, cfg, jnp.asarray(M_first_NxSxD), jnp.asarray(text_NxD))
    hits, _ = r_precision(a, mu, block=min(block, len(mu)), top_k=3)
    return {"top1": float(hits[0]), "top3": float(hits[2])}


def train(run_dir: str | os.PathLike, cfg: GHTTRunConfig, *, stop_at=None, on_log=None, encoder=None) -> dict:
    from handx_jax import train as loop
    from handx_jax.dataset.format import Dataset
    from handx_jax.text.cache import open_cache
    from handx_jax.text.t5 import T5Config
    cfg.validate()
    for key in ("path", "encoder", "pose"):
        if not getattr(cfg.data, key):
            raise ConfigError(f"data.{key} is empty: give --data, --encoder and --ghtt-pose")
    pm = from_dict(G.GHTTConfig, run_config(cfg.data.pose, PP.FAMILY)["model"])
    if (pm.pose, pm.span) != (cfg.model.pose, cfg.model.span):  # P's sizes are the P run's
        cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, pose=pm.pose, span=pm.span))
    ds = Dataset.open(cfg.data.path)
    cache = open_cache(cfg.data.path, encoder if encoder is not None else cfg.data.encoder,
                       max_len=cfg.data.text_max_len, dtype=cfg.data.cache_dtype, joined=True)
    if int(cache.meta["d_model"]) != cfg.model.text_dim:
        cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, text_dim=int(cache.meta["d_model"])))
    n_levels = int(ds.meta["levels"])
    levels = list(cfg.data.levels) or list(range(n_levels))
    if any(not 0 <= v < n_levels for v in levels):
        raise ConfigError(f"data.levels {levels}: the dataset has caption levels 0..{n_levels - 1}")
    clips = np.asarray(ds.split("train", cfg.data.fraction))
    if not len(clips):
        raise DataError("the train split is empty", path=cfg.data.path)
    pose = PP.load(cfg.data.pose)
    pose_params, pose_step, norm = pose.params, pose.step, pose.norm
    M, valid = offset_latents(pose_params, cfg.model, norm.normalize(C.clip_frames(ds.motion[clips])))
    data = TrainData(clips, M, pooled_text(cache, clips, levels))
    enc_cfg = T5Config(**{k: v for k, v in cache.meta["encoder_config"].items()
                          if k in {f.name for f in dataclasses.fields(T5Config)}})
    record = {"family": FAMILY, "preset": cfg.preset, "model": to_dict(cfg.model), "data": to_dict(cfg.data),
              "loss": to_dict(cfg.loss), "sample": to_dict(cfg.sample), "data_fraction": cfg.data.fraction,
              "layers": cfg.model.action.layers, "dim": cfg.model.action.dim, "heads": cfg.model.action.heads,
              "ff": cfg.model.action.ff, **numbers(cfg, text_len=max(1, round(float(cache.meta["mean_tokens"]))),
                                                   encoder_cfg=enc_cfg),
              "pose_run": {"path": cfg.data.pose, "step": pose_step, "fingerprint": pose.fingerprint,
                           "train_flops": _train_flops(cfg.data.pose)},
              "text_cache": {"fingerprint": cache.meta["fingerprint"],
                             "encoder_fingerprint": cache.meta["encoder_fingerprint"]}}
    resume = ("model", "data", "loss", "train", "pose_run")
    loop.check_resume(Path(run_dir), {**record, "train": to_dict(cfg.train)}, resume)
    val = np.asarray(ds.split("val"))[:256]
    evaluate = None
    if len(val) >= 2:
        Mv, _ = offset_latents(pose_params, cfg.model, norm.normalize(C.clip_frames(ds.motion[val])))
        tv = pooled_text(cache, val, [0])[:, 0]

        def evaluate(params, ema, step):
            r = recognition_scores(ema or params, cfg.model, Mv[:, 0], tv)
            return {"eval/top1": r["top1"], "eval/top3": r["top3"]}

    return loop.train(Path(run_dir), loop.TrainSpec(
        init=lambda rng: G.init_action(rng, cfg.model), loss=make_loss(cfg, valid), cfg=cfg.train, config=record,
        get_batch=data.batch, num_examples=data.num_items, evaluate=evaluate,
        flops_per_sample=record["flops_per_sample"], resume_keys=resume), stop_at=stop_at, on_log=on_log)


def _train_flops(run_dir) -> float | None:
    """The training compute a run folder's last log line records (P's, carried into the A run's record)."""
    from handx_jax.infra.readers import read_jsonl

    p = Path(run_dir) / "metrics.jsonl"
    rows = [r for r in read_jsonl(p, strict=False) if isinstance(r, dict) and r.get("train_flops")] if p.exists() else []
    return float(rows[-1]["train_flops"]) if rows else None


# ------------------------------------------------------------------------------------------------
# Command-line hooks


def add_train_args(p) -> None:
    p.add_argument("--data", required=True, help="dataset directory (with a joined text cache)")
    p.add_argument("--encoder", required=True, help="frozen T5 encoder folder")
    p.add_argument("--ghtt-pose", required=True, metavar="POSE", help="the trained P run (`handx train ghtt-pose`)")


def config_from_args(args) -> GHTTRunConfig:
    return make_config(args.preset, args.set, data=args.data, encoder=args.encoder, pose=args.ghtt_pose)


def add_params_args(p) -> None:
    p.add_argument("--text-len", type=int, default=96, help="joined-caption tokens for the text FLOPs count")


def params_from_args(args):
    cfg = make_config(args.preset, args.set)
    P_, A = cfg.model.pose, cfg.model.action
    label = (f"ghtt {cfg.preset}: P L{P_.layers}+{P_.layers} d{P_.dim}, A L{A.layers}+{A.layers} d{A.dim}, "
             f"span {cfg.model.span}")
    return label, numbers(cfg, text_len=args.text_len)


def add_generate_args(p) -> None:
    p.add_argument("--observed-frames", type=int, default=16,
                   help="--task prediction: observed frames, at least one span (15) and below 60 (default 16)")
    p.add_argument("--path", choices=PATHS, help="action: P.b, P + A (default); pose: P.a, P alone (§3.2)")
    p.add_argument("--sigma-scale", type=float, help="sample latents from N(mu, s Sigma) (default: the run's, 5)")
    p.add_argument("--no-rectify", action="store_true",
                   help="decoded spans as they come, not continued from the frame before them (sample.rectify)")


def load_for_generate(args: argparse.Namespace, *, ema: bool, encoder, seed: int, batch_size: int):
    pick = lambda v, d: d if v is None else v  # noqa: E731
    GenerateOptions(pick(args.path, "action"), pick(args.sigma_scale, 5.0), args.observed_frames)  # checks first
    run = load(args.run, ema=ema, encoder=encoder, overrides=args.set)
    s = run.cfg.sample
    return run, GenerateOptions(pick(args.path, s.path), pick(args.sigma_scale, s.sigma_scale), args.observed_frames,
                                seed, batch_size, s.rectify and not args.no_rectify)
