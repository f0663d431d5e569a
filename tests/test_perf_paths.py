"""The fast paths of issue 15 compute what the plain model computes.

- ``TrebleDenoiser.encode`` + ``denoise`` (text keys/values once per sample, one-token null memory for
  the unconditional rows) equal ``__call__`` with the text tiled and the drop flags set.
  With guidance's [x; x] batch, sharing the first self-attention block changes nothing.
- Attention's two layouts (forward-only heads-major matmuls, training einsums) are standard attention.
- Layer 0's self-attention from the tokens the three branches share equals attention over each full
  branch sequence, and the forward-only denoiser equals the training path's full branch stack.
- The compiled sampler's closure gives the samples of the closure that calls the full model.
- Hash dropout keeps 1 − rate of the elements, is a pure function of the seed, and scales by 1/(1 − rate).
- The erf form of exact GELU is exact GELU (values and gradients).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from handx_jax.families.diffusion import process as D
from handx_jax.families.diffusion.sampling import _sample_impl
from handx_jax.models.dit import NUM_BRANCHES
from handx_jax.models.layers import Attention, Dropout, gelu_erf, keep_mask
from tests.diffusion_fixtures import tiny_denoiser


def _text(cfg, B, L, seed=0):
    r = np.random.default_rng(seed)
    text = jnp.asarray(r.normal(size=(NUM_BRANCHES, B, L, cfg.text_dim)), jnp.float32)
    mask = jnp.asarray(np.arange(L)[None, None] < r.integers(2, L + 1, size=(NUM_BRANCHES, B, 1)))
    return text, mask


@pytest.fixture(scope="module")
def tiny():
    # Dropout 0 (tests/diffusion_fixtures.py tiny_denoiser): the training path (deterministic=False) then computes
    # what the forward-only path computes, so the tests below share one model and its compiled programs, every
    # array an argument (a captured array would be a constant of its program: each test would compile again).
    return tiny_denoiser()


def test_encode_denoise_equals_full_forward(tiny):
    cfg, model, params, jit = tiny
    B, L = 3, 8
    text, mask = _text(cfg, B, L)
    r = np.random.default_rng(1)
    x = jnp.asarray(r.normal(size=(B, cfg.frames, 42, 4)), jnp.float32)
    t = jnp.asarray([0, 400, 999])
    # each path compiled (as the sampler and the train step run them): eager dispatch costs seconds per call
    memory = jit.encode(params, text, mask)
    xx, tt = jnp.concatenate([x, x]), jnp.concatenate([t, t])
    both = jit.denoise(params, xx, tt, memory, B, False)
    cond = jit.full(params, x, t, text, mask, jnp.zeros((B, 3), bool), True)
    uncond = jit.full(params, x, t, text, mask, jnp.ones((B, 3), bool), True)
    np.testing.assert_allclose(both[:B], cond, atol=1e-5)
    np.testing.assert_allclose(both[B:], uncond, atol=1e-5)
    only_null = jit.denoise(params, x, t, None, B, False)
    np.testing.assert_allclose(only_null, uncond, atol=1e-5)
    assert not np.allclose(cond, uncond)
    # guidance's [x; x] batch: the first layer's self-attention block runs once and is copied
    shared = jit.denoise(params, xx, tt, memory, B, True)
    np.testing.assert_allclose(shared[:B], cond, atol=1e-5)
    np.testing.assert_allclose(shared[B:], uncond, atol=1e-5)
    with pytest.raises(ValueError, match="null_repeats needs as many null rows"):
        jit.denoise(params, jnp.concatenate([x, x[:1]]), jnp.concatenate([t, t[:1]]), memory, 1, True)


def test_attention_layouts_equal_a_numpy_reference():
    """Forward-only attention (heads-major matmuls) and the training path (einsums) compute standard
    multi-head attention: checked against numpy, with a key mask."""
    B, Q, M, D, H = 2, 5, 7, 16, 4
    r = np.random.default_rng(4)
    x = r.normal(size=(B, Q, D)).astype(np.float32)
    mem = r.normal(size=(B, M, D)).astype(np.float32)
    valid = np.arange(M)[None] < np.array([[7], [3]])  # the second sample sees 3 keys
    mask = jnp.asarray(valid[:, None, None, :])
    attn = Attention(D, H, dropout=0.0)
    params = jax.jit(lambda k, x: attn.init(k, x, deterministic=True))(jax.random.PRNGKey(0), jnp.asarray(x))
    p = jax.tree.map(np.asarray, params["params"])
    proj = lambda a, n: np.einsum("bsd,dhk->bshk", a, p[n]["kernel"]) + p[n]["bias"]  # noqa: E731
    q, k, v = proj(x, "query") / np.sqrt(D // H), proj(mem, "key"), proj(mem, "value")
    logits = np.einsum("bqhk,bmhk->bhqm", q, k)
    logits = np.where(valid[:, None, None, :], logits, -np.inf)
    w = np.exp(logits - logits.max(-1, keepdims=True))
    w /= w.sum(-1, keepdims=True)
    ref = np.einsum("bhqm,bmhk,hkd->bqd", w, v, p["out"]["kernel"]) + p["out"]["bias"]
    kv = jax.jit(lambda p, m: attn.apply(p, m, method=attn.kv))(params, jnp.asarray(mem))
    apply = jax.jit(lambda p, x, kv, mask, det: attn.apply(p, x, kv, mask, deterministic=det), static_argnums=4)
    for deterministic in (True, False):  # rate 0: the two differ only in layout
        got = apply(params, jnp.asarray(x), kv, mask, deterministic)
        np.testing.assert_allclose(got, ref, atol=1e-5, err_msg=f"deterministic={deterministic}")


@pytest.mark.parametrize("class_scale", [1.0, 40.0])
def test_branch_self_attention_equals_attention_on_each_branch_sequence(class_scale):
    """The shared-token form of layer 0's self-attention is attention over the K·N full sequences
    [h_n0, c_k, h_n1..]: with ordinary logits, and with branch tokens so large that their keys take
    (almost) all the weight, where a naive softmax-merge would overflow or lose the shared part."""
    N, S, D, H, K = 3, 6, 16, 4, 3
    r = np.random.default_rng(5)
    h = jnp.asarray(r.normal(size=(N, S, D)), jnp.float32)
    c = jnp.asarray(r.normal(size=(K, D)) * class_scale, jnp.float32)
    full = jnp.concatenate([jnp.broadcast_to(h[None, :, :1], (K, N, 1, D)), jnp.broadcast_to(c[:, None, None], (K, N, 1, D)),
                            jnp.broadcast_to(h[None, :, 1:], (K, N, S - 1, D))], axis=2)
    attn = Attention(D, H, dropout=0.0)
    # compiled (one program each, the same for both scales) rather than dispatched op by op
    params = jax.jit(lambda k, x: attn.init(k, x, deterministic=True))(jax.random.PRNGKey(1),
                                                                       full.reshape(K * N, S + 1, D))
    want = jax.jit(lambda p, x: attn.apply(p, x, deterministic=True))(params, full.reshape(K * N, S + 1, D))
    want = want.reshape(K, N, S + 1, D)
    got = jax.jit(lambda p, h, c: attn.apply(p, h, c, method=attn.branch_self_attention))(params, h, c)
    assert np.isfinite(np.asarray(got)).all()
    np.testing.assert_allclose(got, want, atol=2e-5 * class_scale, rtol=1e-5)
    assert not np.allclose(got[0], got[1])  # the branch token matters at every position


def test_forward_only_denoiser_equals_the_plain_branch_stack(tiny):
    """Forward-only calls (sampling, evaluation) run layer 0's self-attention on the shared tokens;
    the training path (deterministic=False, here with dropout 0) builds the three branch sequences
    in full. Same outputs, with and without text dropped, with guidance's repeated rows."""
    cfg, model, params, jit = tiny  # dropout 0; the programs of the test above, with other inputs
    B, L = 3, 8
    text, mask = _text(cfg, B, L, seed=6)
    r = np.random.default_rng(7)
    x = jnp.asarray(r.normal(size=(B, cfg.frames, 42, 4)), jnp.float32)
    t = jnp.asarray([0, 300, 999])
    drop = jnp.asarray([[False, False, False], [True, False, True], [True, True, True]])
    plain, shared = jit.full(params, x, t, text, mask, drop, False), jit.full(params, x, t, text, mask, drop, True)
    np.testing.assert_allclose(shared, plain, atol=1e-5)
    memory = jit.encode(params, text, mask)
    both = jit.denoise(params, jnp.concatenate([x, x]), jnp.concatenate([t, t]), memory, B, True)
    for rows, flags in ((slice(0, B), False), (slice(B, 2 * B), True)):
        ref = jit.full(params, x, t, text, mask, jnp.full((B, 3), flags), False)
        np.testing.assert_allclose(both[rows], ref, atol=1e-5)


def _sampler(model, guidance, **kw):
    """The sampler as ``compile_sampler`` builds it (DDIM-8, the run's diffusion config), with XLA's default
    options unless ``kw`` says otherwise; arguments (params, text, mask, rng, target, gamma)."""
    from functools import partial

    dcfg = D.DiffusionConfig()
    return partial(_sample_impl, model=model, sched=D.cosine_schedule(dcfg.steps), dcfg=dcfg, sampler="ddim", steps=8,
                   guidance=guidance, **kw)


@pytest.mark.parametrize("guidance", [2.5, 1.0])
def test_sampler_closure_matches_full_model_closure(tiny, guidance):
    cfg, model, params, _ = tiny
    B, L = 2, 8
    text, mask = _text(cfg, B, L, seed=2)
    sched, dcfg = D.cosine_schedule(1000), D.DiffusionConfig()

    @jax.jit
    def ref(params, text, mask, rng):
        def full(x, t_B, uncond_B):  # the pre-issue-15 closure: text tiled per pass, drop flags per row
            reps = x.shape[0] // B
            return model.apply(params, x, t_B, jnp.tile(text, (1, reps, 1, 1)), jnp.tile(mask, (1, reps, 1)),
                               jnp.broadcast_to(uncond_B[:, None], (x.shape[0], 3)))

        return D.sample(full, sched, (B, cfg.frames, 42, 4), rng, dcfg, sampler="ddim", steps=8, guidance=guidance)

    got = jax.jit(_sampler(model, guidance))(params, text, mask, jax.random.PRNGKey(3), None, None)
    np.testing.assert_allclose(got, ref(params, text, mask, jax.random.PRNGKey(3)), atol=1e-4)


def test_hash_dropout_rate_determinism_and_scale():
    km = jax.jit(keep_mask, static_argnums=(1, 2))  # one program rather than one per hash operation
    keep = np.asarray(km(jnp.uint32(7), (1000, 1000), 0.1))
    assert abs(keep.mean() - 0.9) < 0.002  # 1e6 draws: 3σ ≈ 0.0009
    # Rows and columns are not correlated (each row keeps ~90%, neighbouring elements independent).
    assert np.abs(keep.mean(1) - 0.9).max() < 0.15
    assert abs(np.mean(keep[:, 1:] & keep[:, :-1]) - 0.81) < 0.003
    np.testing.assert_array_equal(keep, np.asarray(km(jnp.uint32(7), (1000, 1000), 0.1)))
    other = np.asarray(km(jnp.uint32(8), (1000, 1000), 0.1))
    assert abs(np.mean(keep & other) - 0.81) < 0.003  # another seed: an independent mask
    x = jnp.ones((64, 64))
    y = Dropout(0.25).apply({}, x, deterministic=False, rngs={"dropout": jax.random.PRNGKey(0)})
    vals = np.unique(np.asarray(y))
    np.testing.assert_allclose(vals, [0.0, 1 / 0.75], rtol=1e-6)
    assert abs(float(np.mean(np.asarray(y) == 0)) - 0.25) < 0.03
    assert Dropout(0.25).apply({}, x, deterministic=True) is x
    y2 = Dropout(0.25, broadcast_dims=(0,)).apply({}, x, deterministic=False, rngs={"dropout": jax.random.PRNGKey(0)})
    assert (np.asarray(y2) == np.asarray(y2)[:1]).all()  # one mask shared along the broadcast axis


def test_gelu_erf_is_exact_gelu_in_value_and_gradient():
    # Known answer independent of the code: 0.5·x·erfc(−x/√2) in float64 (scipy), and its derivative
    # Φ(x) + x·φ(x). The erf form loses a little relative precision far in the negative tail, where
    # GELU is ~0 anyway, so the check is absolute.
    from scipy import special, stats

    x = np.linspace(-12.0, 12.0, 20001)
    want = 0.5 * x * special.erfc(-x / np.sqrt(2.0))
    got = np.asarray(jax.jit(gelu_erf)(jnp.asarray(x, jnp.float32)), np.float64)  # compiled, as the model runs it
    np.testing.assert_allclose(got, want, atol=2e-6, rtol=1e-6)
    grad = np.asarray(jax.jit(jax.vmap(jax.grad(gelu_erf)))(jnp.asarray(x, jnp.float32)), np.float64)
    np.testing.assert_allclose(grad, stats.norm.cdf(x) + x * stats.norm.pdf(x), atol=2e-6)
    # and it is what jax.nn.gelu(approximate=False) computes, to float32 rounding
    np.testing.assert_allclose(got, np.asarray(jax.nn.gelu(jnp.asarray(x, jnp.float32), approximate=False)), atol=2e-6)


def test_wide_models_sample_without_ynn_fusions_and_the_same(tiny, monkeypatch):
    """Sampling and decoding of models at least ``MIN_WIDTH`` wide compile with
    ``xla_options.inference_options`` (no YNNPACK fusions on CPU: paper-4L samples 1.15× faster); narrower
    ones keep XLA's defaults; the samples equal those of XLA's defaults up to float rounding, and
    ``HANDX_INFERENCE_XLA=default`` turns the options off."""
    from handx_jax.infra import xla_options as XO
    from handx_jax.families.diffusion import DiffusionRunConfig

    if jax.default_backend() != "cpu":
        pytest.skip("the options are CPU options")
    assert XO.inference_options(XO.MIN_WIDTH) == XO.CPU_INFERENCE
    assert XO.inference_options(XO.MIN_WIDTH - 1) is None  # narrow models sample faster with XLA's defaults
    monkeypatch.setenv(XO.ENV, "default")
    assert XO.inference_options(512) is None
    monkeypatch.delenv(XO.ENV)
    assert not XO._accepted((("xla_cpu_experimental_ynn_fusion_type", "NOT_A_FUSION_TYPE"),))

    cfg, model, params, _ = tiny
    B, L = 2, 8
    text, mask = _text(cfg, B, L, seed=5)
    assert DiffusionRunConfig(preset="tiny", model=cfg).diffusion == D.DiffusionConfig()  # a run's, as _sampler's
    fn = _sampler(model, 2.5)  # with XLA's defaults, the program of test_sampler_closure_matches_full_model_closure
    args = (params, text, mask, jax.random.PRNGKey(3), None, None)
    # the options for a wide model, compiled on the tiny one (what they do does not depend on its size)
    ours, default = XO.jit_inference(fn, XO.MIN_WIDTH).lower(*args).compile(), jax.jit(fn).lower(*args).compile()
    assert "__ynn_fusion" not in ours.as_text()
    if "__ynn_fusion" not in default.as_text():
        pytest.skip("this jaxlib makes no YNNPACK fusions by default: nothing to compare")
    np.testing.assert_allclose(np.asarray(ours(*args)), np.asarray(default(*args)), atol=2e-5)
