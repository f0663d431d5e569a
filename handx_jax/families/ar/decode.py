"""Decoding the prefix LM: one jitted ``lax.while_loop`` with a KV cache (reference §4.6), then tokens →
FSQ decoder → 288-d → de-normalised → global joints (§2.4 inverse).

- Prefill: the text prefix (and, for motion prediction, the observed motion tokens) in one forward
  pass that writes every layer's keys/values into a cache of Lp + 30 slots.
- Each step samples the next token from the last logits (greedy = argmax, the paper's default; or
  temperature / top-k / top-p), feeds it at the next slot, and stops when every row has produced END
  or 30 tokens exist (the reference drops a 31st token, so at most 30 remain).
- ``use_cache=False`` recomputes the whole sequence every step: the same tokens, used as the test
  oracle and as the no-cache benchmark.

Rows that end early keep PAD after END. To decode them to 60 frames, the tokens after END repeat the
last code (the pose is held: §4.8 pads the joints to 60 frames); a row that produced END first decodes
from code 1, as the reference returns the single id 1 (§4.6).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache, partial

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.models.prefix_lm import MOTION_TOKENS, PrefixLM, attention_mask, slot_positions, text_lengths
from handx_jax.infra.xla_options import jit_inference


@partial(jax.tree_util.register_dataclass, data_fields=["temperature", "top_k", "top_p", "guidance"],
         meta_fields=["max_tokens"])
@dataclass(frozen=True)
class DecodeOptions:
    """Sampling settings. They are traced values inside the jitted loop, so changing them does not
    recompile; only ``max_tokens`` is static (and whether guidance is on: :func:`decode`)."""

    temperature: float = 0.0  # 0 = greedy (paper default)
    top_k: int = 0  # 0 = off
    top_p: float = 1.0  # 1 = off
    # Classifier-free guidance on the logits, l = l_c + (s − 1)·(l_c − l_u) = l_u + s·(l_c − l_u), with l_u
    # the logits after the null prefix (:func:`null_prefix`; a run trained with ``data.text_drop`` > 0 has
    # learnt it). 1 = off, the reference's decoding (§4.6 has no guidance); written so that 1 is l_c exactly.
    guidance: float = 1.0
    max_tokens: int = MOTION_TOKENS

    def __post_init__(self) -> None:
        """Range checks, here so that every way in (``handx generate`` flags, a run's ``sample.*``, the API)
        gets them: out of range, the loop would sample something else silently (a negative temperature was
        greedy, top-p 1.5 no cut). JAX rebuilds this class with tracers or placeholders as fields; only
        concrete numbers are checked."""
        t, k, p = self.temperature, self.top_k, self.top_p
        if _number(t) and not (math.isfinite(t) and t >= 0):
            raise ValueError(f"temperature (--temperature) must be a finite number >= 0 (0 = greedy), got {t}")
        if _number(k) and not (k >= 0 and k == int(k)):
            raise ValueError(f"top_k (--top-k) must be a whole number >= 0 (0 = off), got {k}")
        if _number(p) and not 0 < p <= 1:
            raise ValueError(f"top_p (--top-p) must be in (0, 1] (1 = off), got {p}")
        g = self.guidance
        if _number(g) and not (math.isfinite(g) and g >= 0):
            raise ValueError(f"guidance (--guidance) must be a finite number >= 0 (1 = off), got {g}")


def _number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def sample_logits(logits_BxV, rng, opts: DecodeOptions, rows_B=None):
    """Greedy when temperature ≤ 0; else sample from softmax(logits / T) restricted to the top-k and
    then to the smallest set of tokens whose probability reaches top-p (always at least one).

    Row b draws with its own key, ``fold_in(rng, rows_B[b])`` (default: its index), so a row's draw does
    not depend on which other rows share its batch, and a batch split over devices (``hostdevices``)
    draws what the whole batch draws.

    The options are traced (no recompiling per setting), so the choice is a ``lax.cond`` that runs
    one branch: greedy decoding, the paper's default (§4.6), is the argmax alone, and plain temperature
    sampling skips the top-k/top-p cuts (:func:`_top_k_top_p`). Computing every branch and
    selecting afterwards made KV-cache decoding 5× slower (small LM, 4,375 codes: 1,005 against
    5,000+ tokens/s, docs/results/perf_cpu.json, decode_branches_2026_11_25)."""

    def greedy():
        return jnp.argmax(logits_BxV, axis=-1).astype(jnp.int32)

    def draw():
        lg = _top_k_top_p(logits_BxV / jnp.maximum(opts.temperature, 1e-6), opts)
        rows = jnp.arange(lg.shape[0]) if rows_B is None else rows_B
        keys = jax.vmap(lambda r: jax.random.fold_in(rng, r))(rows)
        return jax.vmap(jax.random.categorical)(keys, lg).astype(jnp.int32)

    return jax.lax.cond(opts.temperature <= 0, greedy, draw)


def _top_k_top_p(lg_BxV, opts: DecodeOptions):
    """Logits outside the top-k, then outside the top-p nucleus, set to −inf (each cut skipped by a
    ``lax.cond`` when its option is off).

    A token stays in the top-k when fewer than k logits exceed it, and in the nucleus when the
    probability mass of the tokens above it (after top-k) is below top-p: the sorted-cumsum definition,
    ties kept together, at least the argmax. Each cut is the smallest logit passing its test, found by
    bisection over the 2³² ordered float32 bit patterns (32 masked reductions over the vocabulary)
    instead of a sort: XLA CPU sorts a (16, 4,375) block in ~10.6 ms, the decoding step's bulk."""
    key = _ordered_key(lg_BxV)
    none = jnp.zeros(key.shape[:-1], jnp.uint32)  # a cut that keeps every token
    k = jnp.minimum(opts.top_k, lg_BxV.shape[-1])
    cut_k = jax.lax.cond(opts.top_k > 0, lambda: _smallest_passing(key, lambda u: jnp.sum(key > u[:, None], -1) < k),
                         lambda: none)
    lg = jnp.where(key >= cut_k[:, None], lg_BxV, -jnp.inf)

    def nucleus():
        p = jax.nn.softmax(lg, axis=-1)
        return _smallest_passing(key, lambda u: jnp.sum(jnp.where(key > u[:, None], p, 0.0), -1) < opts.top_p)

    cut_p = jax.lax.cond(opts.top_p < 1, nucleus, lambda: none)
    return jnp.where(key >= cut_p[:, None], lg, -jnp.inf)


def _ordered_key(x):
    """float32 → uint32 with the same order (negative floats' magnitude bits flipped, sign bit set for ≥ 0)."""
    i = jax.lax.bitcast_convert_type(x.astype(jnp.float32), jnp.uint32)
    return jnp.where(i >> 31 == 1, ~i, i | jnp.uint32(0x80000000))


def _smallest_passing(key_BxV, passes):
    """Per row, the smallest u (uint32) with ``passes(u)`` true, for a test that is false at 0 and, once
    true, stays true for every larger u; the row's largest key must pass."""
    lo = jnp.zeros(key_BxV.shape[:-1], jnp.uint32)
    hi = jnp.max(key_BxV, axis=-1)

    def step(_, bounds):
        lo, hi = bounds
        mid = lo + (hi - lo) // 2
        ok = passes(mid)
        return jnp.where(ok, lo, mid), jnp.where(ok, mid, hi)

    return jax.lax.fori_loop(0, 32, step, (lo, hi))[1]


def _empty_cache(model: PrefixLM, B: int, S: int, dtype):
    c = model.cfg
    z = jnp.zeros((B, S, c.heads, c.dim // c.heads), dtype)
    return [(z, z) for _ in range(c.layers)]


def _prefill(m: PrefixLM, text, text_mask, observed, cache, S):
    """Forward over [text | observed] writing the cache; returns (logits of the next token, cache)."""
    Lp, n_obs = text_mask.shape[1], observed.shape[1]
    P = Lp + n_obs
    x = m.embed_text(text)
    if n_obs:
        x = jnp.concatenate([x, m.embed_tokens(observed)], axis=1)
    pos = slot_positions(text_mask, S)[:, :P]
    h, cache = m.hidden(x, pos, attention_mask(text_mask, jnp.arange(P), S), cache, 0)
    if n_obs:
        last = h[:, -1]
    else:
        last = jnp.take_along_axis(h, (text_lengths(text_mask) - 1)[:, None, None], axis=1)[:, 0]
    return m.logits(last), cache


def _extend(m: PrefixLM, tok_B, i, text_mask, cache, S):
    """Feed motion token i at slot Lp + i (position ℓ + i); returns (next logits, cache)."""
    Lp = text_mask.shape[1]
    slot = Lp + i
    pos = (text_lengths(text_mask) + i)[:, None]
    mask = attention_mask(text_mask, slot[None], S)
    h, cache = m.hidden(m.embed_tokens(tok_B[:, None]), pos, mask, cache, slot)
    return m.logits(h[:, 0]), cache


def _full(m: PrefixLM, text, text_mask, tokens_BxT, i):
    """No cache: the whole [text | tokens] sequence, logits of the state predicting token i."""
    Lp = text_mask.shape[1]
    S = Lp + tokens_BxT.shape[1]
    x = jnp.concatenate([m.embed_text(text), m.embed_tokens(tokens_BxT)], axis=1)
    h, _ = m.hidden(x, slot_positions(text_mask, S), attention_mask(text_mask, jnp.arange(S), S))
    idx = jnp.where(i == 0, text_lengths(text_mask) - 1, Lp + i - 1)
    return m.logits(jnp.take_along_axis(h, idx[:, None, None], axis=1)[:, 0])


def decode(model: PrefixLM, params, text_BxLxDt, text_mask_BxL, observed_BxO, rng, opts: DecodeOptions = DecodeOptions(),
           use_cache: bool = True, guided: bool | None = None):
    """Generate motion tokens after the prefix (and the O observed tokens, O may be 0).

    Returns (tokens (B, max_tokens) int32 with the observed ones first and PAD after END, lengths (B,):
    the number of codes before END). With classifier-free guidance (``opts.guidance`` != 1, or ``guided``)
    every row also runs after the null prefix and draws from :func:`guide`'s logits. One jitted ``while_loop``, compiled with the inference options
    (``xla_options``; for 8L-512 1.06× on CPU). Where the host has several CPU devices (``hostdevices``)
    the rows are split over them, each device running its own loop: the same tokens (sampling draws per
    row, :func:`sample_logits`); greedy decoding of the small LM 1.10-1.19× faster at batch 16 on 2 cores.
    """
    from handx_jax.infra import hostdevices

    mesh = hostdevices.inference_mesh(text_mask_BxL.shape[0])
    inputs = (params, text_BxLxDt, text_mask_BxL, observed_BxO, rng, opts)
    if mesh is not None:
        inputs = hostdevices.replicate(mesh, inputs)
    # Guidance doubles the rows (conditional | null prefix), so whether it is on is static (``guided``;
    # None: on unless the scale is 1); its scale is traced. A traced scale counts as on.
    if guided is None:
        guided = not (_number(opts.guidance) and opts.guidance == 1)
    return _decode_jit(model.cfg.dim, mesh)(model, *inputs, use_cache, guided)


@cache
def _decode_jit(width: int, mesh):
    # built on first use, not at import: the options depend on the backend, which must not start at import
    fn = _decode_impl if mesh is None else partial(_decode_split, mesh=mesh)
    return jit_inference(fn, width, static_argnames=("model", "use_cache", "guided"))


def null_prefix(text_BxLxDt, text_mask_BxL):
    """The unconditional input (training's ``data.text_drop``, guidance's l_u): the same shapes with only
    the first slot valid and zero, which the text projection maps to its bias, a learnt "no text" vector.
    Motion slot k then sits at RoPE position 1 + k, in training and decoding alike."""
    first = jnp.arange(text_mask_BxL.shape[1])[None] == 0
    return jnp.zeros_like(text_BxLxDt), jnp.broadcast_to(first, text_mask_BxL.shape)


def guide(logits_2BxV, scale):
    """l_c + (s − 1)·(l_c − l_u) over rows [conditional | unconditional] → (B, V)."""
    B = logits_2BxV.shape[0] // 2
    lc, lu = logits_2BxV[:B], logits_2BxV[B:]
    return lc + (scale - 1) * (lc - lu)


def _decode_split(model: PrefixLM, params, text_BxLxDt, text_mask_BxL, observed_BxO, rng, opts: DecodeOptions,
                  use_cache: bool, guided: bool = False, *, mesh):
    """:func:`_decode_impl` with the rows split over ``mesh``: every device decodes its slice in its own
    ``while_loop`` (no communication; each stops when its own rows are done)."""
    from jax.sharding import PartitionSpec as P

    def body(params, text, mask, observed, rng, opts):
        row0 = jax.lax.axis_index("b") * text.shape[0]  # the slice's first row in the whole batch
        return _decode_impl(model, params, text, mask, observed, rng, opts, use_cache, guided, row0=row0)

    rows = P("b")
    # check_vma off: the loop's carry mixes per-device rows with the replicated key and step counter
    return jax.shard_map(body, mesh=mesh, in_specs=(P(), rows, rows, rows, P(), P()), out_specs=(rows, rows),
                         check_vma=False)(params, text_BxLxDt, text_mask_BxL, observed_BxO, rng, opts)


def _decode_impl(model: PrefixLM, params, text_BxLxDt, text_mask_BxL, observed_BxO, rng, opts: DecodeOptions,
                 use_cache: bool, guided: bool = False, row0=0):
    c, T = model.cfg, opts.max_tokens
    B, Lp = text_mask_BxL.shape
    rows_B = row0 + jnp.arange(B)
    n_obs = observed_BxO.shape[1]
    S = Lp + T
    tokens = jnp.full((B, T), c.pad_id, jnp.int32).at[:, :n_obs].set(observed_BxO.astype(jnp.int32))
    text, mask, observed = text_BxLxDt, text_mask_BxL, observed_BxO
    both = lambda x: x  # noqa: E731  the rows the model runs on: B, or [conditional | null] 2B when guided
    if guided:
        nt, nm = null_prefix(text, mask)
        both = lambda x: jnp.concatenate([x, x])  # noqa: E731
        text, mask, observed = jnp.concatenate([text, nt]), jnp.concatenate([mask, nm]), both(observed)
    pick = (lambda lg: guide(lg, opts.guidance)) if guided else (lambda lg: lg)  # noqa: E731
    run = lambda f, *a: model.apply(params, *a, method=f)  # noqa: E731
    if use_cache:
        dtype = jax.tree_util.tree_leaves(params)[0].dtype
        logits, cache = run(lambda m, *a: _prefill(m, *a, S), text, mask, observed,
                            _empty_cache(model, mask.shape[0], S, dtype))
    else:
        cache = None
        logits = run(_full, text, mask, both(tokens), jnp.full((mask.shape[0],), n_obs))

    def cond(s):
        i, _, done, *_ = s
        return (i < T) & ~jnp.all(done)

    def body(s):
        i, toks, done, cache, logits, rng = s
        rng, sub = jax.random.split(rng)
        tok = jnp.where(done, c.pad_id, sample_logits(pick(logits), sub, opts, rows_B))
        toks = toks.at[:, i].set(tok)
        done = done | (tok == c.end_id)
        if use_cache:
            logits, cache = run(lambda m, *a: _extend(m, *a, S), both(tok), i, mask, cache)
        else:
            logits = run(_full, text, mask, both(toks), jnp.full((mask.shape[0],), i + 1))
        return i + 1, toks, done, cache, logits, rng

    state = (jnp.asarray(n_obs, jnp.int32), tokens, jnp.zeros((B,), bool), cache, logits, rng)
    _, tokens, *_ = jax.lax.while_loop(cond, body, state)
    lengths = jnp.argmax(tokens >= c.nb_code, axis=1)  # first END/PAD
    lengths = jnp.where(jnp.any(tokens >= c.nb_code, axis=1), lengths, T)
    return tokens, lengths.astype(jnp.int32)


def fill_for_decoding(tokens_BxT, lengths_B, nb_code: int) -> np.ndarray:
    """Codes for the FSQ decoder: tokens after END repeat the last code; an empty row is code 1 (§4.6)."""
    tok = np.asarray(tokens_BxT).copy()
    for b, n in enumerate(np.asarray(lengths_B)):
        tok[b, n:] = tok[b, n - 1] if n > 0 else 1
    return np.clip(tok, 0, nb_code - 1)


def tokens_to_joints(tokenizer, tok_params, tokens_BxT, lengths_B, norm) -> np.ndarray:
    """Codes → FSQ decoder → normalised 288-d → de-normalised (``norm``: representation.NormStats)
    → global joints ``(B, 2·T, 2, 21, 3)`` (right wrist of frame 0 at the origin, §2.4 inverse)."""
    from handx_jax.representation import ar_to_joints

    codes = fill_for_decoding(tokens_BxT, lengths_B, tokenizer.cfg.nb_code)
    x_n = np.asarray(_decode_codes(tokenizer, tok_params, jnp.asarray(codes)))
    return ar_to_joints(norm.denormalize(x_n.astype(np.float64)).astype(np.float32))


@partial(jax.jit, static_argnames=("tokenizer",))
def _decode_codes(tokenizer, tok_params, codes):
    return tokenizer.apply(tok_params, codes, method=tokenizer.decode)
