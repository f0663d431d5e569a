"""Contact feasibility: the contacts a clip's interaction caption and hand captions name are the contact
events of its structured record (annotation/events.py; the captioner never leaves out a contact, annotation/caption
inter.py, hand.py). Each is one channel of a per-frame distance and a half-open frame range;
a named contact is realised when the generated motion brings the pair within the project's contact
threshold in at least one frame of that range (BimArt §4 "Con" asks the same of hand–object contact).
Channels: 8 intra-hand thumb-tip pairs, 25 left × right tip pairs, 10 tip → other palm (mean of the
k closest palm-cloud points, as the events measure it)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import skeleton as sk
from handx_jax.metrics.chunking import map_chunks


def _contact_channels() -> dict[tuple[str, str], int]:
    from handx_jax.annotation import events as evm

    keys = [(h, k) for h in ("left_hand_events", "right_hand_events") for k in evm.INTRA_KEYS]
    keys += [("finger_tip_contact", k) for k in evm.INTER_KEYS] + [("finger_palm_distance", k) for k in evm.FP_KEYS]
    return {k: i for i, k in enumerate(keys)}


CONTACT_CHANNELS = _contact_channels()  # (section, record key) → channel
N_CONTACT_CHANNELS = len(CONTACT_CHANNELS)  # 43


@dataclass(frozen=True)
class NamedContacts:
    """The E contacts named by N clips' records: clip index, channel, half-open [start, end)."""

    clip_E: np.ndarray
    channel_E: np.ndarray
    start_E: np.ndarray
    end_E: np.ndarray

    def __len__(self) -> int:
        return len(self.clip_E)


def named_contacts(records) -> NamedContacts:
    """The contact events of each clip's record (events.annotate layout, reference §6.3): tip–tip runs
    within and across hands, and the "contact" periods of the finger–palm series (the captioner's own
    reading, caption.inter.contact_periods). Palm–palm contact is not a tip contact and is not counted."""
    from handx_jax.annotation.caption.inter import contact_periods

    rows = []
    for n, rec in enumerate(records):
        T = int(rec["frame_count"])
        for h in ("left_hand_events", "right_hand_events"):
            for key, runs in rec[h].get("finger_tip_contact", {}).items():
                rows += [(n, CONTACT_CHANNELS[(h, key)], e["start"], e["end"]) for e in runs]
        rel = rec["two_hand_relationships"]
        for key, runs in rel.get("finger_tip_contact", {}).items():
            rows += [(n, CONTACT_CHANNELS[("finger_tip_contact", key)], e["start"], e["end"]) for e in runs]
        for key, evs in rel.get("finger_palm_distance", {}).items():
            rows += [(n, CONTACT_CHANNELS[("finger_palm_distance", key)], s, e) for s, e in contact_periods(evs, T)]
    a = np.asarray(rows, np.int64).reshape(-1, 4)
    return NamedContacts(a[:, 0], a[:, 1], a[:, 2], a[:, 3])


def contact_thresholds() -> np.ndarray:
    """(43,) m: tip–tip below AnnotationConfig.tip_contact_m (Table A: 2 cm), tip–palm below the
    finger–palm "contact" state edge (2.5 cm), the thresholds that made the records' contact events."""
    from handx_jax.annotation import events as evm

    tip, palm = evm.AnnotationConfig().tip_contact_m, evm.FINGER_PALM.state_edges[0]
    return np.array([palm if sec == "finger_palm_distance" else tip for sec, _ in CONTACT_CHANNELS], np.float32)


@partial(jax.jit, static_argnames=("k",))
def contact_channel_distances(joints_NxTx2x21x3: jax.Array, palm_Px21: jax.Array, k: int = 5) -> jax.Array:
    """Per-frame distances (N, T, 43) m of the :data:`CONTACT_CHANNELS`, as features.py measures them:
    tip–tip, and tip → mean of the ``k`` closest points of the other hand's palm cloud."""
    def one(x):
        tips = x[:, :, :, jnp.asarray(sk.TIPS)]  # (C, T, 2, 5, 3) thumb..pinky
        intra = jnp.linalg.norm(tips[:, :, :, 1:] - tips[:, :, :, :1], axis=-1).reshape(*x.shape[:2], 8)
        inter = jnp.linalg.norm(tips[:, :, 0, :, None] - tips[:, :, 1, None, :], axis=-1).reshape(*x.shape[:2], 25)
        # Coordinate-major (xyz first), as in _tip_palm_min_dist: the k smallest of the squared distances,
        # then k square roots.
        palm = jnp.einsum("pj,cthjx->xcthp", palm_Px21, x)[:, :, :, ::-1]  # (3, C, T, 2, P): the OTHER hand
        tcm = jnp.moveaxis(tips, -1, 0)[..., None]  # (3, C, T, 2, 5, 1)
        sq = [jnp.square(tcm[i] - palm[i][..., None, :]) for i in range(3)]  # (C, T, 2, 5, P) each
        near = -jax.lax.top_k(-((sq[0] + sq[2]) + sq[1]), k)[0]
        fp = jnp.mean(jnp.sqrt(near), -1).reshape(*x.shape[:2], 10)
        return jnp.concatenate([intra, inter, fp], -1)

    return map_chunks(one, joints_NxTx2x21x3)


@jax.jit
def _realised(dist_NxTxC, thr_C, clip_E, channel_E, start_E, end_E):
    d = dist_NxTxC[clip_E, :, channel_E]  # (E, T)
    t = jnp.arange(d.shape[1])
    inside = (t[None] >= start_E[:, None]) & (t[None] < end_E[:, None])
    return jnp.any(inside & (d < thr_C[channel_E][:, None]), axis=1)


def contact_feasibility_counts(joints_NxTx2x21x3, named: NamedContacts, palm_Px21,
                               k: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Per clip (N,): contacts named by its record and how many of them the motion realises."""
    n = joints_NxTx2x21x3.shape[0]
    named_N = np.bincount(named.clip_E, minlength=n).astype(np.float64)
    if not len(named):
        return np.zeros(n), named_N
    d = contact_channel_distances(jnp.asarray(joints_NxTx2x21x3, jnp.float32), jnp.asarray(palm_Px21), k)
    hit = np.asarray(_realised(d, jnp.asarray(contact_thresholds()), *(jnp.asarray(a) for a in (
        named.clip_E, named.channel_E, named.start_E, named.end_E))))
    return np.bincount(named.clip_E, weights=hit.astype(np.float64), minlength=n), named_N

