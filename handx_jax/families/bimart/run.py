"""A loaded BimArt run: contact maps, then motion with CFG and contact guidance in one jitted program, then refinement.

One concern: what a trained run does (``load`` → :class:`BimArtRun`); the family module re-exports it."""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.config import from_dict
from handx_jax.families import generation_config, run_config
from handx_jax.families.bimart import common as C
from handx_jax.families.bimart import contact as CM
from handx_jax.families.bimart import physics as PH
from handx_jax.families.bimart.config import FAMILY, MotionRunConfig
from handx_jax.families.diffusion.process import DiffusionConfig, sample
from handx_jax.infra.errors import DataError
from handx_jax.models import bimart as BM
from handx_jax.objects.features import mapped_points_world


@dataclass(frozen=True)
class GenerateOptions:
    contact: str = "generated"
    guidance: float = 1.0
    refine: bool = True
    seed: int = 0
    batch_size: int = 64


@functools.partial(jax.jit, static_argnames=("cm_cfg", "m_cfg", "contact", "schedule", "guide_at"))
def sample_motion(contact_params, params, cm_cfg, m_cfg, obj_BxFxO, gt_contact_BxFxC, V_BxFx2x2xKx3, t0_Bx3,
                  mean_X, std_X, key, cfg_scale, strength, *, contact: str, schedule: str, guide_at: str):
    """The whole sampling of §3.2-3.3 in one program: (X̂ raw (B, F, X), the contact maps used (B, F, 4K) m).

    ``contact``: "generated" (Ĉ sampled from the contact run), "ground_truth" (the oracle) or "none" (Z_c the null
    token in both CFG halves, no guidance). ``strength`` 0 traces the guidance but leaves x̂0 unchanged."""
    B, F, _ = obj_BxFxO.shape
    k_c, k_m = jax.random.split(key)
    if contact == "generated":
        c_m = CM.sample_fn(contact_params, cm_cfg, obj_BxFxO, k_c)
    else:
        c_m = C.unit_to_contact(gt_contact_BxFxC)
    c_u = C.contact_to_unit(c_m)
    target = c_m.reshape(B, F, 2, 2, -1)
    sched = C.schedule(m_cfg)
    guided = contact != "none"

    def steer(x0, t):
        return PH.contact_guide(x0, target, V_BxFx2x2xKx3, mean_X, std_X, t0_Bx3, m_cfg,
                                PH.guide_length(strength, schedule, sched.alphas_cumprod, t))

    def den(x, t_B, drop_B):
        # Both halves of classifier-free guidance in one batched call; with guide_at="before_cfg" the
        # conditional half is stepped before the two are combined (BimArt's code).
        xx, tt = jnp.concatenate([x, x]), jnp.concatenate([t_B, t_B])
        null = jnp.concatenate([jnp.full((B,), not guided), jnp.ones((B,), bool)])
        both = BM.denoise(params, m_cfg, xx, tt, jnp.concatenate([obj_BxFxO] * 2), jnp.concatenate([c_u] * 2), null)
        c, u = both[:B], both[B:]
        if guided and guide_at == "before_cfg":
            c = steer(c, t_B[0])
        return (1 + cfg_scale) * c - cfg_scale * u

    x = sample(den, sched, (B, F, BM.motion_dim(m_cfg)), k_m, DiffusionConfig(steps=m_cfg.steps), sampler="ddpm",
               guidance=1.0, steer=steer if guided and guide_at == "after_cfg" else None)
    return x * std_X + mean_X, c_m


@dataclass
class BimArtRun:
    run_dir: Path
    cfg: Any
    contact: CM.ContactRun
    params: Any
    norm: C.Norm
    step: int
    tasks: tuple = ("object2motion",)

    def generate_clips(self, data: C.Clips, opts: GenerateOptions, *, samples: int = 1) -> dict:
        """``samples`` motions per prepared clip → {"joints": (N, S, F, 2, 21, 3) world, "raw_joints" (before
        refinement), "contact": (N, S, F, 2, 2, K) m, the maps the motion was conditioned on}."""
        m, s = self.cfg.model, self.cfg.sample
        N, F = data.obj.shape[:2]
        rows = np.repeat(np.arange(N), samples)
        V = np.asarray(jax.vmap(mapped_points_world)(jnp.asarray(data.bps_points), jnp.asarray(data.states)))
        t0 = data.states[:, 0, 4:7]
        out_j, out_raw, out_c = [], [], []
        key = jax.random.PRNGKey(opts.seed)
        bs = opts.batch_size
        for b in range(0, len(rows), bs):
            r = rows[b:b + bs]
            pad = (bs - len(r)) if len(rows) > bs else 0  # one compiled shape for every batch
            rr = np.concatenate([r, np.full(pad, r[-1])])
            x, c = sample_motion(self.contact.params, self.params, self.contact.cfg.model, m,
                                 jnp.asarray(data.obj[rr]), jnp.asarray(data.contact[rr]), jnp.asarray(V[rr]),
                                 jnp.asarray(t0[rr]), jnp.asarray(self.norm.mean), jnp.asarray(self.norm.std),
                                 jax.random.fold_in(key, b), jnp.float32(s.cfg_scale), jnp.float32(opts.guidance),
                                 contact=opts.contact, schedule=s.schedule, guide_at=s.guide_at)
            H, D = PH.x_to_points((x - self.norm.mean) / self.norm.std, jnp.asarray(self.norm.mean),
                                  jnp.asarray(self.norm.std), jnp.asarray(t0[rr]), m)
            joints = H[..., :BM.JOINTS, :]
            raw = joints
            if opts.refine:
                from handx_jax.synthesis.object_motion import stack_objects

                objs = stack_objects([data.objects[i] for i in rr])
                joints = PH.refine_batch(joints, H, D, objs, jnp.asarray(data.states[rr]), m, s.refine_cfg)
            out_j.append(np.asarray(joints)[:len(r)])
            out_raw.append(np.asarray(raw)[:len(r)])
            out_c.append(np.asarray(c)[:len(r)])
        shape = (N, samples, F)
        return {"joints": np.concatenate(out_j).reshape(*shape, 2, 21, 3),
                "raw_joints": np.concatenate(out_raw).reshape(*shape, 2, 21, 3),
                "contact": np.concatenate(out_c).reshape(*shape, 2, 2, m.k)}

    def object_clips(self, data_dir, split: str = "test", limit: int | None = None, clip: str | None = None):
        """The corpus clips ``handx generate --task object2motion`` generates for: ``clip`` (an index or id), or
        the split's (the first ``limit``)."""
        from handx_jax.dataset.format import Dataset

        ds = Dataset.open(data_dir)
        if clip is not None:
            ids = list(ds.ids)
            if clip in ids:
                return np.asarray([ids.index(clip)])
            if not clip.isdigit() or int(clip) >= len(ids):
                raise DataError(f"--clip {clip!r}: neither a clip id nor an index below {len(ids)}", path=data_dir)
            return np.asarray([int(clip)])
        clips = np.asarray(ds.split(split))
        if not len(clips):
            raise DataError(f"the {split} split is empty", path=data_dir)
        return clips[:limit] if limit else clips

    def generate_objects(self, data_dir, clips, opts: GenerateOptions, *, samples: int = 1) -> dict:
        """The arrays of an object2motion file (evaluation/object_clips.py) for corpus ``clips``."""
        return self._object_file(C.prepare(data_dir, clips, self.cfg.model, motion=False), opts, samples)

    def generate_arctic(self, root, seq: str, opts: GenerateOptions, *, samples: int = 1, start: int | None = None,
                        limit: int | None = None) -> dict:
        """The arrays of an object2motion file for an ARCTIC sequence (``common.arctic_windows``: consecutive windows
        of the model's frames, or the one from ``start``), with the mesh the file needs to be scored without ARCTIC
        and, where the sequence has hands, its ground truth."""
        from handx_jax.interop.arctic import mesh_arrays

        # Refinement reads the mesh's signed distance frame by frame (physics._sdf): 0.85 GB for a 60-frame window
        # against 176 triangles (all frames at once it took 9.7 GB at 256); its time grows with the triangles
        # (CPU, shared cores: ~300 s a window at 176, against ~14 s on the primitive object): --no-refine skips it.
        data = C.arctic_windows(root, seq, self.cfg.model, start=start, limit=limit)
        if opts.contact == "ground_truth" and data.joints is None:
            raise DataError(f"--contact ground_truth needs the sequence's hands: {seq} has no processed joints "
                            f"(processed_seqs/{seq}.npy)", path=root)
        out = self._object_file(data, opts, samples)
        mesh = mesh_arrays(data.objects[0])      # every window is of the one sequence's object
        out.update(mesh_tri=mesh["tri"][None], mesh_part=mesh["part"][None], mesh_angle_range=mesh["angle_range"][None],
                   gt_joints=data.joints)
        for r in out["records"]:
            r["mesh"] = 0
        return out

    def _object_file(self, data: C.Clips, opts: GenerateOptions, samples: int) -> dict:
        out = self.generate_clips(data, opts, samples=samples)
        return {"joints": out["joints"], "object_state": data.states, "contact": out["contact"],
                "bps_points": data.bps_points, "records": data.records}

    def generate(self, prompts, opts, *, samples: int = 1, task: str = "object2motion", sources=None, **kw):
        raise ValueError(f"the bimart family does not generate {task!r} from text: it generates hands for an object "
                         f"and its trajectory (--task object2motion with --data CORPUS --clip N, or --arctic ROOT "
                         f"--seq sNN/NAME)")

    def generate_long(self, segments, opts, **kw):
        raise ValueError("the bimart family does not do --task long")

    def describe(self, opts: GenerateOptions) -> str:
        s = self.cfg.sample
        g = f"contact guidance s={opts.guidance:g} ({s.schedule}, {s.guide_at})" if opts.contact != "none" else \
            "no contact condition"
        return (f"contact {opts.contact}, {g}, CFG {s.cfg_scale:g}, {'refined' if opts.refine else 'unrefined'}, "
                f"step {self.step}")


def load(run_dir: str | os.PathLike, *, ema: bool = True, encoder=None, overrides: Sequence[str] = ()) -> BimArtRun:
    from handx_jax.train import load_params

    run_dir = Path(run_dir)
    doc = run_config(run_dir, FAMILY)
    cfg = generation_config(from_dict(MotionRunConfig, doc), overrides)
    contact = CM.load(doc["contact_run"]["path"], ema=ema)
    if contact.fingerprint != doc["contact_run"]["fingerprint"]:
        raise DataError(f"the contact run changed since this BimArt run was trained on it (fingerprint "
                        f"{contact.fingerprint}, recorded {doc['contact_run']['fingerprint']})",
                        path=doc["contact_run"]["path"])
    params, step = load_params(run_dir, ema=ema)
    return BimArtRun(run_dir, cfg, contact, params, C.Norm.load(run_dir), step)
