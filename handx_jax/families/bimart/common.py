"""What both BimArt families read from a hand-object corpus (``handx data objects``): object features, contact maps
normalised for diffusion, the motion X = [H | D], per-channel statistics, the diffusion schedule, and the configs
both runs share.

- Object condition per frame: objects/features.py's [O | G | s_o] (§3.1), s_o from the clip's object (a corpus clip's
  rebuilt from its record's category and instance seed; an ARCTIC sequence's mesh template) sampled on its surface
  (Eq. 1 at App. B's open angle). ``object_inputs`` builds them from (objects, states, mapped basis points) alone,
  so a corpus clip (``prepare``) and an ARCTIC sequence (``arctic_windows``) take the same path.
- Contact maps (§3.2): the corpus's distances (N, F, hand, part, K) clipped to [0, 0.2] m (the range App. D's
  Fig. III normalises to: beyond 20 cm a hand is simply "far") and mapped linearly to [-1, 1].
- Motion (§3.3): per hand the 21 joints, then (``hand_rep="surface"``) J fixed points of the hand surface
  (hand_surface.py, a function of the joints; the paper's H is J MANO vertices). Our hand has no MANO
  parameters: the joints are its skeleton, what refinement (Eq. 8) fits and optimises, so they ride along as 21
  more keypoints. D is the vector from each keypoint to the nearest point of the object, -d(p) ∇d(p) of the
  analytic signed distance (exact for a distance field; BimArt's nearest mesh vertex). Positions are relative to
  the object's first-frame position, the origin G's translation is measured from.

One concern: the data both families share; each family module holds its own training and sampling.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import hand_surface as hs
from handx_jax.config import ConfigError
from handx_jax.families.diffusion.process import cosine_schedule
from handx_jax.infra.errors import DataError
from handx_jax.models import bimart as BM
from handx_jax.objects import object_sdf, surface_samples
from handx_jax.objects.bps import basis_points, category_scale_angle, object_scale, part_bps_points
from handx_jax.objects.features import object_features
from handx_jax.optim import OptimConfig
from handx_jax.train import TrainConfig

CONTACT_MAX_M = 0.2
STD_FLOOR = 1e-3

# §3.5: Adam, lr 1e-4, cosine schedule, EMA, 200 epochs. The CPU sizes take a short recipe at a higher rate.
PAPER_TRAIN = TrainConfig(steps=100_000, batch_size=64, log_every=200, ckpt_every=10_000, ema_decay=0.999,
                          ema_warmup=True, optim=OptimConfig(lr=1e-4, b2=0.999, schedule="cosine", warmup_steps=500))
CPU_TRAIN = dataclasses.replace(PAPER_TRAIN, steps=1500, batch_size=32, log_every=50, ckpt_every=500,
                                optim=dataclasses.replace(PAPER_TRAIN.optim, lr=1e-3, warmup_steps=50))
TRAIN_PRESETS = {name: (PAPER_TRAIN if name == "paper" else CPU_TRAIN) for name in BM.PRESETS}


@dataclass(frozen=True)
class DataConfig:
    path: str = ""
    fraction: float = 1.0


def check_model(m: BM.BimArtConfig) -> None:
    if m.block.dim % m.block.heads or m.block.dim % 2:
        raise ConfigError(f"model.block.dim {m.block.dim} must be even and a multiple of model.block.heads")
    if m.hand_rep not in BM.HAND_REPS:
        raise ConfigError(f"model.hand_rep must be one of {', '.join(BM.HAND_REPS)}, got {m.hand_rep!r}")
    for n in ("k", "keypoints", "steps", "frames"):
        if getattr(m, n) < 1:
            raise ConfigError(f"model.{n} must be >= 1, got {getattr(m, n)}")


def schedule(cfg: BM.BimArtConfig):
    """The diffusion schedule of both models: cosine over cfg.steps (50, §3.5) — at 50 steps the linear DDPM betas
    of Ho et al. would not reach noise (ᾱ_T ≈ 0.6)."""
    return cosine_schedule(cfg.steps)


def contact_to_unit(d):
    return jnp.clip(d, 0.0, CONTACT_MAX_M) / (CONTACT_MAX_M / 2) - 1.0


def unit_to_contact(u):
    return (u + 1.0) * (CONTACT_MAX_M / 2)


def surface_index(j: int) -> np.ndarray:
    """The J hand-surface points of H (indices into hand_surface.surface_points): evenly spaced over its list,
    which runs capsule by capsule, so every bone and fingertip gets its share."""
    return np.unique(np.round(np.linspace(0, hs.N_SURFACE_POINTS - 1, j)).astype(np.int32))


def keypoints(joints_x21x3, cfg: BM.BimArtConfig):
    """H of one or more hands: (..., P, 3) = the 21 joints, then (surface rep) the J surface points."""
    if cfg.hand_rep == "joints":
        return joints_x21x3
    pts, _ = hs.surface_points(joints_x21x3)
    return jnp.concatenate([joints_x21x3, pts[..., surface_index(cfg.keypoints), :]], -2)


@jax.jit
def _nearest_vectors(obj, states_Tx7, pts_TxPx3):
    """D: from each point to the nearest point of the object, -d ∇d of its signed distance, (T, P, 3)."""
    def one(state, p):
        def d(q):
            return object_sdf(obj, state, q[None])[0][0]
        v, g = jax.vmap(jax.value_and_grad(d))(p)
        return -v[:, None] * g
    return jax.vmap(one)(states_Tx7, pts_TxPx3)


@dataclass
class Clips:
    """The prepared arrays of some object trajectories (rows = ``clips``): corpus clips, or windows of an ARCTIC
    sequence (``arctic_windows``)."""

    clips: np.ndarray
    obj: np.ndarray        # (N, F, 6K + 7) object features
    contact: np.ndarray    # (N, F, 4K) in [-1, 1]
    states: np.ndarray     # (N, F, 7)
    bps_points: np.ndarray  # (N, 2, K, 3)
    records: list
    joints: np.ndarray | None  # (N, F, 2, 21, 3) world, metres; None where the source has no hands
    motion: np.ndarray | None = None  # (N, F, X) raw, object-relative
    objects: list | None = None  # (N,) the ArticulatedObject of each row (refinement's signed distance)


def open_corpus(path):
    from handx_jax.dataset.format import Dataset
    from handx_jax.synthesis.object_build import open_object_annotations

    ds = Dataset.open(path)
    return ds, open_object_annotations(path)


def object_scales(objects, scale_angles) -> np.ndarray:
    """s_o (Eq. 1) of each object, from 1024 surface samples per part with the top part opened to its scale angle
    (App. B's heuristic per category). An object given several times (an ARCTIC sequence's windows) is sampled once."""
    done: dict = {}
    for obj, angle in zip(objects, scale_angles):
        if (id(obj), angle) not in done:
            pts = jnp.stack([surface_samples(obj, p, 1024, 0 if p == 0 else 1)[0] for p in (0, 1)])
            done[id(obj), angle] = float(object_scale(obj, pts, angle))
    return np.asarray([done[id(obj), angle] for obj, angle in zip(objects, scale_angles)], np.float32)


_features = jax.jit(jax.vmap(object_features, (0, None, 0, 0)))
# One program for the mapping onto a mesh object's parts (op by op it took 4-5 s of dispatch and compiles).
_part_bps = jax.jit(part_bps_points, static_argnames=("n_samples", "seed", "scale_angle"))


def check_shapes(K: int, F: int, cfg: BM.BimArtConfig, path, what: str = "clips") -> None:
    if K != cfg.k:
        raise DataError(f"the corpus maps K = {K} basis points per part, the model is configured with model.k = "
                        f"{cfg.k} (build with --bps-k {cfg.k} or set model.k={K})", path=path)
    if F != cfg.frames:
        raise DataError(f"{what} have {F} frames, the model is configured with model.frames = {cfg.frames}",
                        path=path)


def object_inputs(clips, objects, states_NxFx7, bps_points_Nx2xKx3, records, scale_angles, cfg: BM.BimArtConfig, *,
                  contact_NxFx2x2xK=None, joints_NxFx2x21x3=None, motion: bool = False) -> Clips:
    """The model inputs of object trajectories, wherever they come from (a corpus clip, an ARCTIC sequence): the
    object condition [O | G | s_o] (§3.1), the contact maps in [-1, 1] where known (else the "far" value, read only
    by ``--contact ground_truth``, which refuses a source without hands) and, with ``motion``, X = [H | D] of the
    given hands, positions relative to the first frame's object translation t0."""
    states = np.asarray(states_NxFx7, np.float32)
    bps = np.asarray(bps_points_Nx2xKx3, np.float32)
    N, F = states.shape[:2]
    K = bps.shape[2]
    s_o = object_scales(objects, scale_angles)
    basis = np.asarray(basis_points(K, seed=0))
    obj = np.asarray(_features(jnp.asarray(bps), basis, jnp.asarray(s_o), jnp.asarray(states)))
    if contact_NxFx2x2xK is None:
        cm = np.full((N, F, 4 * K), CONTACT_MAX_M, np.float32)
    else:
        cm = np.asarray(contact_NxFx2x2xK, np.float32).reshape(N, F, -1)
    joints = None if joints_NxFx2x21x3 is None else np.asarray(joints_NxFx2x21x3, np.float32)
    out = Clips(np.asarray(clips, np.int64), obj, np.asarray(contact_to_unit(cm)), states, bps, list(records),
                joints, objects=list(objects))
    if motion:
        if joints is None:
            raise ValueError("X = [H | D] needs the hands: the source has no joints")
        rows = []
        for i, o in enumerate(objects):
            H = np.asarray(keypoints(jnp.asarray(joints[i]), cfg))                       # (F, 2, P, 3)
            t0 = states[i, 0, 4:7]
            if cfg.hand_rep == "surface":
                D = np.asarray(_nearest_vectors(o, jnp.asarray(states[i]), jnp.asarray(H.reshape(F, -1, 3))))
                x = np.concatenate([H - t0, D.reshape(H.shape)], -1)
            else:
                x = H - t0
            rows.append(x.reshape(F, -1))
        out.motion = np.stack(rows).astype(np.float32)
    return out


def prepare(path, clips, cfg: BM.BimArtConfig, *, motion: bool) -> Clips:
    """The model inputs of ``clips`` (indices into the corpus at ``path``)."""
    from handx_jax.synthesis.object_build import clip_object

    ds, ann = open_corpus(path)
    clips = np.asarray(clips, np.int64)
    check_shapes(ann["bps_points"].shape[2], ds.motion.shape[1], cfg, path)
    records = [ann["objects"][int(i)] for i in clips]
    return object_inputs(clips, [clip_object(r) for r in records], ann["object_state"][clips],
                         ann["bps_points"][clips], records,
                         [category_scale_angle(r["category"]) for r in records], cfg,
                         contact_NxFx2x2xK=ann["contact_map"][clips], joints_NxFx2x21x3=ds.motion[clips],
                         motion=motion)


def arctic_windows(root, seq: str, cfg: BM.BimArtConfig, *, start: int | None = None,
                   limit: int | None = None) -> Clips:
    """The model inputs of an ARCTIC sequence (``interop/arctic.py``'s layout): its object template as a mesh
    object, its trajectory cut into consecutive windows of ``cfg.frames`` frames from frame 0 (the frames after the
    last whole window are left out), or the one window from ``start``; at most ``limit`` windows. The basis is
    mapped onto the mesh's parts as the corpus build maps it onto a procedural object's (``objects/bps.py``), with
    App. B's scale angle for ARCTIC's objects. Frames are taken as stored: ARCTIC's ``raw_seqs`` run at its
    images' rate, 30 fps, this project's rate. Where the sequence has hands (ARCTIC's processed joints), they and
    their contact maps ride along (the part contact F1 and ``--contact ground_truth`` read them).

    Each row's record: ``{"source": "arctic", "category", "seq", "start", "frames"}``; ``clips`` are the windows'
    first frames."""
    from handx_jax.interop import arctic as A

    states = A.read_object_states(root, seq)
    name = A.SEQ_RE.match(seq.partition("/")[2])["object"]
    obj = A.read_object(root, name)
    T, F = len(states), cfg.frames
    seq_file = Path(root) / "raw_seqs" / f"{seq}.object.npy"
    if start is not None:
        if not 0 <= start <= T - F:
            raise DataError(f"--start {start}: the sequence has {T} frames, a window of {F} starts in [0, {T - F}]",
                            path=seq_file)
        starts = [start]
    else:
        if T < F:
            raise DataError(f"the sequence has {T} frames, fewer than the model's window of {F}", path=seq_file)
        starts = list(range(0, T - F + 1, F))
    starts = starts[:limit] if limit else starts
    joints = None
    if (seq_file.parent / f"{seq.partition('/')[2]}.mano.npy").exists():
        joints = A.read_sequence(root, seq).joints_Tx2x21x3    # ARCTIC's processed joints, or None
    angle = category_scale_angle(name)
    bps, _ = _part_bps(obj, basis_points(cfg.k, seed=0), scale_angle=float(angle))
    idx = np.asarray(starts)[:, None] + np.arange(F)
    n = len(starts)
    win_joints = contact = None
    if joints is not None:
        from handx_jax.synthesis.object_motion import stack_objects
        from handx_jax.synthesis.object_physics import contact_maps

        win_joints = joints[idx]
        contact = contact_maps(stack_objects([obj] * n), np.repeat(np.asarray(bps)[None], n, 0), states[idx],
                               win_joints)
    records = [{"source": "arctic", "category": name, "seq": seq, "start": int(s), "frames": F} for s in starts]
    return object_inputs(np.asarray(starts), [obj] * n, states[idx], np.repeat(np.asarray(bps)[None], n, 0),
                         records, [angle] * n, cfg, contact_NxFx2x2xK=contact, joints_NxFx2x21x3=win_joints)


@dataclass
class Norm:
    mean: np.ndarray
    std: np.ndarray

    @classmethod
    def fit(cls, x_NxFxX: np.ndarray) -> "Norm":
        flat = x_NxFxX.reshape(-1, x_NxFxX.shape[-1]).astype(np.float64)
        return cls(flat.mean(0).astype(np.float32), np.maximum(flat.std(0), STD_FLOOR).astype(np.float32))

    def save(self, run_dir, name="norm"):
        np.savez(Path(run_dir) / f"{name}.npz", mean=self.mean, std=self.std)

    @classmethod
    def load(cls, run_dir, name="norm") -> "Norm":
        p = Path(run_dir) / f"{name}.npz"
        if not p.exists():
            raise DataError(f"missing {name}.npz (the run's statistics)", path=run_dir)
        with np.load(p) as z:
            return cls(z["mean"], z["std"])


def train_clips(path, fraction: float) -> np.ndarray:
    from handx_jax.dataset.format import Dataset

    clips = np.asarray(Dataset.open(path).split("train", fraction))
    if not len(clips):
        raise DataError("the train split is empty", path=path)
    return clips


def diffusion_loss(denoise_fn, sched, x0, rng):
    """x0-prediction MSE at a uniform timestep (§3.2: "trained to directly predict clean samples")."""
    k_t, k_n = jax.random.split(rng)
    B = x0.shape[0]
    t = jax.random.randint(k_t, (B,), 0, sched.T)
    ac = jnp.asarray(sched.alphas_cumprod, jnp.float32)[t][:, None, None]
    x_t = jnp.sqrt(ac) * x0 + jnp.sqrt(1 - ac) * jax.random.normal(k_n, x0.shape)
    return jnp.mean((denoise_fn(x_t, t) - x0) ** 2)
