"""BimArt's object features (§3.1, Eq. 1-3): the normalised part-based BPS O, the global states G and the scale s_o.

One fixed basis B (K points in the unit ball, ``bps.basis_points``) is mapped to each part at the part's
canonical pose (``bps.part_bps_points``; a hand-object corpus stores the mapped points as ``bps_points.npy``).
Per frame i and part p the feature is the vector from each basis point to its mapped point, with the object
scaled by s_o (Eq. 1) into the ball (Eq. 2):

    O_i^bottom[k] = s_o v^bottom_k - b_k,     O_i^top[k] = s_o R_hinge(a_i) v^top_k - b_k,

in the object-centric frame (the bottom part's canonical frame). The top part's points turn with the frame's
angle a_i, so O carries the articulation; nothing of the global rotation or translation enters it (§3.1: "Our BPS
feature O is independent of the object's global trajectory, encoding only the object's shape and articulation
states"). The paper re-maps B at every frame's angle; the part-1 mapping is fixed per part, so entry k of each
part is one material point over a clip, the point whose contact map entry (§3.2) it conditions.

G (§3.1: "a lower dimensional 6D vector per frame, which consists of relative translation to the first frame and
the global rotation"): [axis-angle rotation (3), t_i - t_1 (3)], metres. Translation relative to the first frame
makes G invariant to where the clip is placed, which the paper uses against overfitting to absolute positions.

Pure jnp functions of arrays; they broadcast over leading clip axes.
"""

import jax.numpy as jnp

from handx_jax.objects.articulated import BOTTOM, TOP
from handx_jax.objects.rotation import hinge_matrix, rotvec_to_matrix

G_DIM = 6


def bps_features(bps_points_2xKx3, basis_Kx3, s_o, angles_T):
    """O of Eq. 2-3 per frame: (T, 2, K, 3) (parts TOP, BOTTOM), unit-ball units."""
    top = jnp.einsum("tij,kj->tki", hinge_matrix(jnp.asarray(angles_T)), bps_points_2xKx3[TOP])   # (T, K, 3)
    bottom = jnp.broadcast_to(bps_points_2xKx3[BOTTOM], top.shape)
    return jnp.stack([top, bottom], 1) * s_o - basis_Kx3


def global_states(states_Tx7):
    """G: (T, 6) = [axis-angle rotation, translation minus the first frame's] per frame."""
    s = jnp.asarray(states_Tx7)
    return jnp.concatenate([s[..., 1:4], s[..., 4:7] - s[..., :1, 4:7]], -1)


def object_features(bps_points_2xKx3, basis_Kx3, s_o, states_Tx7):
    """The per-frame object condition of both BimArt models: [O (2·K·3) | G (6) | s_o (1)], (T, 6K + 7)."""
    O = bps_features(bps_points_2xKx3, basis_Kx3, s_o, states_Tx7[:, 0])
    T = states_Tx7.shape[0]
    return jnp.concatenate([O.reshape(T, -1), global_states(states_Tx7), jnp.full((T, 1), s_o)], -1)


def feature_dim(k: int) -> int:
    return 2 * k * 3 + G_DIM + 1


def mapped_points_world(bps_points_2xKx3, states_Tx7):
    """Ṽ_i of Eq. 4: each part's mapped points in the world at every frame, (T, 2, K, 3) — the points a contact
    map's entries measure from (``articulated.to_world`` of both parts, batched over frames)."""
    s = jnp.asarray(states_Tx7)
    R_g = rotvec_to_matrix(s[:, 1:4])                                                 # (T, 3, 3)
    R_top = R_g @ hinge_matrix(s[:, 0])
    t = s[:, None, 4:7]
    top = jnp.einsum("tij,kj->tki", R_top, bps_points_2xKx3[TOP]) + t
    bottom = jnp.einsum("tij,kj->tki", R_g, bps_points_2xKx3[BOTTOM]) + t
    out = [None, None]
    out[TOP], out[BOTTOM] = top, bottom
    return jnp.stack(out, 1)
