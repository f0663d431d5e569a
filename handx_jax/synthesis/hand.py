"""Forward-kinematic hand model for the procedural corpus (``bimanual.py`` writes the motion programs).

One articulated RIGHT hand is modelled in its own frame, in metres: wrist at the origin, fingers
along +y, the back of the hand along +z (so the palm faces −z) and the thumb on the −x side. The
left hand is its mirror image (x → −x), which ``bimanual.py`` applies after posing.

A pose is 16 angles in degrees per hand and frame (the channel layout below). Coupling that real
hands cannot escape is built in: the DIP joint follows the PIP (DIP = 2/3 PIP), neighbouring fingers
drag each other (``couple_neighbours``), and the thumb's CMC joint has two degrees of freedom
(flexion across the palm and palmar abduction) with the pronation that makes opposition possible
tied to the flexion.

Because every finger bone after the MCP rotates about one axis, the interior angles that the
intensity filter measures (clips.interior_angles_deg) follow in closed form from the channels
(``interior_angles_from_pose``): this lets the program generator check and raise a segment's
finger intensity without running FK twice.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from handx_jax import skeleton as sk

# ---- pose channels (degrees) ------------------------------------------------------------------
# Finger order inside the MCP/PIP/ABD blocks: index, middle, ring, pinky.
MCP = slice(0, 4)    # MCP flexion, + toward the palm, − = hyperextension (bent backwards)
PIP = slice(4, 8)    # PIP flexion; the DIP follows as DIP_PER_PIP × PIP
ABD = slice(8, 12)   # MCP abduction, + toward the thumb
T_CMC_FLEX, T_CMC_ABD, T_MCP, T_IP = 12, 13, 14, 15  # thumb: opposition, palmar abduction, MCP, IP
NUM_CHANNELS = 16
DIP_PER_PIP = 2.0 / 3.0
CHANNEL_NAMES = (
    "index_mcp", "middle_mcp", "ring_mcp", "pinky_mcp",
    "index_pip", "middle_pip", "ring_pip", "pinky_pip",
    "index_abd", "middle_abd", "ring_abd", "pinky_abd",
    "thumb_cmc_flex", "thumb_cmc_abd", "thumb_mcp", "thumb_ip",
)

# Active ranges of motion (degrees). MCP hyperextension to −40° is within normal passive range.
LIMITS_LO_16 = np.array([-40] * 4 + [0] * 4 + [-30] * 4 + [-15, 0, -10, -20], dtype=np.float64)
LIMITS_HI_16 = np.array([90] * 4 + [105] * 4 + [30] * 4 + [55, 70, 60, 80], dtype=np.float64)

# ---- anatomy of the unscaled right hand (centimetres, converted to metres below) -------------
# MCP joint centres relative to the wrist: index, middle, ring, pinky.
_FINGER_MCP_CM_4x3 = np.array([[-2.5, 9.2, 0.0], [-0.4, 9.4, 0.0], [1.4, 9.0, -0.2], [3.0, 8.3, -0.6]])
# Proximal, middle, distal(+pad to the tip) phalanx lengths.
_FINGER_BONES_CM_4x3 = np.array([[4.4, 2.6, 2.3], [4.8, 3.0, 2.4], [4.5, 2.9, 2.4], [3.6, 2.1, 2.2]])
_THUMB_CMC_CM_3 = np.array([-2.0, 2.5, -1.0])
_THUMB_BONES_CM_3 = np.array([4.6, 3.2, 2.9])  # metacarpal, proximal, distal(+pad)

# Abduction that makes the fingers roughly parallel (the metacarpals fan out from the wrist),
# and the extra abduction of a fully spread hand.
ABD_CLOSED_4 = np.array([-12.0, -2.0, 8.0, 16.0])
ABD_SPREAD_FAN_4 = np.array([22.0, 5.0, -11.0, -25.0])

# Thumb rest frame (columns: lateral, along the metacarpal, nail side). At rest the thumb lies near
# the palm plane, pointing forward and away from the index; its pad faces the palm and the pinky.
_T_ALONG = np.array([-0.6, 0.8, -0.05]) / np.linalg.norm([-0.6, 0.8, -0.05])
_T_NAIL = np.array([-0.5, 0.0, 0.85]) - _T_ALONG * (np.array([-0.5, 0.0, 0.85]) @ _T_ALONG)
_T_NAIL = _T_NAIL / np.linalg.norm(_T_NAIL)
_T_LAT = np.cross(_T_ALONG, _T_NAIL)
THUMB_ROLL_PER_FLEX = 0.6  # pronation of the thumb column per degree of CMC opposition

# Neighbouring-finger coupling strength (the ring finger is the least independent).
_COUPLING_4 = np.array([0.08, 0.15, 0.25, 0.15])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# Per-finger frames: the rest direction is the metacarpal line from the wrist, so at zero flexion
# and abduction the MCP interior angle is exactly 0 and the closed-form angles below are exact.
_FINGER_DIR_4x3 = _unit(_FINGER_MCP_CM_4x3)
_FINGER_LAT_4x3 = _unit(np.cross(_FINGER_DIR_4x3, [0.0, 0.0, 1.0]))  # toward the pinky side
_FINGER_BACK_4x3 = np.cross(_FINGER_LAT_4x3, _FINGER_DIR_4x3)        # dorsal; the palm is −back
_THUMB_CMC_DIR_3 = _unit(_THUMB_CMC_CM_3)


def hand_geometry(scale_N: np.ndarray, jitter_Nx5x3: np.ndarray) -> dict[str, np.ndarray]:
    """Bone geometry (metres) for N hands of size ``scale`` with per-bone relative length jitter.

    ``jitter_Nx5x3`` rows are thumb, index, middle, ring, pinky; columns the three finger bones.
    Metacarpal positions scale uniformly so that the palm keeps its shape.
    """
    s = np.asarray(scale_N, dtype=np.float64)[:, None]
    j = 1.0 + np.asarray(jitter_Nx5x3, dtype=np.float64)
    return {
        "mcp_Nx4x3": 0.01 * s[:, :, None] * _FINGER_MCP_CM_4x3,
        "bones_Nx4x3": 0.01 * s[:, :, None] * _FINGER_BONES_CM_4x3 * j[:, 1:],
        "cmc_Nx3": 0.01 * s * _THUMB_CMC_CM_3,
        "thumb_bones_Nx3": 0.01 * s * _THUMB_BONES_CM_3 * j[:, 0],
    }


def couple_neighbours(pose_x16: np.ndarray) -> np.ndarray:
    """Pull each finger's MCP and PIP flexion toward its neighbours' (finger enslaving)."""
    out = np.array(pose_x16, dtype=np.float64, copy=True)
    for blk in (MCP, PIP):
        f = out[..., blk]
        nb = np.stack([f[..., 1], 0.5 * (f[..., 0] + f[..., 2]), 0.5 * (f[..., 1] + f[..., 3]), f[..., 2]], -1)
        out[..., blk] = f + _COUPLING_4 * (nb - f)
    return out


def clip_to_limits(pose_x16: np.ndarray) -> np.ndarray:
    return np.clip(pose_x16, LIMITS_LO_16, LIMITS_HI_16)


def _thumb_axes(pose_x16: np.ndarray, radians: bool = False, xp=None) -> tuple[np.ndarray, np.ndarray]:
    """Thumb metacarpal direction and nail-side axis after the 2-DoF CMC rotation, (..., 3) each.

    R = Rz(−flex) · Ry(−abd) · T0 · Ry_local(roll): flexion swings the thumb across the palm toward
    the pinky, abduction lifts it out of the palm plane, and the coupled roll pronates it so the
    pad turns toward the finger pads (opposition).
    """
    xp = np if xp is None else xp  # looked up per call (a test swaps the module's numpy for one with other sin/cos)
    to_rad = (lambda x: x) if radians else xp.radians
    f, a = to_rad(pose_x16[..., T_CMC_FLEX]), to_rad(pose_x16[..., T_CMC_ABD])
    roll = THUMB_ROLL_PER_FLEX * f
    cf, sf, ca, sa = xp.cos(f), xp.sin(f), xp.cos(a), xp.sin(a)
    # Rows of Rz(−f)·Ry(−a), written out so that no (...,3,3) matrices are materialised.
    def apply(v: np.ndarray) -> np.ndarray:
        vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
        return xp.stack([cf * ca * vx + sf * vy - cf * sa * vz,
                         -sf * ca * vx + cf * vy + sf * sa * vz,
                         sa * vx + ca * vz], -1)
    t_along, t_lat, t_nail = (xp.asarray(v, dtype=f.dtype) for v in (_T_ALONG, _T_LAT, _T_NAIL))
    along = apply(xp.broadcast_to(t_along, f.shape + (3,)))
    nail_local = xp.sin(roll)[..., None] * t_lat + xp.cos(roll)[..., None] * t_nail
    return along, apply(nail_local)


# Model order used inside hand_fk: wrist, thumb CMC..tip, then MCP..tip of index, middle, ring,
# pinky; _MODEL_TO_OFFICIAL permutes it into skeleton.JOINT_NAMES order.
_MODEL_ORDER = (0,) + sk.CHAINS["thumb"][1:] + sum((sk.CHAINS[f][1:] for f in ("index", "middle", "ring", "pinky")), ())
_MODEL_TO_OFFICIAL = np.argsort(_MODEL_ORDER)
_FRAME = {"dir": _FINGER_DIR_4x3, "lat": _FINGER_LAT_4x3, "back": _FINGER_BACK_4x3[:, None, :]}


def hand_fk(pose_x16: np.ndarray, geom: dict[str, np.ndarray], xp=None) -> np.ndarray:
    """Joint positions (..., 21, 3) float64 in the right-hand frame, official joint order, metres.

    ``pose_x16`` is (..., 16) degrees; ``geom`` arrays (from hand_geometry) must broadcast against
    the leading pose axes, e.g. pose (N, T, 2, 16) with geometry reshaped to (N, 1, 1, ...).
    Computed in float64 although float32 would be accurate enough (sub-micrometre): numpy's float32
    sin/cos differ by an ulp between numpy builds and CPUs (SIMD kernels), and 1e-7 relative changes
    of the joints flip ~0.6 % of the captions (thresholds in the annotation). In float64 those
    differences (~1e-16) vanish in the float32 the corpus stores, so a recipe rebuilds the same
    captions and clip ids on another build (issue 14.5). Measured: no slower (0.55 vs 0.63 s a chunk).
    ``xp=jax.numpy`` gives the same function traceable under jit/vmap (in JAX's default float32), which
    the hand–object synthesizer's finger closing needs (synthesis/object_grasp.py).
    """
    xp = np if xp is None else xp
    dtype = np.float64 if xp is np else np.float32
    p = xp.radians(xp.asarray(pose_x16, dtype=dtype))
    lead = p.shape[:-1]
    g = {k: xp.asarray(v, dtype=dtype) for k, v in geom.items()}
    # Fingers: abduction turns the finger in the palm plane, then the three flexions act about one
    # axis, so each finger is planar and bone k points at cumulative flexion phi_k.
    a = p[..., ABD, None]
    dir_a = xp.cos(a) * _FRAME["dir"] - xp.sin(a) * _FRAME["lat"]                   # (..., 4, 3)
    f1, f2 = p[..., MCP], p[..., PIP]
    phi = xp.stack([f1, f1 + f2, f1 + f2 * (1.0 + DIP_PER_PIP)], -1)[..., None]  # (..., 4, 3, 1)
    bone = (xp.cos(phi) * dir_a[..., None, :] - xp.sin(phi) * _FRAME["back"]) * g["bones_Nx4x3"][..., None]
    mcp = xp.broadcast_to(g["mcp_Nx4x3"], lead + (4, 3))
    fingers = xp.cumsum(xp.concatenate([mcp[..., None, :], bone], -2), axis=-2)  # (..., 4, 4, 3)
    # Thumb: CMC sets the metacarpal; MCP and IP flex toward the pad side (−nail).
    along, nail = _thumb_axes(p, radians=True, xp=xp)
    m, i = p[..., T_MCP, None], p[..., T_IP, None]
    tb = g["thumb_bones_Nx3"]
    cmc = xp.broadcast_to(g["cmc_Nx3"], lead + (3,))
    t_mcp = cmc + tb[..., 0:1] * along
    t_ip = t_mcp + tb[..., 1:2] * (xp.cos(m) * along - xp.sin(m) * nail)
    t_tip = t_ip + tb[..., 2:3] * (xp.cos(m + i) * along - xp.sin(m + i) * nail)
    model = xp.concatenate([xp.zeros(lead + (1, 3), dtype=dtype), xp.stack([cmc, t_mcp, t_ip, t_tip], -2),
                            fingers.reshape(lead + (16, 3))], -2)
    return model[..., _MODEL_TO_OFFICIAL, :]


def interior_angles_from_pose(pose_x16: np.ndarray) -> np.ndarray:
    """The 15 interior angles (degrees) that clips.interior_angles_deg would measure on hand_fk.

    Same order as skeleton.INTERIOR_TRIPLES (thumb CMC/MCP/IP, then index..pinky MCP/PIP/DIP).
    Exact for the noise-free model: the finger MCP angle between the metacarpal line and the
    proximal phalanx is acos(cos abd · cos flex), PIP/DIP are planar, and the thumb CMC angle is
    between the wrist→CMC line and the metacarpal.
    """
    p = np.asarray(pose_x16, dtype=np.float64)
    a, f1, f2 = np.radians(p[..., ABD]), np.radians(p[..., MCP]), np.radians(p[..., PIP])
    mcp = np.degrees(np.arccos(np.clip(np.cos(a) * np.cos(f1), -1.0, 1.0)))
    pip = np.degrees(np.abs(f2))
    dip = DIP_PER_PIP * pip
    along, _ = _thumb_axes(p)
    cmc = np.degrees(np.arccos(np.clip(along @ _THUMB_CMC_DIR_3, -1.0, 1.0)))
    thumb = np.stack([cmc, np.abs(p[..., T_MCP]), np.abs(p[..., T_IP])], -1)
    fingers = np.stack([mcp, pip, dip], -1)  # (..., 4, 3), finger order index, middle, ring, pinky
    # skeleton.FINGER_NAMES order after the thumb is index, middle, ring, pinky as well.
    return np.concatenate([thumb, fingers.reshape(p.shape[:-1] + (12,))], -1)


def base_pose(mcp: float, pip: float, spread: float, thumb: tuple[float, float, float, float]) -> np.ndarray:
    """A 16-channel pose with all four fingers alike; ``spread`` in [0, 1] fans them out."""
    p = np.zeros(NUM_CHANNELS)
    p[MCP], p[PIP] = mcp, pip
    p[ABD] = ABD_CLOSED_4 + spread * ABD_SPREAD_FAN_4
    p[T_CMC_FLEX:] = thumb
    return p


# Reference poses the actions interpolate between (degrees).
RELAXED = base_pose(25, 30, 0.2, (10, 20, 10, 10))
FLAT = base_pose(0, 0, 0.1, (0, 10, 0, 0))
SPREAD = base_pose(-5, 0, 1.0, (-12, 5, 0, -5))
FIST = base_pose(85, 100, 0.0, (50, 5, 40, 40))  # thumb folded over the middle phalanges
CLAW = base_pose(-10, 90, 0.5, (10, 40, 30, 40))
GRASP = base_pose(50, 55, 0.3, (30, 50, 15, 15))  # wraps a ~4 cm cylinder


@lru_cache(maxsize=None)
def pinch_pose(finger: int, others_flat: bool = False) -> np.ndarray:
    """A pose whose thumb tip meets the tip of ``finger`` (0 = index … 3 = pinky).

    The other fingers are relaxed, or straight and spread when ``others_flat`` (the OK sign); they
    matter because the neighbour coupling pulls the pinching finger toward them.
    Found once by a coarse-to-fine grid search on the unscaled hand, with the neighbour coupling
    applied, so the contact comes from the FK geometry rather than from a hand-written pose.
    Among the poses within 4 mm, the one closest to a natural pinch is taken.
    """
    geom = hand_geometry(np.ones(1), np.zeros((1, 5, 3)))
    tip_f = sk.CHAINS[("index", "middle", "ring", "pinky")[finger]][4]
    prior = np.array([45.0, 50.0, 25.0, 45.0, 15.0, 20.0])  # mcp, pip, cmc_flex, cmc_abd, t_mcp, t_ip
    lo = np.array([0.0, 0.0, -10.0, 0.0, -10.0, -15.0])
    hi = np.array([85.0, 100.0, 55.0, 70.0, 60.0, 75.0])
    center, width = 0.5 * (lo + hi), 0.5 * (hi - lo)
    best = None
    for _ in range(6):
        axes = [np.clip(np.linspace(c - w, c + w, 5), l, h) for c, w, l, h in zip(center, width, lo, hi)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 6)
        pose = np.tile(SPREAD if others_flat else RELAXED, (len(grid), 1))
        pose[:, MCP.start + finger], pose[:, PIP.start + finger] = grid[:, 0], grid[:, 1]
        pose[:, T_CMC_FLEX:] = grid[:, 2:]
        j = hand_fk(couple_neighbours(pose), geom)
        d = np.linalg.norm(j[:, 16] - j[:, tip_f], axis=-1)
        cost = np.maximum(d - 0.004, 0.0) * 1e3 + 1e-3 * np.abs(grid - prior).sum(1)
        k = int(np.argmin(cost))
        best = pose[k]
        center, width = grid[k], width / 2.0
    best.setflags(write=False)  # cached and shared: callers must copy before editing
    return best
