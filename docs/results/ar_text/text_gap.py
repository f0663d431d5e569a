"""NLL own vs other-clip text on held-out clips, for an LM run folder (or untrained init)."""
import sys, json, numpy as np, jax, jax.numpy as jnp
from handx_jax.families import ar as A
from handx_jax.models import prefix_lm as P
from handx_jax.dataset.format import Dataset
from handx_jax.train import load_params

run = sys.argv[1]
cfg = A.from_dict(A.ARRunConfig, json.load(open(f"{run}/config.json")))
data, tokens = A.load_train_data(cfg)
model = P.PrefixLM(cfg.model)
params, step = load_params(run, ema=False)
val = np.asarray(Dataset.open(cfg.data.path).split("val"))
held = A.dataclasses.replace(data, clips=val, level_ids=())  # every level, whatever the run trained on
idx = np.arange(held.num_items)
b = held.batch(idx)
SHIFTS = range(1, 11)  # each clip given the text of the clip `shift` places later (same level), 10 derangements

def per_tok(p, text, mask, codes):
    B, N = codes.shape
    tok = jnp.concatenate([codes, jnp.full((B, 1), cfg.model.end_id, codes.dtype)], 1)
    lg = model.apply(p, text.astype(jnp.float32), mask, tok)
    lp = jax.nn.log_softmax(lg, -1)
    return -jnp.take_along_axis(lp, tok[..., None], -1)[..., 0]
f = jax.jit(per_tok)
own = np.asarray(f(params, b["text"], b["mask"], b["codes"]))
lv = idx % held.levels
res = {}
for l in range(held.levels):
    gaps = []
    for sh in SHIFTS:
        it = idx[lv == l]
        ob = held.batch(((it // held.levels + sh) % len(val)) * held.levels + l)
        oth = np.asarray(f(params, ob["text"], ob["mask"], b["codes"][lv == l]))
        gaps.append(float(oth.mean() - own[lv == l].mean()))
    res[l] = (round(float(np.mean(gaps)), 4), round(float(np.std(gaps) / np.sqrt(len(gaps))), 4), round(float(own[lv == l].mean()), 4))
print(json.dumps({"run": run, "step": step, "gap_by_level_mean_se_nll": res}))
# text scale
pp = params["params"]
h = b["text"].astype(np.float32); m = b["mask"]
tx = np.asarray(model.apply(params, jnp.asarray(h), method=P.PrefixLM.embed_text))
print("text feat rms (valid)", float(np.sqrt((h[m]**2).mean())), "proj rms", float(np.sqrt((tx[m]**2).mean())),
      "tok emb rms", float(np.sqrt((np.asarray(pp["embed"]["embedding"])**2).mean())),
      "valid len mean", float(m.sum(1).mean()), "max", int(m.sum(1).max()), "frac full", float((m.sum(1)==m.shape[1]).mean()))
