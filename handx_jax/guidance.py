"""A differentiable contact energy on joints, for guiding a sampler toward named contacts (issue 33, item 2).

BimArt (§3.3, §3.5) steers each denoising step with the gradient of a contact term on the predicted clean
motion x̂0 and scales it by the gradient's norm (λ_c = 1 / ‖∇‖). Here the contacts are hand–hand ones, in
the vocabulary of the project's event records and of the contact-feasibility metric
(:data:`handx_jax.metrics.CONTACT_CHANNELS`): 8 intra-hand thumb-tip pairs, 25 left × right tip pairs, 10
tip → other palm (the mean of the k closest palm-cloud points, as data/features.py measures it). A request
is a (T, 43) weight per frame and channel (1 where a named contact should hold, 0 elsewhere; see
:func:`request_from_named`), and the energy is the mean over requested (frame, channel) cells of the
squared amount by which the distance exceeds the channel's contact threshold: zero once every requested
pair is in contact, so satisfied contacts are not pulled further together (into each other).

The sampler integration (a strength schedule inside the compiled sampling loop, ``--contact``) is not here.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import metrics as M
from handx_jax import skeleton as sk

# Distances are aimed this fraction inside the contact threshold: a pair that stops exactly at the
# threshold is not counted as touching (the metric's test is strict), and sampling noise after the last
# guided step would undo a contact held only at the edge.
TARGET_FRACTION = 0.8


def _safe_norm(v: jax.Array, axis: int = -1) -> jax.Array:
    """‖v‖ with a finite gradient at v = 0 (coincident joints give 0/0 in the plain norm's gradient)."""
    return jnp.sqrt(jnp.sum(v * v, axis=axis) + 1e-12)


def channel_distances(joints_BxTx2x21x3: jax.Array, palm_Px21: jax.Array, k: int = 5) -> jax.Array:
    """Differentiable per-frame distances (B, T, 43) m of :data:`handx_jax.metrics.CONTACT_CHANNELS`; the
    same quantities as :func:`handx_jax.metrics.contact_channel_distances` (the metric's fast form)."""
    x = joints_BxTx2x21x3
    B, T = x.shape[:2]
    tips = x[:, :, :, jnp.asarray(sk.TIPS)]  # (B, T, 2, 5, 3) thumb..pinky
    intra = _safe_norm(tips[:, :, :, 1:] - tips[:, :, :, :1]).reshape(B, T, 8)
    inter = _safe_norm(tips[:, :, 0, :, None] - tips[:, :, 1, None, :]).reshape(B, T, 25)
    palm = jnp.einsum("pj,bthjx->bthpx", palm_Px21, x)[:, :, ::-1]  # (B, T, 2, P, 3): the OTHER hand's palm
    d = _safe_norm(tips[:, :, :, :, None] - palm[:, :, :, None])  # (B, T, 2, 5, P)
    fp = -jnp.mean(jax.lax.top_k(-d, k)[0], -1).reshape(B, T, 10)  # mean of the k closest (top_k has a gradient)
    return jnp.concatenate([intra, inter, fp], -1)


def contact_energy(joints_BxTx2x21x3: jax.Array, request_BxTxC: jax.Array, palm_Px21: jax.Array,
                   thresholds_C: jax.Array | None = None, k: int = 5) -> jax.Array:
    """Energy (B,) m²: mean over requested cells of max(0, d − TARGET_FRACTION · threshold)²; 0 with no
    request. ``thresholds_C`` defaults to the records' contact thresholds (:func:`metrics.contact_thresholds`)."""
    thr = jnp.asarray(M.contact_thresholds() if thresholds_C is None else thresholds_C, joints_BxTx2x21x3.dtype)
    d = channel_distances(joints_BxTx2x21x3, palm_Px21, k)
    w = jnp.asarray(request_BxTxC, d.dtype)
    gap = jnp.maximum(d - TARGET_FRACTION * thr, 0.0)
    return jnp.sum(w * gap**2, axis=(1, 2)) / jnp.maximum(jnp.sum(w, axis=(1, 2)), 1.0)


def request_from_named(named: M.NamedContacts, n: int, T: int) -> np.ndarray:
    """(n, T, 43) float32 request of the contacts records name (:func:`metrics.named_contacts`): 1 on every
    frame of each named contact's [start, end) range, in its channel."""
    out = np.zeros((n, T, M.N_CONTACT_CHANNELS), np.float32)
    for c, ch, s, e in zip(named.clip_E, named.channel_E, named.start_E, named.end_E):
        out[c, max(int(s), 0):min(int(e), T), ch] = 1.0
    return out
