"""Contrastive text–motion evaluator (TMR/TEMOS-style; paper E.2, reference §5.1–§5.3).

Motion side: Linear(126 → D) over per-frame right-wrist-centred joint positions, learnable μ and
logvar tokens, sinusoidal PE, a post-LN transformer encoder; the embedding is μ (D = 256).
Text side: the frozen T5 encoder's last hidden states of the joined caption
``<extra_id_0> L <extra_id_1> R <extra_id_2> I <extra_id_3>`` → ReLU → Linear(T5 → D), μ/logvar
tokens, PE and the same encoder design, masked by the T5 attention mask.

Motion input (``motion_input``, ``motion_patch``). The paper preset is the reference: the 126
right-wrist-centred values per frame, one token per frame. The CPU presets' evaluator would need far
more samples than a CPU gives to learn flexion and tip contact from camera-frame positions, where the
hand's orientation mixes into every joint. So "small" reads ``hand_frames`` (the same 126 plus
quantities computed from them: joints in each hand's wrist frame, the frames, thumb-tip and inter-hand
tip distances; no information the 126 lack) in tokens of 2 frames, without dropout (the 20k corpus is
far from being overfit). Measured on corpus20k, 600 steps × 128, lr 1e-3, same seed: GT R-Precision@32
top-1 0.355 (positions), 0.548 (hand_frames), 0.564 (hand_frames, 2-frame tokens, 20% less time).

Why a frozen T5 with trainable layers on top (rather than fine-tuning T5): the evaluator is the
yardstick of every sweep run, so it must be cheap to run after each run and must not drift; a frozen
encoder lets every caption be encoded once into the text cache, makes evaluation a pass of two
small transformers over cached features (seconds for thousands of clips), and is what the reference
does (§5.1). The trainable text transformer is enough to adapt frozen features to the motion space.

Training loss (reference §5.2): SmoothL1 reconstruction of the motion from the text latent and from
the motion latent (weight 1 each), symmetric KL between the two posteriors (0.05 each), SmoothL1
between the two sampled latents (0.05), and symmetric InfoNCE on the μ's with cosine logits / τ,
τ = 0.05 (weight 0.6).
"""

from __future__ import annotations

from dataclasses import dataclass

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from handx_jax.models.layers import DecoderLayer, EncoderLayer, attention_mask, sinusoidal_table


@dataclass(frozen=True)
class EvaluatorConfig:
    latent: int = 256
    layers: int = 4
    heads: int = 4  # the reference's num_head: 6 never reaches the constructor (§5.1)
    ff: int = 1024
    dropout: float = 0.1
    # "positions": the reference's 126 right-wrist-centred values per frame (§5.3). "hand_frames":
    # those 126 plus features computed from them (representation.to_evaluator_hand_frames): joints in
    # each hand's wrist frame, the frames, tip distances; same information, far fewer samples to learn.
    motion_input: str = "positions"
    # Frames per motion token (1 = the reference's one token per frame). p > 1 concatenates p consecutive
    # frames into one token: p× fewer tokens (the encoder's cost falls ~p×), and the input layer sees
    # each token's velocity directly (the difference of its frames), which repetition counts need.
    motion_patch: int = 1
    text_dim: int = 768
    frames: int = 60
    temperature: float = 0.05
    w_infonce: float = 0.6
    w_recon: float = 1.0
    w_kl: float = 0.05
    w_latent: float = 0.05
    recon: bool = True  # the TEMOS decoder (training only); off = contrastive + KL + latent terms
    # Issue 40 (the v5 recipe; both off reproduce v4). ``mask_same_text``: a pair whose captions are
    # identical is no negative of the other (TMR's filtering: in a corpus where many clips share a
    # caption, treating them as negatives punishes the right answer). ``reverse_negative``: each text
    # also sees its own clip played backwards as a negative, with this weight on the logit's presence
    # (0 = off): the order of events is part of what a caption says, and nothing else in a batch asks
    # the motion encoder to read it.
    mask_same_text: bool = False
    reverse_negative: bool = False
    # Issue 55 (the v8 recipe; empty reproduces v7): edits of *which* hand or finger does what
    # (``validity.perturb``'s meaning-changing kinds, e.g. "swap_hands", "swap_fingers"), each applied to
    # every training clip and taken as one more negative of the clip's own caption, as its reversal is.
    # A clip of a corpus is also a valid clip once its hands are swapped, but it says another thing: what
    # no random negative of a batch asks the motion encoder to tell apart.
    hard_negatives: tuple[str, ...] = ()

    def __post_init__(self):
        from handx_jax.representation import EVALUATOR_INPUTS

        if self.motion_input not in EVALUATOR_INPUTS:
            raise ValueError(f"unknown evaluator motion_input {self.motion_input!r}; "
                             f"choose from {sorted(EVALUATOR_INPUTS)}")
        if self.motion_patch < 1 or self.frames % self.motion_patch:
            raise ValueError(f"motion_patch {self.motion_patch} must be ≥ 1 and divide frames ({self.frames})")
        # a JSON list (evaluator.json) or a tuple: one form, so configs compare and hash alike
        object.__setattr__(self, "hard_negatives", tuple(str(k) for k in self.hard_negatives))

    @property
    def motion_dim(self) -> int:
        """Features per frame of the motion input (126 for "positions")."""
        from handx_jax.representation import EVALUATOR_INPUTS

        return EVALUATOR_INPUTS[self.motion_input][1]


PRESETS = {
    "paper": EvaluatorConfig(),
    # CPU-sized: same design, narrower and shallower, no reconstruction decoder.
    "small": EvaluatorConfig(latent=128, layers=2, heads=4, ff=256, recon=False, dropout=0.0,
                             motion_input="hand_frames", motion_patch=2),
    "tiny": EvaluatorConfig(latent=32, layers=1, heads=2, ff=64, recon=False),
}


class DistEncoder(nn.Module):
    """[μ-token, logvar-token, x_1..x_L] + PE → transformer encoder → (μ, logvar)."""

    cfg: EvaluatorConfig
    max_len: int = 1024

    @nn.compact
    def __call__(self, h_BxLxD, valid_BxL, *, deterministic: bool):
        c = self.cfg
        B = h_BxLxD.shape[0]
        tok = self.param("dist_tokens", nn.initializers.normal(1.0), (2, c.latent))
        x = jnp.concatenate([jnp.broadcast_to(tok, (B, 2, c.latent)), h_BxLxD], axis=1)
        x = x + jnp.asarray(sinusoidal_table(self.max_len, c.latent))[: x.shape[1]]
        x = nn.Dropout(c.dropout)(x, deterministic=deterministic)
        valid = jnp.concatenate([jnp.ones((B, 2), bool), valid_BxL], axis=1)
        mask = attention_mask(valid, valid)
        for i in range(c.layers):
            x = EncoderLayer(c.latent, c.heads, c.ff, c.dropout, name=f"layer{i}")(x, mask, deterministic=deterministic)
        return x[:, 0], x[:, 1]


class MotionDecoder(nn.Module):
    cfg: EvaluatorConfig

    @nn.compact
    def __call__(self, z_BxD, *, deterministic: bool):
        c = self.cfg
        B = z_BxD.shape[0]
        q = jnp.broadcast_to(jnp.asarray(sinusoidal_table(c.frames, c.latent)), (B, c.frames, c.latent))
        mem = z_BxD[:, None]
        for i in range(c.layers):
            q = DecoderLayer(c.latent, c.heads, c.ff, c.dropout, name=f"layer{i}")(q, mem, deterministic=deterministic)
        return nn.Dense(c.motion_dim, name="out")(q)


class Evaluator(nn.Module):
    cfg: EvaluatorConfig

    def setup(self):
        c = self.cfg
        self.motion_in = nn.Dense(c.latent, name="motion_in")
        self.text_in = nn.Dense(c.latent, name="text_in")
        self.motion_enc = DistEncoder(c, name="motion_enc")
        self.text_enc = DistEncoder(c, name="text_enc")
        if c.recon:
            self.decoder = MotionDecoder(c, name="decoder")

    def encode_motion(self, motion_BxTxF, *, deterministic: bool = True):
        B, T, F = motion_BxTxF.shape
        p = self.cfg.motion_patch
        if T % p:
            raise ValueError(f"motion has {T} frames, not a multiple of motion_patch {p}")
        tokens_BxNxPF = motion_BxTxF.reshape(B, T // p, p * F)
        return self.motion_enc(self.motion_in(tokens_BxNxPF), jnp.ones((B, T // p), bool),
                               deterministic=deterministic)

    def encode_text(self, text_BxLxDt, text_mask_BxL, *, deterministic: bool = True):
        return self.text_enc(self.text_in(nn.relu(text_BxLxDt)), text_mask_BxL.astype(bool), deterministic=deterministic)

    def decode(self, z_BxD, *, deterministic: bool = True):
        return self.decoder(z_BxD, deterministic=deterministic)

    def __call__(self, motion, text, text_mask, *, deterministic: bool = True):
        mu_m, lv_m = self.encode_motion(motion, deterministic=deterministic)
        mu_t, lv_t = self.encode_text(text, text_mask, deterministic=deterministic)
        out = {"mu_m": mu_m, "lv_m": lv_m, "mu_t": mu_t, "lv_t": lv_t}
        if self.cfg.recon:
            out["dec_m"] = self.decode(mu_m, deterministic=deterministic)
            out["dec_t"] = self.decode(mu_t, deterministic=deterministic)
        return out


def _kl(mu_p, lv_p, mu_q, lv_q):
    """KL(N(mu_p, e^lv_p) ‖ N(mu_q, e^lv_q)), mean over batch and dims."""
    return jnp.mean(0.5 * (lv_q - lv_p + (jnp.exp(lv_p) + (mu_p - mu_q) ** 2) / jnp.exp(lv_q) - 1.0))


def _unit(x):
    return x / (jnp.linalg.norm(x, axis=-1, keepdims=True) + 1e-8)


def infonce(mu_m, mu_t, temperature: float, *, same_text_BxB=None, mu_m_rev=None, rev_same_B=None,
            mu_m_hard_BxKxD=None, hard_same_BxK=None):
    """Symmetric InfoNCE on L2-normalised embeddings with cosine logits / τ (reference §5.2).

    ``same_text_BxB``: pairs (i, j ≠ i) with identical captions are dropped from each other's negatives.
    ``mu_m_rev``: each clip played backwards, one extra negative column for its own text (text → motion);
    ``rev_same_B``: items whose reversal reads the same as the clip (no negative of its text: left out).
    ``mu_m_hard_BxKxD``: K edits of each clip (``hard_negatives``), K more negative columns for its own text;
    ``hard_same_BxK``: the edits that read the same as the clip (left out, as ``rev_same_B``)."""
    m, t = _unit(mu_m), _unit(mu_t)
    logits = m @ t.T / temperature
    B = m.shape[0]
    labels = jnp.arange(B)
    if same_text_BxB is not None:
        logits = jnp.where(same_text_BxB & ~jnp.eye(B, dtype=bool), -1e9, logits)
    t2m = logits.T
    if mu_m_rev is not None:
        rev = jnp.sum(t * _unit(mu_m_rev), axis=-1) / temperature
        if rev_same_B is not None:
            rev = jnp.where(rev_same_B, -1e9, rev)
        t2m = jnp.concatenate([t2m, rev[:, None]], axis=1)
    if mu_m_hard_BxKxD is not None:
        hard = jnp.einsum("bd,bkd->bk", t, _unit(mu_m_hard_BxKxD)) / temperature
        if hard_same_BxK is not None:
            hard = jnp.where(hard_same_BxK, -1e9, hard)
        t2m = jnp.concatenate([t2m, hard], axis=1)
    return 0.5 * (optax.softmax_cross_entropy_with_integer_labels(logits, labels).mean()
                  + optax.softmax_cross_entropy_with_integer_labels(t2m, labels).mean())


def evaluator_loss(model: Evaluator, params, batch, rng, train: bool):
    c = model.cfg
    r_drop, r_m, r_t = jax.random.split(rng, 3)
    mu_m, lv_m = model.apply(params, batch["motion"], deterministic=not train, method=Evaluator.encode_motion,
                             rngs={"dropout": r_drop})
    mu_t, lv_t = model.apply(params, batch["text"], batch["text_mask"], deterministic=not train,
                             method=Evaluator.encode_text, rngs={"dropout": jax.random.fold_in(r_drop, 1)})
    lv_m, lv_t = jnp.clip(lv_m, -10, 10), jnp.clip(lv_t, -10, 10)
    z_m = mu_m + jnp.exp(0.5 * lv_m) * jax.random.normal(r_m, mu_m.shape)
    z_t = mu_t + jnp.exp(0.5 * lv_t) * jax.random.normal(r_t, mu_t.shape)
    same = None
    if c.mask_same_text and "text_id" in batch:
        same = batch["text_id"][:, None] == batch["text_id"][None, :]
    mu_rev = None
    if c.reverse_negative and "motion_rev" in batch:
        mu_rev, _ = model.apply(params, batch["motion_rev"], deterministic=not train, method=Evaluator.encode_motion,
                                rngs={"dropout": jax.random.fold_in(r_drop, 4)})
    mu_hard = None
    if c.hard_negatives and "motion_hard" in batch:  # (B, K, T, F): the K edits of each clip, one pass
        B, K = batch["motion_hard"].shape[:2]
        flat, _ = model.apply(params, batch["motion_hard"].reshape((B * K,) + batch["motion_hard"].shape[2:]),
                              deterministic=not train, method=Evaluator.encode_motion,
                              rngs={"dropout": jax.random.fold_in(r_drop, 5)})
        mu_hard = flat.reshape(B, K, -1)
    l_nce = infonce(mu_m, mu_t, c.temperature, same_text_BxB=same, mu_m_rev=mu_rev,
                    rev_same_B=batch.get("rev_same_text") if mu_rev is not None else None,
                    mu_m_hard_BxKxD=mu_hard, hard_same_BxK=batch.get("hard_same_text") if mu_hard is not None else None)
    l_kl = _kl(mu_t, lv_t, mu_m, lv_m) + _kl(mu_m, lv_m, mu_t, lv_t)
    l_lat = optax.huber_loss(z_t, z_m, delta=1.0).mean()
    total = c.w_infonce * l_nce + c.w_kl * l_kl + c.w_latent * l_lat
    aux = {"infonce": l_nce, "kl": l_kl, "latent": l_lat}
    if c.recon:
        dec = lambda z, k: model.apply(params, z, deterministic=not train, method=Evaluator.decode,  # noqa: E731
                                       rngs={"dropout": jax.random.fold_in(r_drop, k)})
        l_rec = (optax.huber_loss(dec(z_t, 2), batch["motion"], delta=1.0).mean()
                 + optax.huber_loss(dec(z_m, 3), batch["motion"], delta=1.0).mean())
        total = total + c.w_recon * l_rec
        aux["recon"] = l_rec
    return total, aux
