"""The AR family's text conditioning (issue 30 item 4): the held-out text gap, conditioning dropout and
classifier-free guidance on the logits. Tiny shapes (the TINY LM of test_prefix_lm.py), seconds on CPU."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from handx_jax.families import ar as A
from handx_jax.families.ar import decode as AD
from handx_jax.models import prefix_lm as P
from tests.random_params import random_params

TINY = dataclasses.replace(P.PRESETS["tiny"], nb_code=37, text_dim=24)
# XLA compiles are most of this file's CPU: the model, its host-drawn weights and the (4, 6)-slot prompts are
# those of tests/test_prefix_lm.py, so the decoding loop and the training forward (``jax.jit(model.apply)``)
# are the same programs and come from the session's compilation cache (tests/conftest.py); no ``init`` is
# compiled where what is checked holds for any weights.
MODEL = P.PrefixLM(TINY)


def _params(seed):
    return random_params(lambda r: P.init_lm(TINY, r)[1], seed, scale=0.3)


def _prompts(B=4, L=6, seed=5):
    r = np.random.default_rng(seed)
    text = jnp.asarray(r.normal(size=(B, L, TINY.text_dim)), jnp.float32)
    mask = jnp.asarray(np.arange(L)[None] < np.array([6, 3, 1, 5])[:B, None])
    return text, mask


def test_guidance_one_is_the_conditional_logits_and_zero_the_null_prefix():
    lc, lu = jnp.asarray([[1.5, -2.0, 0.25]]), jnp.asarray([[0.5, 1.0, -3.0]])
    both = jnp.concatenate([lc, lu])
    np.testing.assert_array_equal(AD.guide(both, 1.0), lc)  # exactly, not to rounding
    np.testing.assert_allclose(AD.guide(both, 0.0), lu, rtol=0, atol=1e-6)
    np.testing.assert_allclose(AD.guide(both, 3.0), lu + 3 * (lc - lu), rtol=1e-6)

    model, params = MODEL, _params(3)
    text, mask = _prompts()
    empty = jnp.zeros((4, 0), jnp.int32)
    key = jax.random.PRNGKey(0)
    plain, n_plain = AD.decode(model, params, text, mask, empty, key)
    null, n_null = AD.decode(model, params, *AD.null_prefix(text, mask), empty, key)
    assert not np.array_equal(plain, null)  # the prompts matter to this LM, so the cases below differ
    for scale, want, n_want in ((1.0, plain, n_plain), (0.0, null, n_null)):  # one compiled guided loop
        got, n = AD.decode(model, params, text, mask, empty, key, AD.DecodeOptions(guidance=scale), guided=True)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(n, n_want)
    # s = 2 through the public entry (guided because s != 1) differs from both, and is greedy w.r.t. l_c + (l_c − l_u)
    g2, _ = AD.decode(model, params, text, mask, empty, key, AD.DecodeOptions(guidance=2.0))
    # the training forward's first prediction comes from the last text slot, which sees no motion token
    forward = jax.jit(model.apply)  # test_prefix_lm.py's APPLY: one program at these shapes
    first = lambda t, k: np.asarray(forward(params, t, k, jnp.zeros((4, 31), jnp.int32)))[:, 0]  # noqa: E731
    lc0, lu0 = first(text, mask), first(*AD.null_prefix(text, mask))
    np.testing.assert_array_equal(g2[:, 0], np.asarray(jnp.argmax(2 * lc0 - lu0, -1)))
    with pytest.raises(ValueError, match="guidance"):
        AD.DecodeOptions(guidance=-1.0)


def test_text_drop_replaces_the_prefix_by_the_null_prefix_only_in_training():
    model, params = MODEL, _params(1)
    text, mask = _prompts()
    codes = jnp.asarray(np.random.default_rng(2).integers(0, TINY.nb_code, (4, 30)), jnp.int32)
    batch = {"text": text, "mask": mask, "codes": codes}
    rng = jax.random.PRNGKey(7)
    # Jitted as training runs it (eagerly, each op compiles on its own: seconds). drop None: P.lm_loss itself;
    # the settings that trace no dropout trace that same program, which the session's cache compiles once.
    def loss_fn(p, b, r, drop, train):
        if drop is None:
            return P.lm_loss(model, p, b["text"], b["mask"], b["codes"])[0]
        return A.make_loss(model, drop)(p, b, r, train)[0]

    loss = jax.jit(loss_fn, static_argnums=(3, 4))
    text_n, mask_n = AD.null_prefix(text, mask)
    own = loss(params, batch, rng, None, False)
    null = loss(params, {**batch, "text": text_n, "mask": mask_n}, rng, None, False)
    assert abs(float(own) - float(null)) > 1e-4
    assert float(loss(params, batch, rng, 0.0, True)) == float(own)
    assert float(loss(params, batch, rng, 0.999999, False)) == float(own)  # evaluation: no drop
    assert float(loss(params, batch, rng, 0.999999, True)) == pytest.approx(float(null), abs=1e-6)
    with pytest.raises(A.ConfigError, match="text_drop"):
        A.make_config("tiny", ["data.text_drop=1"]).validate()
    cfg = A.make_config("tiny", ["data.text_drop=0.1", "sample.guidance=2.5"])
    assert (cfg.data.text_drop, cfg.sample.guidance) == (0.1, 2.5)


class _Cache:
    """A joined text cache of per-clip random prefixes (lookup as TextCache.lookup); level v adds v."""

    def __init__(self, n, L=4, seed=0):
        self.h = np.random.default_rng(seed).normal(size=(n, L, TINY.text_dim)).astype(np.float32)

    def lookup(self, clips, field, levels):
        return self.h[clips] + np.asarray(levels, np.float32)[:, None, None], np.ones(self.h[clips].shape[:2], bool)


def test_data_levels_restricts_the_items_to_those_caption_levels():
    codes = np.arange(3 * 30).reshape(3, 30).astype(np.int32)
    every = A.TrainData(clips=np.array([2, 0]), levels=5, codes=codes, cache=_Cache(3))
    only = dataclasses.replace(every, level_ids=(0, 3))
    assert (every.num_items, only.num_items) == (10, 4)
    b = only.batch(np.arange(4))  # items: (clip 2, level 0), (2, 3), (0, 0), (0, 3)
    np.testing.assert_array_equal(b["codes"], codes[[2, 2, 0, 0]])
    np.testing.assert_array_equal(b["text"], _Cache(3).h[[2, 2, 0, 0]] + np.array([0, 3, 0, 3], np.float32)[:, None, None])
    np.testing.assert_array_equal(every.batch(np.array([3, 5]))["text"], only.batch(np.array([1, 2]))["text"])
    np.testing.assert_array_equal(A.other_text_items(np.arange(4), 2, 2), [2, 3, 0, 1])
    for bad in ("data.levels=0,0", "data.levels=-1"):
        with pytest.raises(A.ConfigError, match="data.levels"):
            A.make_config("tiny", [bad]).validate()
    assert A.make_config("tiny", ["data.levels=0"]).data.levels == (0,)


def test_an_lm_whose_first_token_is_set_by_its_text_learns_a_positive_text_gap():
    # 8 clips; clip c's 30 codes all equal 4c, so only the first code is unknown without the text: an LM that
    # reads its text predicts it, and with another clip's text it predicts the wrong one.
    n = 8
    codes = np.repeat((4 * np.arange(n))[:, None], 30, axis=1).astype(np.int32)
    data = A.TrainData(clips=np.arange(n), levels=1, codes=codes, cache=_Cache(n))
    np.testing.assert_array_equal(A.other_text_items(np.arange(n), n, 1), np.roll(np.arange(n), -1))
    np.testing.assert_array_equal(A.other_text_items(np.array([0, 1, 5]), 3, 2), [2, 3, 1])  # next clip, same level
    model, params = MODEL, _params(0)
    evaluate = A.make_evaluate(model, data, np.arange(n))
    before = evaluate(params, None, 0)
    assert before["eval/text_gap"] == pytest.approx(before["eval/nll_other_text"] - before["eval/nll"])
    opt = optax.adam(1e-2)
    loss = A.make_loss(model)
    batch = data.batch(np.arange(n))

    @jax.jit
    def step(p, s):
        g = jax.grad(lambda q: loss(q, batch, None, True)[0])(p)
        u, s = opt.update(g, s, p)
        return optax.apply_updates(p, u), s

    state = opt.init(params)
    for _ in range(60):
        params, state = step(params, state)
    after = evaluate(params, None, 60)
    # At init the other text moves the NLL of these targets a little either way (−0.06 measured from these
    # host-drawn weights); trained, the first slot alone with the wrong text costs ≥ log 7 nats, ≥ 0.06 per slot
    # (3.8 per slot measured: the LM also follows the other text's code through the sequence).
    assert abs(before["eval/text_gap"]) < 0.5 and after["eval/text_gap"] > 2.0, (before, after)
    assert after["eval/nll"] < 0.1
