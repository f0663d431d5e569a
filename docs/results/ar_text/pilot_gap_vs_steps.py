"""Gap (held-out NLL with another clip's text minus with its own) vs steps, for text-prefix variants."""
import sys, json, time, argparse, dataclasses, numpy as np, jax, jax.numpy as jnp, optax
from handx_jax.families import ar as A
from handx_jax.models import prefix_lm as P
from handx_jax.dataset.format import Dataset

ap = argparse.ArgumentParser()
ap.add_argument("--steps", type=int, default=600); ap.add_argument("--bs", type=int, default=64)
ap.add_argument("--lr", type=float, default=1e-3); ap.add_argument("--levels", default="all")
ap.add_argument("--maxlen", type=int, default=128); ap.add_argument("--pdrop", type=float, default=0.0)
ap.add_argument("--layers", type=int, default=2); ap.add_argument("--dim", type=int, default=64)
ap.add_argument("--eval_every", type=int, default=100); ap.add_argument("--tok", default="/tmp/h30/tok_small512")
ap.add_argument("--warmup", type=int, default=100); ap.add_argument("--name", default="x")
a = ap.parse_args()
cfg = A.make_config("tiny", [f"model.layers={a.layers}", f"model.dim={a.dim}"], data="/tmp/h30/D",
                    encoder="/work/main/handx_jax/assets/standard/encoder", tokenizer=a.tok)
data, tokens = A.load_train_data(cfg)
m = dataclasses.replace(cfg.model, nb_code=int(tokens.meta["nb_code"]), text_dim=int(data.cache.meta["d_model"]))
model = P.PrefixLM(m)
levels = list(range(data.levels)) if a.levels == "all" else [int(x) for x in a.levels.split(",")]
items = np.array([c * data.levels + l for c in range(len(data.clips)) for l in levels])
val = np.asarray(Dataset.open(cfg.data.path).split("val"))
held = dataclasses.replace(data, clips=val)
vidx = np.arange(held.num_items)
perm = np.roll(np.arange(len(val)), 1)

def cut(b):
    h, mk = b["text"][:, :a.maxlen], b["mask"][:, :a.maxlen]
    return {"codes": b["codes"], "text": h, "mask": mk}
vb = cut(held.batch(vidx)); vo = cut(held.batch(perm[vidx // held.levels] * held.levels + vidx % held.levels))
Lv = int(vb["mask"].sum(1).max()); vb["text"], vb["mask"], vo["text"], vo["mask"] = vb["text"][:, :Lv], vb["mask"][:, :Lv], vo["text"][:, :Lv], vo["mask"][:, :Lv]
null_t = jnp.zeros((1, 1, m.text_dim)); null_m = jnp.ones((1, 1), bool)

def per_tok(p, text, mask, codes):
    B = codes.shape[0]
    tok = jnp.concatenate([codes, jnp.full((B, 1), m.end_id, codes.dtype)], 1)
    lp = jax.nn.log_softmax(model.apply(p, text.astype(jnp.float32), mask, tok), -1)
    return -jnp.take_along_axis(lp, tok[..., None], -1)[..., 0]
ev = jax.jit(per_tok)

sched = optax.warmup_cosine_decay_schedule(0.0, a.lr, min(a.warmup, a.steps // 5), a.steps, 0.0)
opt = optax.chain(optax.clip_by_global_norm(1.0), optax.adamw(sched, 0.9, 0.999, 1e-6, weight_decay=1e-6))
_, params = P.init_lm(m, jax.random.PRNGKey(0), text_len=8)
st = opt.init(params)

@jax.jit
def step(params, st, text, mask, codes, drop):
    # conditioning dropout: dropped rows see one zero text slot (text_proj's bias = a learnt null)
    text = jnp.where(drop[:, None, None], 0.0, text.astype(jnp.float32))
    mask = jnp.where(drop[:, None], jnp.arange(mask.shape[1])[None] == 0, mask)
    (l, aux), g = jax.value_and_grad(lambda p: P.lm_loss(model, p, text, mask, codes), has_aux=True)(params)
    u, st = opt.update(g, st, params)
    return optax.apply_updates(params, u), st, l

def evaluate(s):
    own = np.asarray(ev(params, vb["text"], vb["mask"], vb["codes"])); oth = np.asarray(ev(params, vo["text"], vo["mask"], vb["codes"]))
    nul = np.asarray(ev(params, jnp.broadcast_to(null_t, (len(vidx), 1, m.text_dim)), jnp.ones((len(vidx), 1), bool), vb["codes"]))
    l0 = vidx % held.levels == 0
    r = dict(name=a.name, step=s, nll=round(float(own.mean()), 4), gap=round(float(oth.mean() - own.mean()), 4),
             gap_l0=round(float(oth[l0].mean() - own[l0].mean()), 4), null_gap=round(float(nul.mean() - own.mean()), 4),
             gap_tok0=round(float(oth[:, 0].mean() - own[:, 0].mean()), 3), t=round(time.time() - t0, 1))
    print(json.dumps(r), flush=True)

rng = np.random.default_rng(0)
t0 = time.time()
evaluate(0)
for s in range(1, a.steps + 1):
    b = cut(data.batch(rng.choice(items, a.bs)))
    L = min(a.maxlen, -(-int(b["mask"].sum(1).max()) // 16) * 16)
    drop = rng.random(a.bs) < a.pdrop
    params, st, l = step(params, st, b["text"][:, :L], b["mask"][:, :L], b["codes"], drop)
    if s % a.eval_every == 0:
        evaluate(s)
