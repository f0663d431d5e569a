import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from handx_jax.families.ar import decode as AD
from handx_jax.models import prefix_lm as P
from tests.random_params import random_params

TINY = dataclasses.replace(P.PRESETS["tiny"], nb_code=37, text_dim=24)
# XLA compiling the tiny LM's programs is most of this file's CPU (1-5 s per program: a forward, a gradient,
# a decoding loop), so the tests share one model, one set of parameters (host-drawn: no ``init`` to compile)
# and the batch shapes (B, L) = (4, 6) or (3, 6): each program compiles once, and in a later session comes
# from the persistent compilation cache (tests/conftest.py).
MODEL = P.PrefixLM(TINY)
APPLY = jax.jit(MODEL.apply)  # the training forward, (4, 6) text slots and 31 motion slots below


@functools.cache
def _params():
    """Host-drawn weights (tests/random_params.py): what these tests check holds for any weights, and
    compiling ``init`` would cost ~3 CPU-s."""
    return random_params(lambda r: P.init_lm(TINY, r)[1], 3, scale=0.3)


def _loss(params, text, mask, codes):
    return P.lm_loss(MODEL, params, text, mask, codes)[0]


# loss and gradients w.r.t. (params, text) at (B, L, N) = (3, 6, 30)
LOSS_AND_GRAD = jax.jit(jax.value_and_grad(_loss, argnums=(0, 1)))
# categorical draws of one (1, V) row for a batch of keys, the options traced (one program for every setting)
DRAW = jax.jit(jax.vmap(AD.sample_logits, in_axes=(None, 0, None)))


@pytest.mark.parametrize("preset,nb_code,expected", [
    ("8L-512", 1920, 29_633_024), ("8L-512", 4375, 32_146_944),
    ("12L-768", 4375, 92_266_752), ("16L-1024", 4375, 215_305_216)])
def test_param_counts_reproduce_table_c(preset, nb_code, expected):
    cfg = dataclasses.replace(P.PRESETS[preset], nb_code=nb_code, text_dim=768)
    n = P.param_counts(cfg)
    assert n["params"] == expected  # Table C: 29.63M, 92.27M, 215.31M (reference §4.5)
    assert n["params"] - n["params_non_embedding"] == (nb_code + 2) * cfg.dim


def test_swiglu_hidden_rule():
    assert [P.PRESETS[k].hidden for k in ("8L-512", "12L-768", "16L-1024")] == [1536, 2048, 2816]


def test_rope_rotates_adjacent_pairs_and_is_relative():
    x = jnp.zeros((1, 1, 1, 8)).at[..., 0].set(1.0)
    out = P.rope(x, jnp.asarray([[2.0]]), 10000.0)
    np.testing.assert_allclose(out[0, 0, 0, :2], [np.cos(2.0), np.sin(2.0)], atol=1e-6)  # pair (x0, x1)
    np.testing.assert_allclose(out[0, 0, 0, 2:], 0.0)
    r = np.random.default_rng(0)
    q, k = (jnp.asarray(r.normal(size=(1, 1, 1, 8)), jnp.float32) for _ in range(2))
    dot = lambda a, b: float((P.rope(q, jnp.asarray([[a]]), 1e4) * P.rope(k, jnp.asarray([[b]]), 1e4)).sum())  # noqa: E731
    assert dot(7.0, 3.0) == pytest.approx(dot(24.0, 20.0), rel=1e-5)


def _batch(B=3, L=6, M=31, seed=0, cfg=TINY):
    r = np.random.default_rng(seed)
    text = jnp.asarray(r.normal(size=(B, L, cfg.text_dim)), jnp.float32)
    lens = np.array([L, 3, 1, 5, 2, 4][:B])
    mask = jnp.asarray(np.arange(L)[None] < lens[:, None])
    toks = jnp.asarray(r.integers(0, cfg.nb_code, size=(B, M)), jnp.int32)
    return text, mask, toks


def test_causal_over_motion_and_prefix_fully_visible():
    params = _params()
    text, mask, toks = _batch(B=2)
    Lp = text.shape[1]

    def probe(params, x_text, x_tok, t, b, motion):
        """Row b's logits at motion slot t (``motion``), else row b's state at its FIRST text slot: one
        program for both gradients (the branch not taken contributes exact zeros)."""
        m = MODEL.bind(params)
        x = jnp.concatenate([m.embed_text(x_text), x_tok], axis=1)
        S = x.shape[1]
        h, _ = m.hidden(x, P.slot_positions(mask, S), P.attention_mask(mask, jnp.arange(S), S))
        return jnp.where(motion, m.logits(h[b, Lp + t]).sum(), h[b, 0].sum())

    x_tok = MODEL.apply(params, toks, method=lambda m, t: m.embed_tokens(t))
    grad = jax.jit(jax.grad(probe, argnums=(1, 2)))
    for b, valid in ((0, 6), (1, 3)):
        for t in (0, 7, 29):
            g_text, g_tok = grad(params, text, x_tok, t, b, True)
            assert np.all(np.asarray(g_tok[b, t + 1:]) == 0.0)  # exactly zero after t
            assert np.all(np.abs(np.asarray(g_tok[b, : t + 1])).sum(-1) > 0)
            assert np.all(np.abs(np.asarray(g_text[b, :valid])).sum(-1) > 0)  # every prefix token
            assert np.all(np.asarray(g_text[b, valid:]) == 0.0)  # padded text slots are never keys
            assert np.all(np.asarray(g_text[1 - b]) == 0.0)  # no leak across the batch

    # Bidirectional prefix: the FIRST text slot's state depends on the last valid text token (and on every
    # other one), and on no motion slot.
    g_text, g_tok = grad(params, text, x_tok, 0, 0, False)
    assert np.abs(np.asarray(g_text[0, 5])).sum() > 0
    assert np.all(np.abs(np.asarray(g_text[0])).sum(-1) > 0) and np.all(np.asarray(g_tok) == 0.0)


def test_padding_matches_the_packed_sequence():
    """A prompt padded to 6 slots gives the logits of the same prompt with no padding (positions run
    ℓ, ℓ+1, … after the prefix, as the reference's packed rows)."""
    params = _params()
    text, mask, toks = _batch(B=4, seed=5)  # row 1: 3 valid text tokens
    full = APPLY(params, text, mask, toks)
    short = APPLY(params, text[1:2, :3], mask[1:2, :3], toks[1:2])
    np.testing.assert_allclose(full[1], short[0], atol=2e-5)


def test_loss_is_log_vocab_with_zero_head_and_targets_end():
    params = jax.tree_util.tree_map(lambda x: x, _params())
    params["params"]["head"]["kernel"] = jnp.zeros_like(params["params"]["head"]["kernel"])
    text, mask, toks = _batch(M=30)
    loss, _ = LOSS_AND_GRAD(params, text, mask, toks)  # the program of the backward-pass test below
    assert float(loss) == pytest.approx(np.log(TINY.nb_code + 1), rel=1e-6)


def test_flops_match_xla():
    cfg = dataclasses.replace(TINY, layers=2, dim=128, heads=4, nb_code=300, text_dim=96)
    model = P.PrefixLM(cfg)
    # the parameters' shapes are all XLA's cost analysis needs (compiling ``init`` would cost more than the test)
    params = jax.eval_shape(lambda r: P.init_lm(cfg, r)[1], jax.random.PRNGKey(0))
    text, mask, toks = _batch(B=1, L=16, cfg=cfg)
    cost = jax.jit(lambda p, a, b, c: model.apply(p, a, b, c)).lower(params, text, mask, toks).compile().cost_analysis()
    xla = (cost[0] if isinstance(cost, list) else cost)["flops"]
    ours = P.forward_flops(cfg, 16)
    assert abs(ours - xla) / xla < 0.10, (ours, xla)


def test_kv_cache_decoding_equals_full_recompute():
    params = _params()
    text, mask, _ = _batch(B=4, seed=5)
    empty = jnp.zeros((4, 0), jnp.int32)
    a, la = AD.decode(MODEL, params, text, mask, empty, jax.random.PRNGKey(0))
    b, lb = AD.decode(MODEL, params, text, mask, empty, jax.random.PRNGKey(0), use_cache=False)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(la, lb)
    assert len({tuple(r) for r in np.asarray(a).tolist()}) == 4  # the prompts lead to different tokens
    # Each row is greedy w.r.t. the full forward: the training forward's argmax reproduces every row's codes
    # and its END (the PAD slots after END cannot change earlier predictions: causal).
    lg = APPLY(params, text, mask, jnp.concatenate([a, jnp.full((4, 1), TINY.pad_id, a.dtype)], axis=1))
    pred = np.asarray(lg.argmax(-1))
    for r, n in enumerate(np.asarray(la).tolist()):
        upto = min(n + 1, 30)  # the codes, then END where the row ended before 30 codes
        np.testing.assert_array_equal(pred[r, :upto], np.asarray(a[r, :upto]))
        assert n == 30 or int(a[r, n]) == TINY.end_id
    # Motion prediction: observed tokens are prefilled and kept, and the cached continuation is the
    # full-recompute sequence b (b's first 5 tokens are these, and greedy decoding continues them as b did).
    obs = a[:, :5]
    c, lc = AD.decode(MODEL, params, text, mask, obs, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(c[:, :5], obs)
    np.testing.assert_array_equal(c, b)
    np.testing.assert_array_equal(lc, lb)


def test_sampling_options():
    params = _params()
    text, mask, _ = _batch(B=4, seed=5)  # the shapes of the test above: its compiled loop is reused
    empty = jnp.zeros((4, 0), jnp.int32)
    greedy, _ = AD.decode(MODEL, params, text, mask, empty, jax.random.PRNGKey(0))
    k1, _ = AD.decode(MODEL, params, text, mask, empty, jax.random.PRNGKey(9), AD.DecodeOptions(1.0, top_k=1))
    np.testing.assert_array_equal(k1, greedy)  # top-1 sampling is greedy
    p0, _ = AD.decode(MODEL, params, text, mask, empty, jax.random.PRNGKey(9), AD.DecodeOptions(1.0, top_p=1e-6))
    np.testing.assert_array_equal(p0, greedy)  # a tiny nucleus keeps only the argmax
    s1, _ = AD.decode(MODEL, params, text, mask, empty, jax.random.PRNGKey(1), AD.DecodeOptions(1.0))
    s2, _ = AD.decode(MODEL, params, text, mask, empty, jax.random.PRNGKey(2), AD.DecodeOptions(1.0))
    assert not np.array_equal(s1, s2)
    lg = jnp.log(jnp.asarray([[0.5, 0.3, 0.15, 0.05]], jnp.float32))
    draws = DRAW(lg, jax.random.split(jax.random.PRNGKey(0), 8000), AD.DecodeOptions(1.0, top_p=0.7))
    assert set(np.unique(np.asarray(draws))) == {0, 1}  # 0.5 + 0.3 reaches 0.7


def _top_k_top_p_by_sorting(lg, top_k, top_p):
    """The sorted-cumsum definition in numpy: the reference for the bisection in ``families.ar.decode``."""
    out = lg.copy()
    for row in out:
        srt = np.sort(row)[::-1]
        k = min(top_k, row.size) if top_k > 0 else row.size
        row[row < srt[k - 1]] = -np.inf
        srt = np.where(srt < srt[k - 1], -np.inf, srt)
        e = np.exp(srt - srt[0])
        probs = e / e.sum()
        keep = int(np.sum(np.cumsum(probs) - probs < top_p)) if top_p < 1 else row.size
        row[row < srt[max(keep, 1) - 1]] = -np.inf
    return out


_CUTS = jax.jit(AD._top_k_top_p)  # the options traced, as in the decoding loop: one program for every case


@pytest.mark.parametrize("top_k,top_p", [(0, 0.9), (50, 1.0), (7, 0.5), (1, 1.0), (0, 1e-6), (3000, 0.999)])
def test_top_k_top_p_cuts_equal_the_sorted_definition(top_k, top_p):
    r = np.random.default_rng(top_k + int(1000 * top_p))
    lg = (r.normal(size=(6, 4375)) * r.uniform(0.5, 4, size=(6, 1))).astype(np.float32)
    lg[0, :40] = lg[0, 40]  # ties, at and around the cuts
    lg[1, ::3] = -np.inf  # masked codes
    lg[2] = np.round(lg[2])
    got = np.asarray(_CUTS(jnp.asarray(lg), AD.DecodeOptions(1.0, top_k=top_k, top_p=top_p)))
    want = _top_k_top_p_by_sorting(lg, top_k, top_p)
    kept, kept_ref = np.isfinite(got), np.isfinite(want)
    np.testing.assert_array_equal(got[kept], lg[kept])  # kept logits unchanged
    assert kept.sum(axis=1).min() >= 1
    # Identical but where float32 summation order decides: a token whose mass above (after top-k, in
    # float64) is within 1e-5 of top-p.
    for b, i in zip(*np.nonzero(kept != kept_ref)):
        after_k = _top_k_top_p_by_sorting(lg[b:b + 1], top_k, 1.0)[0].astype(np.float64)
        p = np.exp(after_k - after_k.max())
        p /= p.sum()
        assert abs(p[after_k > lg[b, i]].sum() - top_p) < 1e-5, (b, i)
    assert (kept != kept_ref).sum() <= 2


def test_top_p_zero_is_refused_not_treated_as_top_1():
    # top-p 0 keeps nothing by its definition; the cut used to keep the top token silently (top_p=1e-6 does)
    with pytest.raises(ValueError, match=r"top_p \(--top-p\) must be in \(0, 1\]"):
        AD.DecodeOptions(1.0, top_p=0.0)


def test_greedy_step_does_not_sort_the_vocabulary():
    """With the options traced (as every caller that passes them traces them), the top-k/top-p cuts
    and the categorical draw sit inside ``cond`` branches, not on the greedy step's path:
    computing them every step and selecting made KV-cache decoding 5x slower (perf_cpu.json)."""
    lg = jnp.zeros((2, 50))
    jaxpr = jax.make_jaxpr(lambda o: AD.sample_logits(lg, jax.random.PRNGKey(0), o))(AD.DecodeOptions(0.0)).jaxpr
    top = [e.primitive.name for e in jaxpr.eqns]
    assert "cond" in top and not {"sort", "while", "scan", "argmax"} & set(top), top

    def prims(jx):
        for e in jx.eqns:
            yield e.primitive.name
            for p in e.params.values():
                for sub in (p if isinstance(p, (list, tuple)) else [p]):
                    if hasattr(sub, "jaxpr"):
                        yield from prims(sub.jaxpr)
    inside = set(prims(jaxpr))
    assert "argmax" in inside and {"while", "scan"} & inside  # in the branches (the top-k/top-p bisection loop)


@pytest.mark.parametrize("temperature", [1.0, 0.5])
def test_temperature_sampling_follows_the_tempered_softmax(temperature):
    """Plain temperature sampling (no top-k/top-p: the branch that skips the vocabulary sort) draws
    from softmax(logits / T): p^(1/T) renormalised, here p = (0.5, 0.3, 0.15, 0.05)."""
    p = np.array([0.5, 0.3, 0.15, 0.05])
    want = p ** (1 / temperature) / np.sum(p ** (1 / temperature))
    lg = jnp.log(jnp.asarray([p], jnp.float32))
    n = 8000
    keys = jax.random.split(jax.random.PRNGKey(4), n)
    draws = np.asarray(DRAW(lg, keys, AD.DecodeOptions(temperature)))[:, 0]
    freq = np.bincount(draws, minlength=4) / n
    assert np.all(np.abs(freq - want) < 4 * np.sqrt(want * (1 - want) / n) + 1e-3), (freq, want)
    greedy = DRAW(lg, keys, AD.DecodeOptions(0.0))
    assert greedy.dtype == jnp.int32 and np.all(np.asarray(greedy) == 0)


def test_end_stops_and_rows_fill_for_decoding():
    tok = np.array([[5, 6, 37, 38], [37, 38, 38, 38], [1, 2, 3, 4]])
    filled = AD.fill_for_decoding(tok, np.array([2, 0, 4]), 37)
    np.testing.assert_array_equal(filled, [[5, 6, 6, 6], [1, 1, 1, 1], [1, 2, 3, 4]])


def test_hand_written_backward_passes_equal_autodiff(monkeypatch):
    """``attend`` and ``swiglu`` keep less for their backward pass than autodiff would (the AR memory fix);
    the loss is bit-identical and every gradient equals autodiff's up to float32 rounding."""
    import flax.linen as nn

    params = _params()
    text, mask, _ = _batch(B=3)
    codes = jnp.asarray(np.random.default_rng(1).integers(0, TINY.nb_code, size=(3, 30)), jnp.int32)
    l_new, (g_new, g_text) = LOSS_AND_GRAD(params, text, mask, codes)
    monkeypatch.setattr(P, "attend", lambda q, k, v, m: P.attend_reference(q, k, v, m)[0])
    monkeypatch.setattr(P, "swiglu", lambda a, b: nn.silu(a) * b)
    # a new trace (a new function for jit), so the patched formulations are the ones compiled
    l_ref, g_ref = jax.jit(jax.value_and_grad(_loss, argnums=(0, 1)))(params, text, mask, codes)
    assert float(l_new) == float(l_ref)
    for a, b in zip(jax.tree_util.tree_leaves((g_new, g_text)), jax.tree_util.tree_leaves(g_ref)):
        a, b = np.asarray(a), np.asarray(b)
        assert np.abs(a - b).max() <= 2e-6 * np.abs(b).max() and np.abs(b).max() > 0
    # padded text slots still get exactly zero gradient through the new attention backward
    assert np.all(np.asarray(g_text[1, 3:]) == 0.0) and np.abs(np.asarray(g_text[1, :3])).sum() > 0
