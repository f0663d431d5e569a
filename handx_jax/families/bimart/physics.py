"""BimArt's contact guidance (§3.3, Eq. 5-6) and refinement (§3.4, Eq. 8-12) on this project's hands.

Contact guidance. From a predicted clean motion X̂ (normalised), each hand's keypoints H^ρ in the world; the derived
contact map C̃^ρ (Eq. 5) is, at each part's K mapped points Ṽ (objects/features.mapped_points_world), the distance
to the nearest of the hand's surface keypoints — a min over keypoints, the paper's "differentiable one-nearest-
neighbour" (its gradient flows through the nearest point). Both maps are clipped at the contact range (0.2 m):
beyond it a hand is "far" and should not be pulled toward an entry the generated map also calls far. The energy
per hand is the mean squared discrepancy to the generated map Ĉ^ρ. The step is the project's guidance step
(families/diffusion/guidance.py: ``guide_step``, x̂0 - ℓ ∇E/‖∇E‖ with ℓ = min(s·w(t), 2E/‖∇E‖), w(t) of its
``SCHEDULES``), per hand as Eq. 6 writes it (each hand's rows of X̂ stepped by its own unit gradient); the direction
of ∇‖Ĉ-C̃‖ and of ∇‖Ĉ-C̃‖² is the same, and the squared form makes the step's cap the Gauss-Newton step.

Refinement. The paper fits MANO to Ĥ (Eq. 8), then refines it against three energies (Eq. 9-12). Here the hand
is this project's parametric hand (hand_fit.py: per clip a bone geometry β, per frame the wrist's pose and 16
joint angles within their limits, θ), started in closed form from the joints X̂ predicts (they are among its
keypoints, common.py), fitted to Ĥ (Eq. 8: geometry and pose), then refined with the geometry frozen:

- l_proj (Eq. 10): the keypoints moved by their predicted D̂ should lie on the object: mean |d(h + D̂)|;
- l_pen (Eq. 11): hand-surface points (all of hand_surface.surface_points, the dense Ξ̂) inside the object: mean
  max(0, -d);
- l_acc (Eq. 12): mean ‖h_i - 2h_{i-1} + h_{i-2}‖ over those surface points;

weighted w_proj : w_pen : w_acc = 100 : 10 : 1000 (§3.5, ARCTIC), each a mean over its points rather than the
paper's sum over MANO's vertices, so the ratios are the paper's whatever the point counts. Adam on Θ, all
iterations in one ``lax.scan`` (one jitted program per clip shape). ``RefineConfig.param="joints"`` optimises the
21 free joints instead (the first version of this module: bone lengths then drift and fingers crumple).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
from handx_jax import hand_surface as hs
from handx_jax.families.bimart import common as C
from handx_jax.families.bimart import hand_fit as HF
from handx_jax.families.diffusion.guidance import guide_step, schedule_weight
from handx_jax.models import bimart as BM
from handx_jax.objects import object_sdf

GUIDE_AT = ("before_cfg", "after_cfg")


def x_to_points(x_BxFxX, mean_X, std_X, t0_Bx3, cfg: BM.BimArtConfig):
    """Normalised X̂ → world keypoints (B, F, 2, P, 3) and D̂ (B, F, 2, P, 3) (zeros for the joints rep)."""
    B, F, _ = x_BxFxX.shape
    raw = x_BxFxX * std_X + mean_X
    c = 6 if cfg.hand_rep == "surface" else 3
    raw = raw.reshape(B, F, 2, BM.hand_points(cfg), c)
    H = raw[..., :3] + t0_Bx3[:, None, None, None]
    D = raw[..., 3:] if c == 6 else jnp.zeros_like(H)
    return H, D


def surface_keypoints(H_BxFx2xPx3, cfg: BM.BimArtConfig):
    """The hand-surface points a contact map is read from: X's J surface points, or (joints rep) those on the
    surface of the predicted joints."""
    if cfg.hand_rep == "surface":
        return H_BxFx2xPx3[..., BM.JOINTS:, :]
    return hs.surface_points(H_BxFx2xPx3)[0][..., C.surface_index(cfg.keypoints), :]


def derived_contact(S_BxFx2xJx3, V_BxFx2xKx3):
    """C̃ of Eq. 5: (B, F, 2 hands, 2 parts, K), the distance from each mapped point to the hand's nearest point."""
    diff = V_BxFx2xKx3[:, :, None, :, :, None, :] - S_BxFx2xJx3[:, :, :, None, None, :, :]   # (B,F,h,p,K,J,3)
    d2 = jnp.sum(diff * diff, -1)
    d2min = jnp.min(d2, -1)
    return jnp.sqrt(jnp.maximum(d2min, 1e-12))


def contact_energy_per_hand(x_BxFxX, target_BxFx2x2xK, V, mean_X, std_X, t0, cfg):
    """(B, 2): each hand's mean squared discrepancy (m²) between its derived map and the target (both clipped)."""
    H, _ = x_to_points(x_BxFxX, mean_X, std_X, t0, cfg)
    c = jnp.minimum(derived_contact(surface_keypoints(H, cfg), V), C.CONTACT_MAX_M)
    r = c - jnp.minimum(target_BxFx2x2xK, C.CONTACT_MAX_M)
    return jnp.mean(r * r, axis=(1, 3, 4))


def hand_rows(x_BxFxX):
    """X̂ → (B·2, F, X/2): each hand's columns as its own row, so the guidance step normalises per hand (Eq. 6)."""
    B, F, X = x_BxFxX.shape
    return x_BxFxX.reshape(B, F, 2, X // 2).transpose(0, 2, 1, 3).reshape(B * 2, F, X // 2)


def from_hand_rows(r, B):
    _, F, Xh = r.shape
    return r.reshape(B, 2, F, Xh).transpose(0, 2, 1, 3).reshape(B, F, 2 * Xh)


def contact_guide(x0_BxFxX, target, V, mean_X, std_X, t0, cfg, length):
    """One Eq. 6 step on X̂ (normalised), per hand, of length ``length`` (the guidance step's cap applies)."""
    B = x0_BxFxX.shape[0]

    def energy(rows):
        return contact_energy_per_hand(from_hand_rows(rows, B), target, V, mean_X, std_X, t0, cfg).reshape(-1)

    return from_hand_rows(guide_step(hand_rows(x0_BxFxX), energy, length), B)


def guide_length(strength, schedule: str, alphas_cumprod_T, t):
    return strength * schedule_weight(schedule, jnp.asarray(alphas_cumprod_T, jnp.float32)[t])


# ------------------------------------------------------------------------------------------------
# Refinement (§3.4)


PARAMS = ("skeleton", "joints")


@dataclass(frozen=True)
class RefineConfig:
    fit_iters: int = 100  # Eq. 8
    iters: int = 100      # Eq. 9, §3.5: "performed for 100 iterations"
    lr: float = 1e-3      # Adam: metres per step (about) of the wrist, or of a joint (param="joints")
    w_proj: float = 100.0
    w_pen: float = 10.0
    w_acc: float = 1000.0
    param: str = "skeleton"  # what is optimised: hand_fit's Θ, or the 21 free joints


def _sdf(obj, states_Tx7, pts_TxNx3):
    return jax.vmap(lambda s, p: object_sdf(obj, s, p)[0])(states_Tx7, pts_TxNx3)


def energies(joints_Tx2x21x3, H_hat_Tx2xPx3, D_hat_Tx2xPx3, obj, states_Tx7, cfg: BM.BimArtConfig):
    """Eq. 8 (fit) and the three terms of Eq. 9 (proj, pen, acc) of one clip's joints."""
    T = joints_Tx2x21x3.shape[0]
    H = C.keypoints(joints_Tx2x21x3, cfg)                                         # (T, 2, P, 3)
    fit = jnp.mean(jnp.sqrt(jnp.sum((H - H_hat_Tx2xPx3) ** 2, -1) + 1e-12))
    dense, _ = hs.surface_points(joints_Tx2x21x3)                                 # (T, 2, S, 3)
    d_dense = _sdf(obj, states_Tx7, dense.reshape(T, -1, 3))
    pen = jnp.mean(jnp.maximum(-d_dense, 0.0))
    acc = jnp.mean(jnp.sqrt(jnp.sum((dense[2:] - 2 * dense[1:-1] + dense[:-2]) ** 2, -1) + 1e-12))
    if cfg.hand_rep == "surface":
        proj = jnp.mean(jnp.abs(_sdf(obj, states_Tx7, (H + D_hat_Tx2xPx3).reshape(T, -1, 3))))
    else:
        proj = jnp.zeros(())
    return {"fit": fit, "proj": proj, "pen": pen, "acc": acc}


def refine(joints0_Tx2x21x3, H_hat, D_hat, obj, states_Tx7, cfg: BM.BimArtConfig, rc: RefineConfig):
    """Fit (Eq. 8) then refine (Eq. 9); returns the joints. Traceable: jit it (``refine_jit``) or vmap it."""
    if rc.param == "joints":
        to_joints, theta = (lambda J: J), joints0_Tx2x21x3
        step_scale = rc.lr
    else:
        to_joints, theta = HF.joints, HF.init(joints0_Tx2x21x3)
        step_scale = {k: v * rc.lr / HF.STEP_SCALE["trans"] for k, v in HF.STEP_SCALE.items()}

    def run(theta, iters, weights, frozen):
        def loss(theta):
            e = energies(to_joints(theta), H_hat, D_hat, obj, states_Tx7, cfg)
            return sum(w * e[k] for k, w in weights.items())

        def step(carry, _):
            theta, s = carry
            g = jax.grad(loss)(theta)
            return HF.scaled_adam_step(s, theta, g, step_scale, frozen), None

        (theta, _), _ = jax.lax.scan(step, (theta, HF.adam_init(theta)), None, length=iters)
        return theta

    theta = run(theta, rc.fit_iters, {"fit": 1.0}, ())
    # β is the clip's: fitted to Ĥ, then held while the pose moves against the object (MANO's β likewise).
    theta = run(theta, rc.iters, {"proj": rc.w_proj, "pen": rc.w_pen, "acc": rc.w_acc}, ("scale", "jitter"))
    return to_joints(theta)


energies_jit = jax.jit(energies, static_argnames=("cfg",))
refine_jit = jax.jit(refine, static_argnames=("cfg", "rc"))
refine_batch = jax.jit(jax.vmap(refine, (0, 0, 0, 0, 0, None, None)), static_argnames=("cfg", "rc"))
