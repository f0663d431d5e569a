"""A loaded G-HTT run: prediction (§3.2, paths P.b and P.a, rectified spans) and recognition embeddings.

One concern: what a trained run does (``load`` → :class:`GHTTRun`); the family module re-exports it."""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.config import from_dict
from handx_jax.families import generation_config, run_config
from handx_jax.families.ghtt import common as C
from handx_jax.families.ghtt import pose as PP
from handx_jax.infra.errors import DataError
from handx_jax.models import ghtt as G
from handx_jax.models import ghtt_motion as HM
from handx_jax.families.ghtt.config import FAMILY, PATHS, TASKS, GHTTRunConfig


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
# The observed clips' palm frames at their last frame and their hand sizes, and the whole clips' μ^A: one
# program each (op by op, each compiled a few dozen one-op programs per run of the command).
_palm_frames = jax.jit(HM.palm_frames)
_hand_scales = jax.jit(jax.vmap(HM.hand_scale))
_text_embed = jax.jit(G.text_embed)


@functools.partial(jax.jit, static_argnames=("cfg",))
def _clip_embeddings(pose_params, params, cfg: G.GHTTConfig, Hn_BxSxTx153):
    m = C.span_latents(pose_params, cfg, Hn_BxSxTx153)
    return G.action_encode(params, cfg, m, jnp.ones(m.shape[:2], bool))[0]


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
        R, o = (np.asarray(a) for a in _palm_frames(jnp.asarray(obs[:, N - 1])))  # host arrays: rows picked below
        scale = np.asarray(_hand_scales(jnp.asarray(obs)))
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
            out.append(np.asarray(_clip_embeddings(self.pose_params, self.params, self.cfg.model,
                                                   jnp.asarray(Hn[s:s + 256]))))
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
        a = np.asarray(_text_embed(self.params, jnp.asarray(np.concatenate(out))))
        return a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-6)


def load(run_dir: str | os.PathLike, *, ema: bool = True, encoder=None, overrides: Sequence[str] = ()) -> GHTTRun:
    from handx_jax.train import load_params

    run_dir = Path(run_dir)
    doc = run_config(run_dir, FAMILY)
    cfg = generation_config(from_dict(GHTTRunConfig, doc), overrides)
    pose = PP.load(doc["pose_run"]["path"])
    if pose.fingerprint != doc["pose_run"]["fingerprint"]:
        raise DataError(f"the P run changed since this G-HTT run was trained on it (fingerprint {pose.fingerprint}, "
                        f"recorded {doc['pose_run']['fingerprint']})", path=doc["pose_run"]["path"])
    params, step = load_params(run_dir, ema=ema)
    return GHTTRun(run_dir, cfg, pose.params, params, pose.norm, step,
                   encoder if encoder is not None else cfg.data.encoder)
