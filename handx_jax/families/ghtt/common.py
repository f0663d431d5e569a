"""What both G-HTT stages share: the clips as frames (App. B.2), their normalisation, P's augmentation
(App. B.3) and the P forward passes the A stage and generation reuse."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_npz
from handx_jax.models import ghtt as G
from handx_jax.models import ghtt_motion as HM

NORM_FILE = "ghtt_norm.npz"
STD_FLOOR = 1e-3  # features that never vary (the wrist's p, frame 0's v) are left at their scale, not blown up


@dataclass(frozen=True)
class Norm:
    """Per-feature mean and std of the 153 frame values over the train clips' frames."""

    mean: np.ndarray
    std: np.ndarray

    def normalize(self, H):
        return (H - self.mean) / self.std

    def denormalize(self, H):
        return H * self.std + self.mean

    def save(self, run_dir) -> None:
        np.savez(Path(run_dir) / NORM_FILE, mean=self.mean, std=self.std)

    @classmethod
    def load(cls, run_dir) -> "Norm":
        p = Path(run_dir) / NORM_FILE
        if not p.exists():
            raise DataError(f"no {NORM_FILE} (the frame statistics the P run was trained with)", path=run_dir)
        z = read_npz(p, keys=("mean", "std"), kind="f", finite=True)
        for k in ("mean", "std"):
            if z[k].shape != (HM.FRAME_DIM,):
                raise DataError(f"shape {z[k].shape}; a G-HTT frame has {HM.FRAME_DIM} values", path=p, field=k)
        if (z["std"] <= 0).any():
            raise DataError("holds values <= 0: the frames are divided by it", path=p, field="std")
        return cls(np.asarray(z["mean"], np.float32), np.asarray(z["std"], np.float32))


_frames_jit = jax.jit(jax.vmap(lambda j: HM.to_frames(j)[0]))


def pad_rows(x: np.ndarray, rows: int) -> np.ndarray:
    """``x`` with its last row repeated up to ``rows`` rows (one compiled shape for every chunk)."""
    return np.concatenate([x, np.repeat(x[-1:], rows - len(x), 0)]) if len(x) < rows else x


def clip_frames(joints_NxFx2x21x3, chunk: int = 512) -> np.ndarray:
    """H (N, F, 153) of whole clips (v of frame 0 the identity). Every chunk is padded to ``chunk`` clips, so
    the train, validation and test clips of every command run one program (each count of clips compiled its
    own, ~0.5 CPU-s apiece, where the padded clips cost milliseconds). XLA's code for another batch size may
    round differently in the last bit (measured: 6e-7 m at most in H), so H is that of the padded batch."""
    x = np.asarray(joints_NxFx2x21x3, np.float32)
    parts = [x[s:s + chunk] for s in range(0, len(x), chunk)]
    return np.concatenate([np.asarray(_frames_jit(pad_rows(p, chunk)))[:len(p)] for p in parts]) if parts else \
        np.zeros((0, x.shape[1], HM.FRAME_DIM), np.float32)


def fit_norm(H_NxFx153: np.ndarray) -> Norm:
    flat = H_NxFx153.reshape(-1, HM.FRAME_DIM).astype(np.float64)
    return Norm(flat.mean(0).astype(np.float32), np.maximum(flat.std(0), STD_FLOOR).astype(np.float32))


@dataclass(frozen=True)
class AugConfig:
    """App. B.3's input noise for P (p in hand-size units; angles in degrees; translations in cm).

    The paper writes N(0, 0.025 I) for p; read here as a standard deviation of 0.025 hand sizes (~2 mm),
    since a variance of 0.025 (16% of a hand) would bury the finger poses the evaluator reads."""

    on: bool = True
    p_std: float = 0.025
    v_deg: float = 1.25
    v_cm: float = 0.75
    r_deg: float = 5.0
    r_cm: float = 5.0


def _perturb_rigid(key, x_x9, deg, cm):
    """Compose a 9-D rigid transform with a random rotation (uniform axis, N(0, deg) angle) and add N(0, cm)
    to its translation (metres)."""
    k1, k2, k3 = jax.random.split(key, 3)
    axis = jax.random.normal(k1, x_x9.shape[:-1] + (3,))
    Rn = HM.axis_angle_rotation(axis, jnp.deg2rad(deg) * jax.random.normal(k2, x_x9.shape[:-1]))
    R = Rn @ HM.rot_from_6d(x_x9[..., :6])
    t = x_x9[..., 6:] + 0.01 * cm * jax.random.normal(k3, x_x9.shape[:-1] + (3,))
    return HM.rigid_9d(R, t)


def augment(key, H_BxTx153, aug: AugConfig):
    """P's input augmentation (App. B.3) on raw (not normalised) frames."""
    if not aug.on:
        return H_BxTx153
    kp, kv, kr = jax.random.split(key, 3)
    B, T = H_BxTx153.shape[:2]
    p = H_BxTx153[..., HM.P_SLICE] + aug.p_std * jax.random.normal(kp, (B, T, 2 * HM.P_DIM))
    v = _perturb_rigid(kv, H_BxTx153[..., HM.V_SLICE].reshape(B, T, 2, HM.RIGID), aug.v_deg, aug.v_cm)
    r = _perturb_rigid(kr, H_BxTx153[..., HM.R_SLICE], aug.r_deg, aug.r_cm)
    return jnp.concatenate([p, v.reshape(B, T, 2 * HM.RIGID), r], -1)


def span_latents(pose_params, cfg: G.GHTTConfig, Hn_BxSxTx153):
    """μ^P of every span (B, S, D): E^P on each span (the A stage's m̄^P, §3.3: pre-computed from GT with E^P)."""
    B, S, T, _ = Hn_BxSxTx153.shape
    mu, _, _ = G.pose_encode(pose_params, cfg, Hn_BxSxTx153.reshape(B * S, T, -1))
    return mu.reshape(B, S, -1)


def spans_at(H_BxFx153, offset_B, n_spans: int, span: int):
    """The ``n_spans`` consecutive spans from frame ``offset`` (B, S, t, 153), frame indices clamped to the
    clip (spans past its end are marked invalid by the caller), and which are wholly inside (B, S)."""
    F = H_BxFx153.shape[1]
    idx_BxSxt = offset_B[:, None, None] + jnp.arange(n_spans)[None, :, None] * span + jnp.arange(span)[None, None, :]
    valid_BxS = (offset_B[:, None] + (jnp.arange(n_spans)[None, :] + 1) * span) <= F
    g = jax.vmap(lambda h, i: h[i])(H_BxFx153, jnp.clip(idx_BxSxt, 0, F - 1))
    return g, valid_BxS
