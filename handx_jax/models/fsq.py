"""The FSQ motion tokenizer (paper §5.2; reference §4.1–4.4) on the 288-d AR representation (§2.4).

    h      = Enc(x)          Conv(288→W,k3) → ReLU → [Conv(W→W,k4,s2) → ResStack] → Conv(W→W,k3)
    y      = Linear(W → d)(h)                 d = number of FSQ dimensions (len(levels))
    ŷ      = quantize(y)     one integer digit per dimension, straight-through gradient
    x̂      = Dec(Linear(d → W)(code(ŷ)))      Conv → ReLU → [ResStack → ×2 nearest → Conv] → Conv → ReLU → Conv(W→288)
    ResStack = three pre-activation blocks, dilations 9, 3, 1 in BOTH encoder and decoder (§4.1):
               x + Conv1x1(ReLU(LN(Conv_k3,dil(ReLU(LN(x))))))

One temporal down-sampling (stride 2): 60 frames → 30 tokens (48-frame training windows → 24).

Quantisation, one config field ``quantizer``:
- ``paper`` (default, paper §5.2): digit = round(σ(y)·(L−1)) ∈ {0..L−1}; the code the decoder sees is
  digit/(L−1)·2 − 1 ∈ [−1, 1].
- ``fsq`` (the reference code, §4.2): b = tanh(y + atanh(o/half))·half − o with half = (L−1)(1+1e−3)/2 and
  o = 0.5 for even L; q = round(b); code = q/⌊L/2⌋; digit = q + ⌊L/2⌋.
Both round with a straight-through gradient. Index = Σ_k digit_k·Π_{e<k} L_e (first dim least
significant, §4.2), so every (quantizer, levels) pair has prod(levels) codes: the real codebook size,
e.g. 4375 for the nominal "4096" (7,5,5,5,5).
"""

from __future__ import annotations

from dataclasses import dataclass

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import skeleton as sk
from handx_jax.models.shape_cache import per_config
from handx_jax.representation import AR_DIM, AR_LAYOUT

# Nominal codebook size → FSQ levels (reference §4.2 table).
LEVELS: dict[int, tuple[int, ...]] = {
    256: (8, 6, 5), 512: (8, 8, 8), 1024: (8, 5, 5, 5), 2048: (8, 8, 6, 5), 4096: (7, 5, 5, 5, 5),
    16384: (8, 8, 8, 6, 5), 65536: (8, 8, 8, 5, 5, 5),
}
QUANTIZERS = ("paper", "fsq")


def levels_for(codebook: int) -> tuple[int, ...]:
    if codebook not in LEVELS:
        raise ValueError(f"no FSQ levels for codebook {codebook}; choose from {sorted(LEVELS)}")
    return LEVELS[codebook]


def real_codebook_size(codebook: int) -> int:
    """Number of distinct codes of the nominal size's levels (e.g. 4096 → 4375, 2048 → 1920)."""
    return int(np.prod(levels_for(codebook)))


@dataclass(frozen=True)
class FSQConfig:
    codebook: int = 512  # nominal size; the levels (and the real size) follow from it
    quantizer: str = "paper"
    width: int = 512
    depth: int = 3
    dilations: tuple[int, ...] = (9, 3, 1)  # reference: dilation growth 3, reversed, same order in both stacks
    down_t: int = 1  # stride-2 stages: temporal factor 2**down_t
    in_dim: int = AR_DIM

    @property
    def levels(self) -> tuple[int, ...]:
        return levels_for(self.codebook)

    @property
    def nb_code(self) -> int:
        return real_codebook_size(self.codebook)


# Named sizes: "paper" is the reference width 512; tiny/small are CPU presets.
PRESETS = {
    "tiny": FSQConfig(width=32),
    "small": FSQConfig(width=128),
    "paper": FSQConfig(width=512),
}


# ------------------------------------------------------------------------------------------------
# Quantisation


def _round_ste(x):
    """round(x) forward, identity backward (straight-through)."""
    return x + jax.lax.stop_gradient(jnp.round(x) - x)


def _level_consts(levels):
    L = jnp.asarray(levels, jnp.float32)
    half_width = jnp.floor(L / 2)
    return L, half_width


def bounded(y_xd, levels, quantizer: str = "paper"):
    """The continuous value that is rounded, per dimension, float32: σ(y)(L−1) (paper) or
    tanh(y + shift)·half − o (fsq, §4.2)."""
    y = y_xd.astype(jnp.float32)
    L, _ = _level_consts(levels)
    if quantizer == "paper":
        return jax.nn.sigmoid(y) * (L - 1)
    if quantizer == "fsq":
        half = (L - 1) * (1 + 1e-3) / 2
        o = jnp.where(L % 2 == 0, 0.5, 0.0)
        return jnp.tanh(y + jnp.arctanh(o / half)) * half - o
    raise ValueError(f"unknown quantizer {quantizer!r}; choose from {QUANTIZERS}")


def digits_to_code(digits_xd, levels, quantizer: str = "paper"):
    """Integer digits in {0..L−1} → the code vector the decoder sees (paper: [−1, 1]; fsq: q/⌊L/2⌋)."""
    L, hw = _level_consts(levels)
    d = jnp.asarray(digits_xd).astype(jnp.float32)
    if quantizer == "paper":
        return d / (L - 1) * 2 - 1
    return (d - hw) / hw


def _to_code(r, levels, quantizer):
    """Rounded value (still carrying the straight-through gradient) → code; the same affine map as
    digits_to_code, so the gradient is a per-dimension constant."""
    L, hw = _level_consts(levels)
    return r / (L - 1) * 2 - 1 if quantizer == "paper" else r / hw


def quantize(y_xd, levels, quantizer: str = "paper"):
    """(code, digits): code carries the straight-through gradient of the bounded value; digits are int32."""
    b = bounded(y_xd, levels, quantizer)
    r = _round_ste(b)
    _, hw = _level_consts(levels)
    digits = jax.lax.stop_gradient(r if quantizer == "paper" else r + hw).astype(jnp.int32)
    return _to_code(r, levels, quantizer), digits


def _bases(levels) -> np.ndarray:
    return np.concatenate([[1], np.cumprod(levels[:-1])]).astype(np.int64)


def digits_to_index(digits_xd, levels):
    """Index = Σ_k digit_k·Π_{e<k} L_e (first dimension least significant, §4.2)."""
    return (jnp.asarray(digits_xd) * jnp.asarray(_bases(levels), jnp.int32)).sum(-1).astype(jnp.int32)


def index_to_digits(index_x, levels):
    idx = jnp.asarray(index_x)[..., None]
    return ((idx // jnp.asarray(_bases(levels), jnp.int32)) % jnp.asarray(levels, jnp.int32)).astype(jnp.int32)


def index_to_code(index_x, levels, quantizer: str = "paper"):
    return digits_to_code(index_to_digits(index_x, levels), levels, quantizer)


def code_to_index(code_xd, levels, quantizer: str = "paper"):
    L, hw = _level_consts(levels)
    c = jnp.asarray(code_xd, jnp.float32)
    d = (c + 1) / 2 * (L - 1) if quantizer == "paper" else c * hw + hw
    return digits_to_index(jnp.round(d).astype(jnp.int32), levels)


# ------------------------------------------------------------------------------------------------
# Encoder / decoder


class ResBlock(nn.Module):
    width: int
    dilation: int

    @nn.compact
    def __call__(self, x_BxTxW):
        h = nn.relu(nn.LayerNorm(epsilon=1e-5, name="norm1")(x_BxTxW))  # LN over channels (reference "LN")
        h = nn.Conv(self.width, (3,), kernel_dilation=(self.dilation,), padding=((self.dilation, self.dilation),),
                    name="conv1")(h)
        h = nn.relu(nn.LayerNorm(epsilon=1e-5, name="norm2")(h))
        return x_BxTxW + nn.Conv(self.width, (1,), name="conv2")(h)


class ResStack(nn.Module):
    width: int
    dilations: tuple[int, ...]

    @nn.compact
    def __call__(self, x):
        for i, d in enumerate(self.dilations):
            x = ResBlock(self.width, d, name=f"block{i}")(x)
        return x


def _conv(width, k, name, stride=1, pad=1):
    return nn.Conv(width, (k,), strides=(stride,), padding=((pad, pad),), name=name)


class Encoder(nn.Module):
    cfg: FSQConfig

    @nn.compact
    def __call__(self, x_BxTxC):
        c = self.cfg
        h = nn.relu(_conv(c.width, 3, "conv_in")(x_BxTxC))
        for i in range(c.down_t):
            h = _conv(c.width, 4, f"down{i}", stride=2)(h)  # k4 s2 p1: T → T/2
            h = ResStack(c.width, c.dilations[: c.depth], name=f"res{i}")(h)
        return _conv(c.width, 3, "conv_out")(h)


class Decoder(nn.Module):
    cfg: FSQConfig

    @nn.compact
    def __call__(self, h_BxNxW):
        c = self.cfg
        h = nn.relu(_conv(c.width, 3, "conv_in")(h_BxNxW))
        for i in range(c.down_t):
            h = ResStack(c.width, c.dilations[: c.depth], name=f"res{i}")(h)
            h = jnp.repeat(h, 2, axis=1)  # nearest ×2 upsampling
            h = _conv(c.width, 3, f"up{i}")(h)
        h = nn.relu(_conv(c.width, 3, "conv_mid")(h))
        return _conv(c.in_dim, 3, "conv_out")(h)


class FSQTokenizer(nn.Module):
    """``__call__(x_BxTx288)`` → (x̂_BxTx288, digits_BxNxd); ``encode`` → indices (B, N); ``decode`` indices → x̂."""

    cfg: FSQConfig

    def setup(self):
        c = self.cfg
        self.encoder = Encoder(c)
        self.decoder = Decoder(c)
        self.proj_in = nn.Dense(len(c.levels))  # Linear(W → d) with bias (§4.2)
        self.proj_out = nn.Dense(c.width)  # Linear(d → W) with bias

    def __call__(self, x_BxTxC):
        code, digits = quantize(self.proj_in(self.encoder(x_BxTxC)), self.cfg.levels, self.cfg.quantizer)
        return self.decoder(self.proj_out(code)), digits

    def reconstruct(self, x_BxTxC):
        """(x̂, digits, y): ``__call__`` plus the pre-quantisation values y the ``latent`` loss term bounds."""
        y = self.proj_in(self.encoder(x_BxTxC))
        code, digits = quantize(y, self.cfg.levels, self.cfg.quantizer)
        return self.decoder(self.proj_out(code)), digits, y

    def encode(self, x_BxTxC):
        _, digits = quantize(self.proj_in(self.encoder(x_BxTxC)), self.cfg.levels, self.cfg.quantizer)
        return digits_to_index(digits, self.cfg.levels)

    def decode(self, index_BxN):
        code = index_to_code(index_BxN, self.cfg.levels, self.cfg.quantizer)
        return self.decoder(self.proj_out(code))


def init_tokenizer(cfg: FSQConfig, rng: jax.Array, frames: int = 60):
    model = FSQTokenizer(cfg)
    # jitted: one XLA program rather than one compile per initialiser op (same values, seconds less on CPU)
    return model, jax.jit(model.init)(rng, jnp.zeros((1, frames, cfg.in_dim)))


@per_config
def param_count(cfg: FSQConfig) -> int:
    """Trainable parameters, from shapes only; cached per config (frozen, hashable: tracing costs ~0.5 CPU-s)."""
    shapes = jax.eval_shape(lambda r: init_tokenizer(cfg, r)[1], jax.random.PRNGKey(0))
    return int(sum(int(np.prod(s.shape)) for s in jax.tree_util.tree_leaves(shapes)))


def forward_flops(cfg: FSQConfig, frames: int = 60) -> int:
    """Analytic forward FLOPs per clip (2 per multiply-add; convolutions and projections only)."""
    W, C, d, T = cfg.width, cfg.in_dim, len(cfg.levels), frames
    res = lambda t: cfg.depth * (t * 3 * W * W + t * W * W)  # noqa: E731  k3 conv + 1×1 conv per block
    macs = T * 3 * C * W  # encoder conv_in
    t = T
    for _ in range(cfg.down_t):
        t //= 2
        macs += t * 4 * W * W + res(t)
    macs += t * 3 * W * W + 2 * t * W * d  # encoder conv_out, proj_in, proj_out
    macs += t * 3 * W * W  # decoder conv_in
    for _ in range(cfg.down_t):
        macs += res(t)
        t *= 2
        macs += t * 3 * W * W
    macs += t * 3 * W * W + t * 3 * W * C  # conv_mid, conv_out
    return int(2 * macs)


# ------------------------------------------------------------------------------------------------
# Losses (reference §4.3) and validation metrics


def smooth_l1(a, b):
    """SmoothL1, β = 1, mean reduction."""
    d = jnp.abs(a - b)
    return jnp.mean(jnp.where(d < 1.0, 0.5 * d * d, d - 0.5))


def rot6d_to_matrix(d6_x6):
    """ROW-convention Gram–Schmidt, as the data (representation.rotation_6d_to_matrix, §2.4)."""
    a1, a2 = d6_x6[..., :3], d6_x6[..., 3:]
    n = lambda v: v / jnp.maximum(jnp.linalg.norm(v, axis=-1, keepdims=True), 1e-8)  # noqa: E731
    b1 = n(a1)
    b2 = n(a2 - jnp.sum(b1 * a2, -1, keepdims=True) * b1)
    return jnp.stack([b1, b2, jnp.cross(b1, b2)], axis=-2)


def geodesic(Ra, Rb):
    """Mean angle of Ra·Rbᵀ: arccos((tr − 1)/2), clamped to ±(1 − 1e−7) as the reference."""
    tr = jnp.einsum("...ij,...ij->...", Ra, Rb)
    return jnp.mean(jnp.arccos(jnp.clip((tr - 1) / 2, -1 + 1e-7, 1 - 1e-7)))


_BONES = np.asarray(sk.BONES, np.int64)  # (20, 2) parent, child


def bone_lengths(local_xTx120):
    """20 bone lengths per hand from the local positions of joints 1..20 (wrist at the origin)."""
    loc = local_xTx120.reshape(*local_xTx120.shape[:-1], 2, sk.NUM_JOINTS - 1, 3)
    loc = jnp.concatenate([jnp.zeros_like(loc[..., :1, :]), loc], axis=-2)
    return jnp.linalg.norm(loc[..., _BONES[:, 1], :] - loc[..., _BONES[:, 0], :], axis=-1)


# The reference's weights (§4.3): kept by name, ``loss=reference``, where a published number depends on them.
LOSS_WEIGHTS = {"all": 1.0, "pos": 0.5, "pos_acc": 0.15, "root": 0.03, "geo": 0.01, "geo_rel": 0.002,
                "rot6d": 0.01, "bones": 0.1, "left_vel": 0.03, "offset": 0.03}
# ``loss=hands`` (the default): the paper's intent, a tokenizer that reconstructs hands (§5.2: "MPJPE"
# is its yardstick). Under the reference's weights the 12 wrist-rotation features carry a few percent of
# the loss, so the bottleneck spends its bits on the fingers' 240 features: on the 1,200-clip prefix the
# fingers alone came back to 7.7 mm and the wrist orientation alone to 56.6 mm against a mean pose of
# 67.6 mm (issue 30). The added terms act on what MPJPE measures: ``joints``, the joints placed by the
# reconstructed wrist rotation (R_h·local_j, in cm, SmoothL1), so an orientation error costs what it
# moves the fingertips; ``glob``, the joints with the integrated root trajectory, relative to the
# clip's first right-wrist position (cm), so drift of the summed velocities costs what it moves;
# ``latent``, a penalty on pre-quantisation values beyond ±LATENT_BOUND, where the bound (σ or tanh)
# saturates and the straight-through gradient vanishes: without it, at the CPU recipe's lr, whole FSQ
# dimensions drifted out of range within 150 steps (y ≈ −10 on one dimension, 6 codes of 512 in use)
# and stayed dead. Inside the bound every digit is reachable (σ(3)·7 = 6.67 rounds to the top digit
# of L = 8), so the term is 0 for any working code.
LATENT_BOUND = 3.0
LOSS_PRESETS = {
    "reference": LOSS_WEIGHTS,
    "hands": {**LOSS_WEIGHTS, "joints": 1.0, "glob": 0.1, "latent": 1.0},
}


def tokenizer_loss(pred_n, gt_n, mean, std, weights: dict | str = "reference", latent=None):
    """The §4.3 terms on normalised (n) and de-normalised (u) 288-d frames ``(B, T, 288)``, weighted by
    ``weights`` (a dict, or a name of :data:`LOSS_PRESETS`); terms of weight 0 or absent are not computed.
    ``latent``: the pre-quantisation values ``(B, N, d)`` (``FSQTokenizer.reconstruct``), for that term.

    Not ported from the reference, on purpose:
    - its geodesic terms build matrices from 6D with a COLUMN convention, while the data store the first
      two ROWS (§2.4); here both terms use the data's row convention (``rot6d_to_matrix``);
    - its relative-rotation term pairs neighbours of the flattened (batch, frame, hand) list, i.e. left
      with right hand and across batch items (§9.17); here it is the rotation between consecutive frames
      of the same hand, R_tᵀ·R_{t+1}, compared between prediction and ground truth.
    """
    L = AR_LAYOUT
    un = lambda z: z * std + mean  # noqa: E731  (std already includes the AR eps)
    pu, gu = un(pred_n), un(gt_n)
    acc = lambda z: z[:, 2:] - 2 * z[:, 1:-1] + z[:, :-2]  # noqa: E731
    Rp = rot6d_to_matrix(pu[..., L.rot6d].reshape(*pu.shape[:-1], 2, 6))
    Rg = rot6d_to_matrix(gu[..., L.rot6d].reshape(*gu.shape[:-1], 2, 6))
    rel = lambda R: jnp.einsum("btkji,btkjl->btkil", R[:, :-1], R[:, 1:])  # noqa: E731  R_tᵀ R_{t+1}
    # Implied left-wrist velocity: offset(t+1) − offset(t) + v_R(t) (§2.4 inverse), frames 0..T−2.
    lvel = lambda u: u[:, 1:, L.lr_offset] - u[:, :-1, L.lr_offset] + u[:, :-1, L.root_vel]  # noqa: E731
    w = LOSS_PRESETS[weights] if isinstance(weights, str) else weights
    terms = {
        "all": smooth_l1(pred_n, gt_n),
        "pos": smooth_l1(pred_n[..., L.local_pos], gt_n[..., L.local_pos]),
        "pos_acc": smooth_l1(acc(pred_n[..., L.local_pos]), acc(gt_n[..., L.local_pos])),
        "root": smooth_l1(pred_n[..., 0:6], gt_n[..., 0:6]),
        "geo": geodesic(Rg, Rp),
        "geo_rel": geodesic(rel(Rg), rel(Rp)),
        "rot6d": smooth_l1(pred_n[..., L.rot6d], gt_n[..., L.rot6d]),
        "bones": smooth_l1(bone_lengths(pu[..., L.local_pos]), bone_lengths(gu[..., L.local_pos])),
        "left_vel": smooth_l1(lvel(pu), lvel(gu)),
        "offset": smooth_l1(pred_n[..., L.lr_offset], gt_n[..., L.lr_offset]),
    }
    if w.get("joints"):
        terms["joints"] = smooth_l1(100.0 * wrist_relative_joints(pu), 100.0 * wrist_relative_joints(gu))
    if w.get("glob"):
        terms["glob"] = smooth_l1(100.0 * global_joints(pu), 100.0 * global_joints(gu))
    if w.get("latent") and latent is not None:
        terms["latent"] = jnp.mean(jax.nn.relu(jnp.abs(latent.astype(jnp.float32)) - LATENT_BOUND) ** 2)
    total = sum(w.get(k, 0.0) * v for k, v in terms.items())
    return total, {f"l_{k}": v for k, v in terms.items()}


def wrist_relative_joints(f_xTx288):
    """Joints 0..20 of each hand relative to that hand's wrist, ``(..., T, 2, 21, 3)``, from
    de-normalised 288-d frames: R_h·local_j (§2.4 inverse, steps 1–2; the roots cancel)."""
    L = AR_LAYOUT
    lead = f_xTx288.shape[:-1]
    R = rot6d_to_matrix(f_xTx288[..., L.rot6d].reshape(*lead, 2, 6))
    loc = f_xTx288[..., L.local_pos].reshape(*lead, 2, sk.NUM_JOINTS - 1, 3)
    rel = jnp.einsum("...hij,...hkj->...hki", R, loc)
    return jnp.concatenate([jnp.zeros_like(rel[..., :1, :]), rel], axis=-2)


def global_joints(f_xTx288):
    """Joints ``(..., T, 2, 21, 3)`` with the root trajectory integrated (§2.4 inverse, steps 1–5): the
    right wrist at Σ_{s<t} vel(s) from the origin, the left at right + offset; as
    ``representation.ar_to_joints`` with root0 = 0, in float32 JAX."""
    L = AR_LAYOUT
    vel = f_xTx288[..., L.root_vel]
    root_r = jnp.cumsum(vel, axis=-2) - vel  # exclusive sum: root_R(0) = 0
    roots = jnp.stack([root_r + f_xTx288[..., L.lr_offset], root_r], axis=-2)[..., None, :]  # (..., T, 2, 1, 3)
    return roots + wrist_relative_joints(f_xTx288)


# Parts of the 288-d frame, for the error split: each is put back from the prediction into the ground
# truth alone, so its error is what that part alone costs (issue 30). Slots 18:48 (rotation scalars)
# and 168:288 (local velocities) place no joint.
PARTS = {"fingers": (AR_LAYOUT.local_pos,), "wrist_orient": (AR_LAYOUT.rot6d,),
         "root": (AR_LAYOUT.root_vel, AR_LAYOUT.lr_offset)}


def _put(gt_u, pred_u, slices):
    out = gt_u
    for sl in slices:
        out = out.at[..., sl].set(pred_u[..., sl])
    return out


def _per_clip_mm(a, b):
    return 1000.0 * jnp.linalg.norm(a - b, axis=-1).mean(axis=tuple(range(1, a.ndim - 1)))


def reconstruction_errors(pred_u, gt_u) -> dict:
    """Per-clip errors (mm, shape (B,)) of de-normalised 288-d clips ``(B, T, 288)``:

    - ``mpjpe``: wrist-relative, orientation included (R_h·local_j, the §4.3 validation MPJPE);
    - ``fingers`` / ``wrist_orient``: the same with only the local positions / only the wrist 6D
      taken from the prediction (everything else ground truth);
    - ``root``: global joints (:func:`global_joints`) with only the root velocity and left–right offset
      taken from the prediction (the wrist-relative error of that part is 0 by construction);
    - ``global``: global joints of the whole prediction, root trajectory integrated from the origin.
    """
    wr, gj = wrist_relative_joints, global_joints
    out = {"mpjpe": _per_clip_mm(wr(pred_u), wr(gt_u)), "global": _per_clip_mm(gj(pred_u), gj(gt_u))}
    for name, sl in PARTS.items():
        mixed = _put(gt_u, pred_u, sl)
        out[name] = _per_clip_mm(gj(mixed), gj(gt_u)) if name == "root" else _per_clip_mm(wr(mixed), wr(gt_u))
    return out


def mpjpe_mm(pred_u, gt_u):
    """Reference §4.3 validation MPJPE: per hand relative to its wrist, averaged over all 21 joints and
    both hands (the wrist row contributes 0, as in the reference's recovered joints), in millimetres."""
    d = jnp.linalg.norm(wrist_relative_joints(pred_u) - wrist_relative_joints(gt_u), axis=-1)
    return 1000.0 * jnp.mean(d)


def codebook_stats(indices, nb_code: int) -> dict:
    """Usage (fraction of the real codebook hit) and perplexity exp(H) of the code histogram."""
    counts = np.bincount(np.asarray(indices).reshape(-1), minlength=nb_code).astype(np.float64)
    p = counts / max(counts.sum(), 1.0)
    nz = p[p > 0]
    return {"usage": float((counts > 0).mean()), "perplexity": float(np.exp(-(nz * np.log(nz)).sum())),
            "codes_used": int((counts > 0).sum())}
