"""Sampling a trained diffusion run: text-to-motion and the masked tasks of paper App. D.

One mask builder (``process.task_centers`` + ``soft_mask``) and one compiled sampler
(``process.sample``, a single ``lax.scan``) serve every task. Constraints come from a source clip:
its normalised diffusion features are the target x0^gt and γ (F, 42) says where and how strongly
they are enforced (p_hard at the centre frames, a linear band of k_trans frames down to p_soft).
Outputs are de-normalised and placed at the source clip's centre (so constrained joints match the
source in absolute coordinates); without a source they stay clip-centred.

Long-horizon generation (App. D.2, Eq. Q) chains 60-frame segments: segment k+1 is constrained by
the last K_hor + k_trans frames of segment k placed at its frames 0..K_hor+k_trans−1 (centre frames
0..K_hor−1, the band after them). The chained motion keeps segment k up to that overlap and then all
of segment k+1, so each new segment adds 60 − K_hor − k_trans frames.

Motion prediction (G-HTT's task, issue 33; ``task="prediction"``, ``SampleOptions.observed_frames``):
the first N frames of the source, centred on their own mean, are kept (γ = 1, no band) and the rest is
generated; nothing after frame N of the source is read (``task_gamma``, ``generate``), and the output's
first N frames are the source's own. A run trained with ``diffusion.observe_prob`` > 0 reads them clean
at every step (``process.sample``), as it was trained to.

Contact guidance (``sample.contact``, issue 33 item 2; handx_jax/families/diffusion/guidance.py): a request (B, F, 43) of named
contacts per frame, from a written spec or the prompt record's contact events, and its strength are
traced inputs of the same compiled sampler (a new request or strength does not recompile); every step
moves x̂0 down the contact energy's gradient (``guidance.make_steer``). Without a request the sampler is
compiled exactly as before.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.families.diffusion import guidance as G
from handx_jax import metrics as M
from handx_jax import representation as rep
from handx_jax.families.diffusion import process as D
from handx_jax.generation import Prompt
from handx_jax.infra.xla_options import jit_inference

if TYPE_CHECKING:
    from handx_jax.families.diffusion import DiffusionRun

K_INBET = 5  # paper App. D.2 (the code uses 10, reference §9.9)
K_HOR = 5


@dataclass(frozen=True)
class SampleOptions:
    sampler: str = "ddpm"  # "ddpm" (ancestral, all T steps, the reference) or "ddim"
    steps: int = 50  # DDIM steps
    guidance: float | None = None  # None: the run's diffusion.guidance (2.5)
    seed: int = 0
    batch_size: int = 256  # samples per compiled call
    # Contact guidance (guidance.py): "" off, "caption" (the prompt record's contact events) or a written
    # spec ("L.thumb-R.index@20:40,..."); strength s (1 = BimArt's unit step) and schedule w(t).
    contact: str = ""
    contact_strength: float = 16.0
    contact_schedule: str = "late"
    observed_frames: int = 20  # for the prediction task

    def __post_init__(self) -> None:
        f = self.observed_frames  # the clip length bounds it too, checked against the model in ``generate``
        if not (isinstance(f, int) and 0 < f < 60):
            raise ValueError(f"--observed-frames must be in (0, 60), got {f}")

    @property
    def needs_records(self) -> bool:
        """Whether prompts must carry their structured record (``Prompt.record``): ``contact=caption``."""
        return self.contact.strip() == G.CAPTION


# ------------------------------------------------------------------------------------------------
# Masks


def task_gamma(task: str, dcfg: D.DiffusionConfig, frames: int = 60, *, keyframes: Sequence[int] = (30,),
               fixed_hand: str = "left", observed: int = 20) -> np.ndarray:
    """γ (F, 42) for a task (App. D.2), with the run's p_hard/p_soft/k_trans.

    ``prediction`` is the exception: γ = 1 on the ``observed`` frames and 0 after them, no band. The
    observation is given, so the output keeps it exactly (γ < 1 would let the model move frames it was
    shown), and a band after it would pull the first predicted frames toward a target that holds no
    values there (the hidden future is never passed in)."""
    c = D.task_centers(task, frames, 42, k_inbet=K_INBET, keyframes=tuple(keyframes), fixed_hand=fixed_hand,
                       k_hor=K_HOR, observed=observed)
    if task == "prediction":
        return c.astype(np.float32)
    return D.soft_mask(c, dcfg.p_hard, dcfg.p_soft, dcfg.k_trans)


# ------------------------------------------------------------------------------------------------
# Sampling


def _sample_impl(params, text_KxBxLxD, mask_KxBxL, rng, target, gamma, request_BxFxC=None, strength=None, *, model,
                 sched, dcfg, sampler, steps, guidance, mesh=None, norm=None, schedule="late"):
    """The whole sampler as one traced function. ``mesh`` (``hostdevices.inference_mesh``): split every
    denoiser call's samples over its devices (the noise, the text encoding and the update stay global:
    the same numbers on one device or several). ``request_BxFxC`` and ``strength`` (traced): contact
    guidance on x̂0 with the run's normalisation ``norm`` and the strength ``schedule`` (guidance.py)."""
    B = text_KxBxLxD.shape[1]
    # The text memory is the same at every step: project it and compute each layer's cross-attention
    # keys/values once, outside the scan (issue 15).
    memory = model.apply(params, text_KxBxLxD, mask_KxBxL, method=model.encode)

    def denoise_rows(params, x, t_B, memory, b):
        # ``diffusion.guided`` stacks [conditional; unconditional] on the batch axis, so the rows past the
        # first ``b`` are the null-text pass: one memory token, no text keys/values. Their x and t repeat
        # the first b rows', so the work before the first cross-attention is shared.
        null_rows = x.shape[0] - b
        return model.apply(params, x, t_B, memory, null_rows, null_rows == b, method=model.denoise)

    def denoise(x, t_B, uncond_B):
        del uncond_B  # the layout says it: rows past B are unconditional
        if mesh is None:
            return denoise_rows(params, x, t_B, memory, B)
        return _split_over(mesh, denoise_rows, params, x, t_B, memory, B)

    steer = None
    if request_BxFxC is not None:
        steer = G.make_steer(request_BxFxC, strength, schedule, sched.alphas_cumprod, norm.mean, norm.std + norm.eps)
    shape = (B, model.cfg.frames, model.cfg.joints, model.cfg.channels)
    return D.sample(denoise, sched, shape, rng, dcfg, sampler=sampler, steps=steps, guidance=guidance,
                    target=target, gamma_FxJ=gamma, steer=steer)


def _split_over(mesh, denoise_rows, params, x_GBxFxJxC, t_GB, memory, B):
    """``denoise_rows`` with the B samples split over ``mesh`` (hostdevices): each device gets its slice
    of every group (the conditional rows and, under guidance, the repeated null rows) and of the text
    memory, whose rows are branch-major (K·B), so the layout each device sees is the unsplit one's."""
    from jax.sharding import PartitionSpec as P

    G = x_GBxFxJxC.shape[0] // B
    x = x_GBxFxJxC.reshape(G, B, *x_GBxFxJxC.shape[1:])
    t = t_GB.reshape(G, B)
    by_sample = lambda a: a.reshape(-1, B, *a.shape[1:])  # noqa: E731  (K·B, ...) -> (K, B, ...)
    mem = jax.tree_util.tree_map(by_sample, memory)
    split = P(None, "b")

    def body(params, x, t, mem):
        b = x.shape[1]
        flat = lambda a: a.reshape(-1, *a.shape[2:])  # noqa: E731
        y = denoise_rows(params, flat(x), flat(t), jax.tree_util.tree_map(flat, mem), b)
        return y.reshape(G, b, *y.shape[1:])

    y = jax.shard_map(body, mesh=mesh, in_specs=(P(), split, split, split), out_specs=split)(params, x, t, mem)
    return y.reshape(G * B, *y.shape[2:])


def compile_sampler(model, dcfg: D.DiffusionConfig, *, sampler: str, steps: int, guidance: float, batch: int,
                    norm=None, contact_schedule: str = "late"):
    """The compiled sampler for batches of ``batch`` samples: ``fn(params, text_KxBxLxD, mask_KxBxL, rng,
    target, gamma[, request_BxFxC, strength]) -> x0 (B, F, J, C)``, with the inference XLA options
    (``xla_options``) and, where the host has several CPU devices, the batch split over them
    (``hostdevices``). A request (contact guidance) needs the run's ``norm``; called without one, the
    program is the unguided sampler's."""
    from handx_jax.infra import hostdevices

    mesh = hostdevices.inference_mesh(batch)
    fn = jit_inference(partial(_sample_impl, model=model, sched=D.cosine_schedule(dcfg.steps), dcfg=dcfg,
                               sampler=sampler, steps=steps, guidance=guidance, mesh=mesh, norm=norm,
                               schedule=contact_schedule), model.cfg.dim)
    if mesh is None:
        return fn

    def placed(params, *args):
        return fn(*hostdevices.replicate(mesh, (params, *args)))

    placed.mesh = mesh
    return placed


# The compiled samplers of this process, shared by every run loaded in it (``_compiled``); a few entries bound
# the executables a long session keeps alive.
_SAMPLERS: "collections.OrderedDict[tuple, Any]" = collections.OrderedDict()
_SAMPLERS_MAX = 8


def _compiled(run: DiffusionRun, opts: SampleOptions, masked: bool, batch: int):
    """The jitted sampler for ``run``, kept per process under everything its program depends on: the model's
    class, config and dtype, the diffusion config, sampler, steps, guidance, batch, contact schedule and the
    run's normalisation (a constant of the guided program); params, text and noise are arguments. A process
    that loads a run of the same configuration again (each ``handx generate`` of a session, a notebook, a
    sweep's evaluate stage) then calls the same jitted function, without tracing and lowering it again
    (~0.5 CPU-s a call for the tiny preset, more for larger models) or reading it from the compilation cache."""
    g = run.cfg.diffusion.guidance if opts.guidance is None else float(opts.guidance)
    norm = run.norm
    key = (type(run.model), run.model.cfg, str(run.model.dtype), opts.sampler,
           opts.steps if opts.sampler == "ddim" else None, g, masked, run.cfg.diffusion, batch, opts.contact_schedule,
           None if norm is None else (norm.mean.tobytes(), norm.std.tobytes(), norm.eps))
    if key not in _SAMPLERS:
        _SAMPLERS[key] = compile_sampler(run.model, run.cfg.diffusion, sampler=opts.sampler, steps=opts.steps,
                                         guidance=g, batch=batch, norm=norm, contact_schedule=opts.contact_schedule)
        while len(_SAMPLERS) > _SAMPLERS_MAX:
            _SAMPLERS.popitem(last=False)
    _SAMPLERS.move_to_end(key)
    return _SAMPLERS[key]


def sample_normalised(run: DiffusionRun, prompts: Sequence[Prompt], opts: SampleOptions, *,
                      targets_BxFx42x4: np.ndarray | None = None, gamma_FxJ: np.ndarray | None = None,
                      rng: jax.Array | None = None, request_BxFxC: np.ndarray | None = None) -> np.ndarray:
    """One sample per prompt, (B, F, 42, 4) in normalised space, in chunks of ``opts.batch_size``.
    ``request_BxFxC``: contact guidance (one request per prompt, guidance.py) at ``opts.contact_strength``."""
    rng = jax.random.PRNGKey(opts.seed) if rng is None else rng
    masked = targets_BxFx42x4 is not None
    out = []
    n = len(prompts)
    bs = min(opts.batch_size, n)
    fn = _compiled(run, opts, masked, bs)
    for ci, s in enumerate(range(0, n, bs)):
        chunk = list(prompts[s:s + bs])
        real = len(chunk)
        chunk += [chunk[-1]] * (bs - real)  # pad the last chunk: one compiled shape
        h, m = run.encode([t for p in chunk for t in p.texts()])
        h = h.reshape(bs, 3, *h.shape[1:]).swapaxes(0, 1)
        m = m.reshape(bs, 3, -1).swapaxes(0, 1)
        tgt = gam = None
        if masked:
            tgt = np.asarray(targets_BxFx42x4[s:s + bs], np.float32)
            tgt = np.concatenate([tgt, np.repeat(tgt[-1:], bs - real, 0)])
            gam = np.asarray(gamma_FxJ, np.float32)
        guide = ()
        if request_BxFxC is not None:
            req = np.asarray(request_BxFxC[s:s + bs], np.float32)
            req = np.concatenate([req, np.repeat(req[-1:], bs - real, 0)])
            guide = (jnp.asarray(req), jnp.float32(opts.contact_strength))
        x = fn(run.params, jnp.asarray(h), jnp.asarray(m), jax.random.fold_in(rng, ci), tgt, gam, *guide)
        out.append(np.asarray(x)[:real])
    return np.concatenate(out)


def contact_request(prompts: Sequence[Prompt], contact: str, frames: int) -> np.ndarray | None:
    """(B, F, 43) request per prompt of ``sample.contact`` (guidance.py): None when off; ``caption``: the
    contact events of each prompt's record (``Prompt.record``); else a written spec, the same for all."""
    contact = contact.strip()
    if not contact:
        return None
    if contact != G.CAPTION:
        return G.request_from_spec(contact, len(prompts), frames)
    if any(p.record is None for p in prompts):
        raise ValueError("contact guidance from the caption needs each prompt's structured record: take the prompts "
                         "from a dataset with events.jsonl (--data DIR, or --source DIR --clip ID); typed "
                         "prompts and .npz sources carry none")
    named = M.named_contacts([p.record for p in prompts])
    G.check_named(named, len(prompts))
    return G.request_from_named(named, len(prompts), frames)


def to_joints(run: DiffusionRun, x_BxFx42x4: np.ndarray, centers_Bx3: np.ndarray | None = None) -> np.ndarray:
    """De-normalise and convert to joints (B, F, 2, 21, 3)."""
    return rep.diffusion_to_joints(run.norm.denormalize(np.asarray(x_BxFx42x4, np.float32)), centers_Bx3)


def generate(run: DiffusionRun, prompts: Sequence[Prompt], opts: SampleOptions, *, samples: int = 1,
             task: str = "text2motion", sources: Sequence[np.ndarray] | None = None,
             keyframes: Sequence[int] = (30,), fixed_hand: str = "left") -> np.ndarray:
    """G samples per prompt: joints (P, G, F, 2, 21, 3). ``sources`` (one joints array per prompt) give
    the task's constraint clips and the output placement."""
    if task == "long":
        raise ValueError("use generate_long for long-horizon generation")
    if task not in D.TASKS:
        raise ValueError(f"unknown task {task!r}; choose from {D.TASKS}")
    if task != "text2motion" and sources is None:
        raise ValueError(f"task {task!r} needs a source clip")
    P, G = len(prompts), samples
    flat = [p for p in prompts for _ in range(G)]
    centers = targets = gamma = None
    if sources is not None:
        if len(sources) != P:
            raise ValueError(f"{len(sources)} sources for {P} prompts")
        src = np.stack([np.asarray(s, np.float64) for s in sources])
        centers = np.repeat(rep.diffusion_center(src), G, 0)
        if task == "prediction":
            n, F = opts.observed_frames, run.cfg.model.frames
            if not 0 < n < min(F, src.shape[1]):
                raise ValueError(f"--observed-frames must be in (0, {min(F, src.shape[1])}), got {n}")
            # Only the observed frames are read: they are centred on their own mean wrist midpoint (as a
            # continued segment is in generate_long), since the whole clip's centre would tell the model
            # where the hidden future goes; the output is placed back at that centre.
            obs = src[:, :n]
            centers = np.repeat(rep.diffusion_center(obs), G, 0)
            tgt = np.zeros((P, F, 42, 4), np.float32)
            tgt[:, :n] = run.norm.normalize(rep.to_diffusion(obs).astype(np.float32))
            targets = np.repeat(tgt, G, 0)  # frames >= n: γ = 0 there, so their value never enters
            gamma = task_gamma(task, run.cfg.diffusion, F, observed=n)
        elif task != "text2motion":
            x_src = run.norm.normalize(rep.to_diffusion(src).astype(np.float32))
            targets = np.repeat(x_src, G, 0)
            gamma = task_gamma(task, run.cfg.diffusion, src.shape[1], keyframes=keyframes, fixed_hand=fixed_hand)
    x = sample_normalised(run, flat, opts, targets_BxFx42x4=targets, gamma_FxJ=gamma,
                          request_BxFxC=contact_request(flat, opts.contact, run.cfg.model.frames))
    j = to_joints(run, x, centers)
    j = j.reshape(P, G, *j.shape[1:])
    if task == "prediction":  # the observation is given: returned as read, not through the normalisation
        j[:, :, :opts.observed_frames] = src[:, None, :opts.observed_frames]
    return j


def generate_long(run: DiffusionRun, segments: Sequence[Prompt], opts: SampleOptions, *, samples: int = 1,
                  source: np.ndarray | None = None) -> np.ndarray:
    """Chain one 60-frame segment per prompt (App. D.2, Eq. Q): joints (G, T, 2, 21, 3) with
    T = 60 + (S − 1)(60 − K_hor − k_trans), or S·(60 − K_hor − k_trans) more frames after ``source``
    when a source clip is continued (the source itself is not part of the output)."""
    if opts.contact.strip():
        raise ValueError("contact guidance is for one 60-frame clip per prompt, not --task long")
    dcfg = run.cfg.diffusion
    overlap = K_HOR + dcfg.k_trans
    F = run.cfg.model.frames
    gamma = task_gamma("long", dcfg, F)
    G = samples
    rng = jax.random.PRNGKey(opts.seed)
    prev = None  # (G, F, 42, 4) de-normalised diffusion features of the previous segment, absolute xyz
    pieces = []
    if source is not None:
        src = np.asarray(source, np.float64)
        x = rep.to_diffusion(src).astype(np.float32)
        x[..., :3] += rep.diffusion_center(src).astype(np.float32)
        prev = np.repeat(x[None], G, 0)
    for k, prompt in enumerate(segments):
        targets = offset = None
        if prev is not None:
            tail = prev[:, -overlap:]  # (G, overlap, 42, 4)
            # Re-centre on the constrained frames' mean wrist midpoint (a centred clip's frame).
            offset = 0.5 * (tail[:, :, 0, :3] + tail[:, :, 21, :3]).mean(1)  # (G, 3)
            tgt = np.zeros((G, F, 42, 4), np.float32)
            tgt[:, :overlap] = tail
            tgt[:, :overlap, :, :3] -= offset[:, None, None]
            targets = run.norm.normalize(tgt)
            targets[:, overlap:] = 0.0  # unconstrained (γ = 0) frames: the value is irrelevant
        x = sample_normalised(run, [prompt] * G, opts, targets_BxFx42x4=targets,
                              gamma_FxJ=gamma if targets is not None else None, rng=jax.random.fold_in(rng, k))
        seg = run.norm.denormalize(x)
        if offset is not None:
            seg[..., :3] += offset[:, None, None]
        if prev is None:
            pieces.append(seg)
        elif k == 0:  # continuing a source: only the new frames are output
            pieces.append(seg[:, overlap:])
        else:
            pieces[-1] = pieces[-1][:, :-overlap]
            pieces.append(seg)
        prev = seg
    x = np.concatenate(pieces, axis=1)
    return rep.diffusion_to_joints(x)
