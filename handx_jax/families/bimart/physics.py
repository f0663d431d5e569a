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

weighted w_proj : w_pen : w_acc = 1000 : 10000 : 1000, each a mean over its points (``RefineConfig``: chosen on this
corpus's validation split; BimArt's ARCTIC weights, 100 : 10 : 1000 as sums, are one --set away). Adam on Θ, all
iterations in one ``lax.scan`` (one jitted program per clip shape). ``RefineConfig.param="joints"`` optimises the
21 free joints instead (the first version of this module: bone lengths then drift and fingers crumple).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
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
REDUCE = ("sum", "mean")


@dataclass(frozen=True)
class RefineConfig:
    """Eq. 8-12's settings. The weights are this corpus's, chosen on its validation split (docs/results/bimart,
    refine_scan.json): BimArt tunes them per dataset (§3.5: w_acc = 1000 on ARCTIC, 10^4 on HOI4D), and its ARCTIC
    setting, ``w_proj=100 w_pen=10 w_acc=1000 reduce=sum``, leaves this corpus's penetration where the denoiser put
    it (val: Pen 1cm 44 -> 42%, Con 81 -> 82%), where these cut it 18x with Con 100% and Accel at the ground
    truth's. Per point, penetration weighs 10x acceleration here, where it weighs 1/100 of it in BimArt's."""

    fit_iters: int = 100  # Eq. 8
    iters: int = 100      # Eq. 9, §3.5: "performed for 100 iterations"
    lr: float = 1e-3      # Adam: metres per step (about) of the wrist, or of a joint (param="joints")
    w_proj: float = 1000.0
    w_pen: float = 10000.0
    w_acc: float = 1000.0
    param: str = "skeleton"  # what is optimised: hand_fit's Θ, or the 21 free joints
    # "sum": Eq. 10-12 as printed, sums over their points (normalised by the dense points of a clip, which Adam
    # does not see): a keypoint's projection weighs w_proj, a dense point's penetration w_pen. "mean": each term a
    # mean over its own points, which weighs the J + 21 keypoints' projection S / (J + 21) times more per point.
    reduce: str = "mean"


def _sdf(obj, states_Tx7, pts_TxNx3):
    """The object's signed distance at each frame's points, (T, N). A primitive object's is vectorised over the
    frames; a mesh's (an ARCTIC template: every point against every triangle) goes frame by frame, each frame
    rematerialised in the backward pass, so refinement holds one frame's point × triangle intermediates instead
    of T of them (measured before: 9.7 GB for one 60-frame window against 256 triangles, all frames at once)."""
    def one(state_pts):
        return object_sdf(obj, state_pts[0], state_pts[1])[0]

    if obj.tri_Fx3x3 is None:
        return jax.vmap(one)((states_Tx7, pts_TxNx3))
    return jax.lax.map(jax.checkpoint(one), (states_Tx7, pts_TxNx3))


_TIP_CAPSULES = np.flatnonzero(hs.CAPSULE_IS_TIP)
# The spheres along the capsules' axes that carry the dense surface points (hand_surface.surface_points: a ring of
# points around each centre at the capsule's radius; a fingertip's rounded end around the capsule's end).
SPHERE_RADIUS_M = np.concatenate([np.repeat(hs.CAPSULE_RADII_M, len(hs.RINGS)), hs.CAPSULE_RADII_M[_TIP_CAPSULES]])


def axis_spheres(joints_Mx21x3):
    """Centres (M, C·R + 5, 3) of the spheres of radius ``SPHERE_RADIUS_M`` that carry the dense surface points."""
    p, q = hs.capsules(joints_Mx21x3)
    rings = p[..., None, :] + jnp.asarray(hs.RINGS, jnp.float32)[:, None] * (q - p)[..., None, :]   # (M, C, R, 3)
    return jnp.concatenate([rings.reshape(*rings.shape[:-3], -1, 3), q[..., _TIP_CAPSULES, :]], -2)


def energies(joints_Tx2x21x3, H_hat_Tx2xPx3, D_hat_Tx2xPx3, obj, states_Tx7, cfg: BM.BimArtConfig):
    """Eq. 8 (fit) and the three terms of Eq. 9 (proj, pen, acc) of one clip's joints.

    pen reads the object at the 71 sphere centres per hand that carry the 573 dense points, not at the points:
    a signed distance is 1-Lipschitz, so a surface point of a sphere of radius r at centre c is at most
    r - d(c) deep, with equality where the object's surface is locally flat; max(0, r - d(c)) bounds every point
    of the ring above. 8× fewer distance evaluations, the cost of refinement (measured: 36 of 39 ms of the
    energies of one clip, dense points)."""
    T = joints_Tx2x21x3.shape[0]
    H = C.keypoints(joints_Tx2x21x3, cfg)                                         # (T, 2, P, 3)
    fit = jnp.mean(jnp.sqrt(jnp.sum((H - H_hat_Tx2xPx3) ** 2, -1) + 1e-12))
    dense, _ = hs.surface_points(joints_Tx2x21x3)                                 # (T, 2, S, 3)
    d_centre = _sdf(obj, states_Tx7, axis_spheres(joints_Tx2x21x3).reshape(T, -1, 3)).reshape(T, 2, -1)
    pen = jnp.mean(jnp.maximum(jnp.asarray(SPHERE_RADIUS_M, jnp.float32) - d_centre, 0.0))
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
    w_proj = rc.w_proj * (BM.hand_points(cfg) / hs.N_SURFACE_POINTS if rc.reduce == "sum" else 1.0)
    theta = run(theta, rc.iters, {"proj": w_proj, "pen": rc.w_pen, "acc": rc.w_acc}, ("scale", "jitter"))
    return to_joints(theta)


energies_jit = jax.jit(energies, static_argnames=("cfg",))
refine_jit = jax.jit(refine, static_argnames=("cfg", "rc"))
refine_batch = jax.jit(jax.vmap(refine, (0, 0, 0, 0, 0, None, None)), static_argnames=("cfg", "rc"))
