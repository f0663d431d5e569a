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
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.config import ConfigError, apply_overrides, from_dict, get_preset, to_dict
from handx_jax.families import entry, run_config
from handx_jax.families.ghtt import common as C
from handx_jax.families.ghtt import pose as PP
from handx_jax.io import DataError
from handx_jax.models import ghtt as G
from handx_jax.models import ghtt_motion as HM
from handx_jax.train import TrainConfig

FAMILY = "ghtt"
PRESETS = G.PRESETS
TASKS = entry(FAMILY).tasks  # declared in the registry (families.FAMILIES)
PATHS = ("action", "pose")  # §3.2's P.b (P + A) and P.a (P alone)


@dataclass(frozen=True)
class DataConfig:
    path: str = ""
    encoder: str = ""
    pose: str = ""  # the trained P run (``handx train ghtt-pose``)
    fraction: float = 1.0
    levels: tuple[int, ...] = ()  # caption levels of the training items (empty: all)
    text_max_len: int = 128  # the joined text cache's
    cache_dtype: str = "float16"


@dataclass(frozen=True)
class LossConfig:
    """§3.3's weights λ4 = 1, λ5 = 0.1, λ6 = 1e-5; ``m_noise``: the std of App. B.3's noise on the observed
    latents, relative to their RMS (the paper's absolute 1.5 is in the scale of its own latents)."""

    mid: float = 1.0
    action: float = 0.1
    kl: float = 1e-5
    m_noise: float = 0.25


@dataclass(frozen=True)
class SampleConfig:
    """Prediction defaults (``handx generate`` flags override them): §4.2 samples N(μ, 5Σ)."""

    path: str = "action"
    sigma_scale: float = 5.0
    # Each predicted span's hand poses p start from the frame before it (the last observed frame, then each
    # span's last), the offset blended out linearly over the span: the paper's rectification of E^P's
    # trajectory (App. B.2, Eq. 10: linear interpolation with weights (t − i)/(t − 1)) applied where a
    # decoded span meets the frames before it. D^P decodes a span from the latent alone, which keeps the
    # gist of the poses, not the exact fingers: unrectified, the first predicted frame of a 200-step tiny
    # run was 21.7 mm (MPJPE-RA) from the truth where holding the last frame is 3.4 mm off.
    rectify: bool = True


TRAIN_PRESETS = {name: dataclasses.replace(PP.TRAIN_PRESETS[name],
                                           steps=200 * 3600 * 5 // 256 if name == "paper" else 1000)
                 for name in PRESETS}  # §3.3: A for 200 epochs


@dataclass(frozen=True)
class GHTTRunConfig:
    preset: str = "tiny"
    model: G.GHTTConfig = PRESETS["tiny"]
    train: TrainConfig = TRAIN_PRESETS["tiny"]
    data: DataConfig = field(default_factory=DataConfig)
    loss: LossConfig = LossConfig()
    sample: SampleConfig = SampleConfig()

    def validate(self) -> None:
        b = self.model.action
        if b.dim % b.heads:
            raise ConfigError(f"model.action.dim {b.dim} must be a multiple of model.action.heads {b.heads}")
        if self.sample.path not in PATHS:
            raise ConfigError(f"sample.path must be one of {', '.join(PATHS)}, got {self.sample.path!r}")
        if not self.sample.sigma_scale >= 0:
            raise ConfigError(f"sample.sigma_scale must be >= 0, got {self.sample.sigma_scale}")
        if not 0 < self.data.fraction <= 1:
            raise ConfigError(f"data.fraction must be in (0, 1], got {self.data.fraction}")


Config = GHTTRunConfig


def make_config(preset: str = "tiny", overrides: Sequence[str] = (), *, data: str = "", encoder: str = "",
                pose: str = "") -> GHTTRunConfig:
    """A run config of a named size; P's part (``model.pose``, ``model.span``) is the P run's when given."""
    model = get_preset(PRESETS, preset, "G-HTT preset")
    if pose:
        pm = from_dict(G.GHTTConfig, run_config(pose, PP.FAMILY)["model"])
        model = dataclasses.replace(model, pose=pm.pose, span=pm.span)
    cfg = GHTTRunConfig(preset=preset, model=model, train=TRAIN_PRESETS[preset],
                        data=DataConfig(*(str(Path(p).absolute()) if p else "" for p in (data, encoder, pose))))
    return apply_overrides(cfg, overrides)


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
    for s in range(0, len(Hn_NxFx153), chunk):
        m, valid = one(jnp.asarray(Hn_NxFx153[s:s + chunk]))
        outs.append(np.asarray(m))
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


def recognition_scores(params, cfg: G.GHTTConfig, M_first_NxSxD, text_NxD, block: int = 32) -> dict:
    """Top-1/3 caption retrieval (R-Precision, the standard evaluator's code) of μ^A of whole clips."""
    from handx_jax.metrics import r_precision

    S = M_first_NxSxD.shape[1]
    mu, _, _ = G.action_encode(params, cfg, jnp.asarray(M_first_NxSxD), jnp.ones((len(M_first_NxSxD), S), bool))
    a = G.text_embed(params, jnp.asarray(text_NxD))
    unit = lambda x: x / jnp.linalg.norm(x, axis=-1, keepdims=True).clip(1e-6)  # noqa: E731
    hits, _ = r_precision(unit(a), unit(mu), block=min(block, len(mu)), top_k=3)
    return {"top1": float(hits[0]), "top3": float(hits[2])}


def train(run_dir: str | os.PathLike, cfg: GHTTRunConfig, *, stop_at=None, on_log=None, encoder=None) -> dict:
    from handx_jax import train as loop
    from handx_jax.data.dataset import Dataset
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
    from handx_jax.io import read_jsonl

    p = Path(run_dir) / "metrics.jsonl"
    rows = [r for r in read_jsonl(p, strict=False) if isinstance(r, dict) and r.get("train_flops")] if p.exists() else []
    return float(rows[-1]["train_flops"]) if rows else None


# ------------------------------------------------------------------------------------------------
# Loading, prediction and recognition


@dataclass(frozen=True)
class GenerateOptions:
    path: str = "action"
    sigma_scale: float = 5.0
    observed_frames: int = 16
    seed: int = 0
    batch_size: int = 256
    rectify: bool = True  # SampleConfig.rectify

    def __post_init__(self) -> None:
        if self.path not in PATHS:
            raise ValueError(f"--path must be one of {', '.join(PATHS)}, got {self.path!r}")
        if not self.sigma_scale >= 0:
            raise ValueError(f"--sigma-scale must be >= 0, got {self.sigma_scale}")
        if not (isinstance(self.observed_frames, int) and 0 < self.observed_frames < 60):
            raise ValueError(f"--observed-frames must be in (0, 60), got {self.observed_frames}")


def rectify(span_BxTx153, before_Bx153):
    """Shift a decoded span's hand poses p so that its first frame is the frame before it, the shift blended
    out linearly over the span (Eq. 10's weights (t − i)/(t − 1), i = 1..t); its motion v and r are kept."""
    t = span_BxTx153.shape[1]
    w_T = (t - 1 - jnp.arange(t)) / max(t - 1, 1)
    delta = before_Bx153[:, None, HM.P_SLICE] - span_BxTx153[:, :1, HM.P_SLICE]
    return span_BxTx153.at[..., HM.P_SLICE].add(w_T[None, :, None] * delta)


@functools.partial(jax.jit, static_argnames=("cfg", "n_future", "path", "rectified"))
def predict_frames(pose_params, action_params, cfg: G.GHTTConfig, Hn_BxSxTx153, key, sigma_scale, *,
                   n_future: int, path: str, rectified: bool = True):
    """The whole sampling of §3.2 in one program: the observed spans' normalised frames (B, n, t, 153) → the
    next ``n_future`` spans' normalised frames (B, n_future·t, 153), one sample per row."""
    B, n, t, _ = Hn_BxSxTx153.shape
    mu, logvar, _ = G.pose_encode(pose_params, cfg, Hn_BxSxTx153.reshape(B * n, t, -1))
    mu, logvar = mu.reshape(B, n, -1), logvar.reshape(B, n, -1)
    keys = jax.random.split(key, n_future + 1)
    spans = []

    def put(span):  # a decoded span, continued from the frame before it (SampleConfig.rectify)
        before = spans[-1][:, -1] if spans else Hn_BxSxTx153[:, -1, -1]
        spans.append(rectify(span, before) if rectified else span)

    m = G.reparameterize(keys[0], mu[:, -1], logvar[:, -1], sigma_scale)
    put(G.pose_decode(pose_params, cfg, m))  # the first future span from the last observed latent
    if n_future > 1 and path == "action":  # P.b: A's future latents, expanded by D^P
        S = n + n_future - 1
        m_all = jnp.concatenate([mu, jnp.zeros((B, n_future - 1, mu.shape[-1]))], 1)
        obs = jnp.arange(S)[None] < n
        mu_a, logvar_a, clips = G.action_encode(action_params, cfg, m_all, jnp.broadcast_to(obs, (B, S)))
        alpha = G.reparameterize(keys[1], mu_a, logvar_a, sigma_scale)
        m_hat = G.action_decode(action_params, cfg, alpha, clips, jnp.broadcast_to(obs, (B, S)),
                                jnp.broadcast_to(~obs, (B, S)))
        for j in range(n, S):
            put(G.pose_decode(pose_params, cfg, m_hat[:, j]))
    else:  # P.a: each predicted span fed back to E^P (or a single span)
        for k in range(1, n_future):
            mu_k, logvar_k, _ = G.pose_encode(pose_params, cfg, spans[-1])
            put(G.pose_decode(pose_params, cfg, G.reparameterize(keys[k + 1], mu_k, logvar_k, sigma_scale)))
    return jnp.concatenate(spans, 1)


@jax.jit
def _place(H_Tx153, R0, o0, scale):
    return HM.from_frames(H_Tx153, R0, o0, scale, first_is_anchor=False)


_place_rows = jax.jit(jax.vmap(_place))


@dataclass
class GHTTRun:
    run_dir: Path
    cfg: GHTTRunConfig
    pose_params: Any
    params: Any
    norm: C.Norm
    step: int
    encoder_path: str
    encoder: Any = None
    tasks: tuple[str, ...] = TASKS

    # -- prediction ------------------------------------------------------------------------------
    def generate(self, prompts, opts: GenerateOptions, *, samples: int = 1, task: str = "prediction", sources=None,
                 keyframes=(30,), fixed_hand: str = "left") -> np.ndarray:
        """K samples per observed clip → joints (P, K, F, 2, 21, 3), the first ``observed_frames`` frames the
        source's own. Text is not read (G-HTT infers the action from the motion, §3.2)."""
        if task == "recognition":
            raise ValueError("recognition is not generation: score it with `handx eval recognition --run RUN`")
        if task != "prediction":
            raise ValueError(f"the ghtt family does not generate {task!r} (from text alone or otherwise): it "
                             f"predicts how an observed motion continues (--task prediction) and recognises "
                             f"captions (handx eval recognition)")
        if sources is None or len(sources) != len(prompts):
            raise ValueError("--task prediction needs one source clip per prompt")
        t, N = self.cfg.model.span, opts.observed_frames
        src = np.stack([np.asarray(s, np.float32) for s in sources])
        F = src.shape[1]
        if N < t:
            raise ValueError(f"--observed-frames must be at least one G-HTT span ({t} frames), got {N}")
        if N >= F:
            raise ValueError(f"--observed-frames must be below the clip's {F} frames, got {N}")
        n = min(N // t, self.cfg.model.max_spans - 1)
        n_future = math.ceil((F - N) / t)
        n = min(n, self.cfg.model.max_spans - n_future + 1)
        if n < 1:
            raise ValueError(f"{F - N} frames to predict need more than the {self.cfg.model.max_spans} spans of the "
                             f"phase table (model.max_spans)")
        obs = src[:, :N]
        H = np.asarray(C._frames_jit(jnp.asarray(obs)))[:, N - n * t:]  # the last n spans, ending at frame N
        Hn = self.norm.normalize(H).reshape(len(src), n, t, HM.FRAME_DIM)
        R, o = HM.palm_frames(jnp.asarray(obs[:, N - 1]))
        scale = jax.vmap(HM.hand_scale)(jnp.asarray(obs))
        K = samples
        rows = np.repeat(np.arange(len(src)), K)
        out = np.zeros((len(rows), F - N, 2, 21, 3), np.float32)
        key = jax.random.PRNGKey(opts.seed)
        bs = opts.batch_size
        for s in range(0, len(rows), bs):
            r = rows[s:s + bs]
            pad = bs - len(r) if len(rows) > bs else 0  # one compiled shape for every chunk
            rr = np.concatenate([r, np.full(pad, r[-1])])
            Hf = predict_frames(self.pose_params, self.params, self.cfg.model, jnp.asarray(Hn[rr]),
                                jax.random.fold_in(key, s), jnp.float32(opts.sigma_scale), n_future=n_future,
                                path=opts.path, rectified=opts.rectify)
            Hf = self.norm.denormalize(np.asarray(Hf))[:, :F - N]
            j = _place_rows(jnp.asarray(Hf), R[rr], o[rr], scale[rr])
            out[s:s + len(r)] = np.asarray(j)[:len(r)]
        full = np.concatenate([src[rows][:, :N], out], 1)
        return full.reshape(len(src), K, F, 2, 21, 3)

    def generate_long(self, segments, opts, *, samples: int = 1, source=None):
        raise ValueError("the ghtt family does not do --task long")

    def describe(self, opts: GenerateOptions) -> str:
        how = "P.b (P + A)" if opts.path == "action" else "P.a (P alone)"
        return (f"path {how}, latents from N(mu, {opts.sigma_scale:g} Sigma), {opts.observed_frames} observed "
                f"frames, spans {'rectified' if opts.rectify else 'as decoded'}, step {self.step}")

    # -- recognition -----------------------------------------------------------------------------
    def embed_motions(self, joints_NxFx2x21x3) -> np.ndarray:
        """μ^A of each whole clip (all its spans observed, from frame 0), unit-normalised (N, D)."""
        x = np.asarray(joints_NxFx2x21x3, np.float32)
        t = self.cfg.model.span
        S = min(x.shape[1] // t, self.cfg.model.max_spans)
        Hn = self.norm.normalize(C.clip_frames(x))[:, :S * t].reshape(len(x), S, t, HM.FRAME_DIM)
        out = []
        for s in range(0, len(x), 256):
            m = C.span_latents(self.pose_params, self.cfg.model, jnp.asarray(Hn[s:s + 256]))
            mu, _, _ = G.action_encode(self.params, self.cfg.model, m, jnp.ones(m.shape[:2], bool))
            out.append(np.asarray(mu))
        e = np.concatenate(out)
        return e / np.maximum(np.linalg.norm(e, axis=-1, keepdims=True), 1e-6)

    def embed_texts(self, prompts) -> np.ndarray:
        """FC1 of each prompt's caption feature (the mean of the frozen encoder's states over the joined
        prompt, as the text cache stores it), unit-normalised (N, D)."""
        from handx_jax.text.cache import joined_texts
        from handx_jax.text.hf import as_encoder

        if self.encoder is None:
            self.encoder = as_encoder(self.encoder_path)
        texts = [t["joined"][0] for t in joined_texts([{"left": [p.left], "right": [p.right],
                                                        "interaction": [p.interaction]} for p in prompts])]
        out = []
        for s in range(0, len(texts), 256):
            e, h = self.encoder.encode(texts[s:s + 256], max_len=self.cfg.data.text_max_len)
            m = e.mask_BxL.astype(np.float32)[..., None]
            h = h.astype(self.cfg.data.cache_dtype).astype(np.float32)
            out.append((h * m).sum(1) / np.maximum(m.sum(1), 1.0))
        a = np.asarray(G.text_embed(self.params, jnp.asarray(np.concatenate(out))))
        return a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-6)


def load(run_dir: str | os.PathLike, *, ema: bool = True, encoder=None, overrides: Sequence[str] = ()) -> GHTTRun:
    from handx_jax.train import load_params

    run_dir = Path(run_dir)
    doc = run_config(run_dir, FAMILY)
    cfg = from_dict(GHTTRunConfig, doc)
    bad = [o for o in overrides if not o.split("=", 1)[0].strip().startswith("sample.")]
    if bad:
        raise ValueError(f"generation can only override sample.* keys, got {bad}")
    cfg = apply_overrides(cfg, overrides)
    cfg.validate()
    pose = PP.load(doc["pose_run"]["path"])
    if pose.fingerprint != doc["pose_run"]["fingerprint"]:
        raise DataError(f"the P run changed since this G-HTT run was trained on it (fingerprint {pose.fingerprint}, "
                        f"recorded {doc['pose_run']['fingerprint']})", path=doc["pose_run"]["path"])
    params, step = load_params(run_dir, ema=ema)
    return GHTTRun(run_dir, cfg, pose.params, params, pose.norm, step,
                   encoder if encoder is not None else cfg.data.encoder)


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
