"""A differentiable contact energy on joints, for guiding a sampler toward named contacts (issue 33, item 2).

BimArt (§3.3, §3.5) steers each denoising step with the gradient of a contact term on the predicted clean
motion x̂0 and scales it by the gradient's norm (λ_c = 1 / ‖∇‖). Here the contacts are hand–hand ones, in
the vocabulary of the project's event records and of the contact-feasibility metric
(:data:`handx_jax.metrics.CONTACT_CHANNELS`): 8 intra-hand thumb-tip pairs, 25 left × right tip pairs, 10
tip → other palm (the mean of the k closest palm-cloud points, as annotation/descriptors.py measures it). A request
is a (T, 43) weight per frame and channel (1 where a named contact should hold, 0 elsewhere; see
:func:`request_from_named`), and the energy is the mean over requested (frame, channel) cells of the
squared amount by which the distance exceeds TARGET_FRACTION × the channel's contact threshold: zero once
every requested pair is in contact, so satisfied contacts are not pulled further together (into each other).

Sampling (``families/diffusion/sampling.py``): at every denoising step the clean prediction x̂0 (normalised,
after classifier-free guidance) is mapped to joints in metres (:func:`x0_to_joints`, the inverse z-score of
the diffusion features' xyz channels), and moved against the energy's gradient (:func:`make_steer`):

    x̂0 ← x̂0 − ℓ · ∇E / ‖∇E‖,   ℓ = min(s · w(t), 2E / ‖∇E‖)

per sample, in the normalised space the denoiser predicts in. The direction and the unit length are
BimArt's (Eq. 6 with λ_c = 1/‖∇X̂‖, §3.5); ``s`` is ``sample.contact_strength`` (1 = BimArt's step) and w(t)
the schedule (:data:`SCHEDULES`): "late" = √ᾱ_t, which is ~0 while x̂0 is still a blur of the data mean and
1 at the last steps, where the output is decided; "constant" = 1 at every step, BimArt's Eq. 6 as written.
The cap 2E/‖∇E‖ is the Gauss–Newton step that closes the gaps exactly when they are linear in x̂0 (for
one pair: gap/‖∇gap‖), so a nearly met contact is not overshot into the other hand. A satisfied request
has E = 0 and ∇E = 0: x̂0 is left bit-for-bit unchanged. Guidance off (no request) traces no guidance at
all: the compiled sampler is the unguided one. One unit step is spread over every requested cell, so
requests over many frames need s of several units: on make demo's run (docs/results/guidance) s = 4 / 16
realise 35% / 59% of the captions' inter-hand contacts (2.6% unguided), FID and top-3 unchanged within
their intervals, Pen 1cm 2.9% → 6.1% at s = 16 (the energy pulls requested pairs together; nothing keeps
the rest of the hands apart).

Where requests come from (``--contact`` / ``sample.contact``, :func:`parse_contacts`): the contact events
of the prompt's structured record (``caption``: :func:`request_from_named` of :func:`metrics.named_contacts`,
the events its captions were written from), or a list in the events' own vocabulary::

    SPEC    := "caption" | CONTACT ("," CONTACT)*
    CONTACT := SIDE "-" SIDE ["@" [START] ":" [END]]     frames, half-open, default the whole clip
    SIDE    := HAND "." PART       HAND: L | R | left | right
                                   PART: thumb | index | middle | ring | pinky | palm | tips (all five)

    L.thumb-R.index@20:40     left thumb tip touches the right index tip, frames 20–39
    L.index-R.palm@0:60       left index tip on the right palm (finger_palm_distance "contact")
    R.index-R.thumb@:30       a right-hand pinch (intra-hand thumb–finger contact)
    L.tips-R.tips             all fingertips of both hands meet (thumb–thumb, …, pinky–pinky)

Palm–palm is not a fingertip contact and has no channel (the metric's vocabulary, ``metrics.named_contacts``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import metrics as M
from handx_jax import skeleton as sk

SCHEDULES = ("late", "constant")
CAPTION = "caption"  # the spec that takes the prompt record's contact events

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


# ------------------------------------------------------------------------------------------------
# Requests from a written spec (``--contact``)

_HANDS = {"l": "left", "left": "left", "r": "right", "right": "right"}
_PARTS = (*sk.FINGER_NAMES, "palm", "tips")
SYNTAX = "HAND.PART-HAND.PART[@START:END], HAND L|R, PART thumb|index|middle|ring|pinky|palm|tips"


def _side(tok: str, contact: str) -> tuple[str, tuple[str, ...]]:
    hand, dot, part = tok.strip().partition(".")
    if not dot or hand.lower() not in _HANDS or part.lower() not in _PARTS:
        raise ValueError(f"contact {contact!r}: bad side {tok!r} (want {SYNTAX})")
    part = part.lower()
    return _HANDS[hand.lower()], (sk.FINGER_NAMES if part == "tips" else (part,))


def _channels(a: tuple[str, tuple[str, ...]], b: tuple[str, tuple[str, ...]], contact: str) -> list[int]:
    """The contact channels of one written pair (either order); ``tips`` against ``tips`` pairs the
    fingers one to one, against a single part it is each finger with that part."""
    (ha, pa), (hb, pb) = a, b
    if len(pa) == len(pb) == 5:
        pairs = list(zip(pa, pb))
    else:
        pairs = [(x, y) for x in pa for y in pb]
    out = []
    for x, y in pairs:
        (h1, f1), (h2, f2) = sorted([(ha, x), (hb, y)], key=lambda e: (e[1] == "palm", e[0]))
        if f1 == "palm":
            raise ValueError(f"contact {contact!r}: palm–palm is not a fingertip contact (no such channel)")
        if f2 == "palm":
            if h1 == h2:
                raise ValueError(f"contact {contact!r}: a fingertip touches the OTHER hand's palm")
            key = ("finger_palm_distance", f"{h1}_{f1}_tip, {h2}_palm")
        elif h1 != h2:
            key = ("finger_tip_contact", f"{h1}_{f1}_tip, {h2}_{f2}_tip")
        else:
            if "thumb" not in (f1, f2) or f1 == f2:
                raise ValueError(f"contact {contact!r}: within one hand only thumb–finger contacts are events")
            key = (f"{h1}_hand_events", f"{f1 if f2 == 'thumb' else f2}_tip, thumb_tip")
        out.append(M.CONTACT_CHANNELS[key])
    return out


def _frame(tok: str, contact: str) -> int | None:
    if not tok.strip():
        return None
    if not (tok.strip().isascii() and tok.strip().isdigit()):
        raise ValueError(f"contact {contact!r}: frame {tok!r} is not a non-negative integer")
    return int(tok)


CLIP_FRAMES = 60  # HandX clips (the default clip length every model here generates)


def parse_contacts(spec: str, frames: int = CLIP_FRAMES) -> list[tuple[int, int | None, int | None]]:
    """(channel, start, end) per requested contact of a written spec (module docstring); frames are
    half-open, None = the clip's start / end. The one check of a spec's frames: 0 <= START < END <=
    ``frames`` (a range past the clip is refused, not cut to it). Raises ValueError naming the bad token."""
    out = []
    for contact in spec.split(","):
        c = contact.strip()
        if not c:
            raise ValueError(f"contact spec {spec!r}: an empty contact (want {SYNTAX})")
        pair, at, rng = c.partition("@")
        sides = pair.split("-")
        if len(sides) != 2:
            raise ValueError(f"contact {c!r}: want two sides joined by '-' ({SYNTAX})")
        start = end = None
        if at:
            a, colon, b = rng.partition(":")
            if not colon:
                raise ValueError(f"contact {c!r}: frames {rng!r} want START:END (either may be left out)")
            start, end = _frame(a, c), _frame(b, c)
            if start is not None and end is not None and end <= start:
                raise ValueError(f"contact {c!r}: frames {rng!r} are empty (END must exceed START)")
            if (start is not None and start >= frames) or (end is not None and end > frames):
                raise ValueError(f"contact {c!r}: frames {rng!r} run past the clip's {frames} frames (START:END "
                                 f"within 0:{frames}, END excluded)")
        out += [(ch, start, end) for ch in _channels(_side(sides[0], c), _side(sides[1], c), c)]
    return out


def request_from_spec(spec: str, n: int, T: int) -> np.ndarray:
    """(n, T, 43) float32 request of a written spec, the same for all n samples."""
    out = np.zeros((n, T, M.N_CONTACT_CHANNELS), np.float32)
    for ch, s, e in parse_contacts(spec, T):
        out[:, 0 if s is None else s:T if e is None else e, ch] = 1.0
    return out


def check_named(named: M.NamedContacts, n: int, what: str = "prompt") -> None:
    """``--contact caption`` guides toward the contacts the records name: refuse when none of the ``n``
    records names one (nothing would be guided, yet the run would say it guides); when only some do, say how
    many are guided."""
    guided = len(set(np.asarray(named.clip_E).tolist()))
    if 0 < guided < n:  # a batch (--reference): the others are sampled unguided, and the user is told
        import sys

        print(f"handx: --contact caption guides {guided} of the {n} prompts; the records of the other {n - guided} "
              "name no contact", file=sys.stderr)
    if len(named) == 0:
        from handx_jax.infra.errors import DataError

        whose = "the prompt's record names no" if n == 1 else f"none of the {n} prompts' records names a"
        raise DataError(f"--contact caption: {whose} contact (no fingertip touch among the events its captions "
                        "were written from), so there is nothing to guide toward; give a written spec such as "
                        "L.thumb-R.thumb@20:40, or leave --contact off")


# ------------------------------------------------------------------------------------------------
# The guided step on x̂0 (inside the sampler's scan)


def x0_to_joints(x_BxFx42x4: jax.Array, mean_42x4, std_42x4) -> jax.Array:
    """Normalised diffusion features → clip-centred joints (B, F, 2, 21, 3) m, differentiably (the
    traced form of ``representation.diffusion_to_joints(norm.denormalize(x))``; the energy only uses
    differences of joints, so the clip's centre is not needed)."""
    xyz = x_BxFx42x4[..., :3] * jnp.asarray(std_42x4)[:, :3] + jnp.asarray(mean_42x4)[:, :3]
    return xyz.reshape(*x_BxFx42x4.shape[:-2], 2, sk.NUM_JOINTS, 3)


def schedule_weight(schedule: str, alpha_bar_t: jax.Array) -> jax.Array:
    """w(t) of the strength schedule (:data:`SCHEDULES`, module docstring)."""
    if schedule == "late":
        return jnp.sqrt(alpha_bar_t)
    if schedule == "constant":
        return jnp.ones_like(alpha_bar_t)
    raise ValueError(f"unknown contact schedule {schedule!r}; choose from {', '.join(SCHEDULES)}")


def guide_step(x0_BxS: jax.Array, energy_fn, length: jax.Array) -> jax.Array:
    """One guidance step per sample: x̂0 − min(length, 2E/‖∇E‖) · ∇E/‖∇E‖ (module docstring), where
    ``energy_fn`` maps x̂0 to the per-sample energy (B,). Samples with E = 0 are returned unchanged."""
    def total(x):
        e_B = energy_fn(x)
        return jnp.sum(e_B), e_B

    (_, e_B), g = jax.value_and_grad(total, has_aux=True)(x0_BxS)
    gn_B = jnp.sqrt(jnp.sum(g * g, axis=tuple(range(1, g.ndim))))
    safe = jnp.where(gn_B > 0, gn_B, 1.0)
    ell_B = jnp.where(gn_B > 0, jnp.minimum(length, 2.0 * e_B / safe), 0.0)
    return x0_BxS - (ell_B / safe).reshape((-1,) + (1,) * (g.ndim - 1)) * g


def make_steer(request_BxFxC, strength, schedule: str, alphas_cumprod_T, mean_42x4, std_42x4, palm_Px21=None):
    """``steer(x0_hat, t) -> x0_hat`` for ``process.sample``: one :func:`guide_step` of the contact energy of
    ``request_BxFxC`` at length ``strength`` · w(t). ``mean``/``std``: the run's diffusion normalisation
    (std + eps); ``request`` and ``strength`` may be traced (a new request does not recompile)."""
    ac_T = jnp.asarray(alphas_cumprod_T, jnp.float32)
    palm = jnp.asarray(M.palm_barycentric() if palm_Px21 is None else palm_Px21)

    def energy(x):
        return contact_energy(x0_to_joints(x, mean_42x4, std_42x4), request_BxFxC, palm)

    def steer(x0_hat, t):
        return guide_step(x0_hat, energy, strength * schedule_weight(schedule, ac_T[t]))

    return steer
