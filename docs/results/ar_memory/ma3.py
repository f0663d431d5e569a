import dataclasses, sys, time, importlib.util, numpy as np, jax, jax.numpy as jnp
sys.path.insert(0, "/work/main")
path, B, reps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
spec = importlib.util.spec_from_file_location("plm", path); P = importlib.util.module_from_spec(spec); sys.modules["plm"] = P; spec.loader.exec_module(P)
cfg = dataclasses.replace(P.PRESETS["small"], nb_code=4375, text_dim=64)
model, params = P.init_lm(cfg, jax.random.PRNGKey(0), 128)
f = jax.jit(jax.value_and_grad(lambda p, t, m, c: P.lm_loss(model, p, t, m, c)[0]))
r = np.random.default_rng(0)
args = (params, jnp.asarray(r.normal(size=(B, 128, 64)), jnp.float32), jnp.ones((B, 128), bool), jnp.asarray(r.integers(0, 4375, (B, 30)), jnp.int32))
c = f.lower(*args).compile()
l, g = c(*args); jax.block_until_ready(g)
ts = []
for _ in range(reps):
    t0 = time.perf_counter(); l, g = c(*args); jax.block_until_ready(g); ts.append(time.perf_counter() - t0)
print(path.split("/")[-1], "B", B, "temp MB %.1f" % (c.memory_analysis().temp_size_in_bytes / 2**20), "step s", " ".join("%.2f" % t for t in ts), "samples/s (best) %.1f" % (B / min(ts)))
