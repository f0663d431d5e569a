"""Run by tests/test_hostdevices.py in a fresh process (the CPU device count is fixed at JAX start-up).

Configures the host's CPU devices as the CLI does (HANDX_CPU_DEVICES from the environment), samples a tiny
denoiser with the compiled sampler (guided and unguided on a batch the devices divide; on one they do not it
checks the sampler is the unsplit one) and decodes a tiny prefix LM, and writes the samples to the .npz named by argv[1]. Then it runs the same
cases again as a one-device host does (``hostdevices.inference_mesh`` answering None: no split) and writes
those to argv[2]. Both passes in one process: a two-device process's cached compilations do not serve a
one-device process (the device count is part of XLA's cache key), and the one-device programs are the same
programs either way.
"""

import json
import sys


def _random_params(init, seed: int):
    """Parameters of ``init``'s structure from a host draw (tests/random_params.py: no compiled initialiser;
    splitting the batch must not change the numbers for any weights), committed to one device as restored
    parameters are: the split sampler must copy them itself."""
    import jax

    from random_params import random_params

    return jax.device_put(random_params(init, seed), jax.devices()[0])


def samples() -> tuple[dict, dict]:
    """({case: samples}, {batch: devices its sampler used}) of a tiny denoiser and LM with fixed inputs."""
    import dataclasses

    import jax
    import numpy as np

    from handx_jax.families.diffusion import process as D
    from handx_jax.families.diffusion import make_model
    from handx_jax.families.diffusion.sampling import compile_sampler
    from handx_jax.models.dit import PRESETS, init_denoiser

    # one layer: splitting the batch over devices does not depend on depth
    m = dataclasses.replace(PRESETS["tiny"], layers=1)
    params = _random_params(lambda r: init_denoiser(m, r, 8)[1], 0)
    rng = np.random.default_rng(1)
    out, used = {}, {}
    B = 4
    text = rng.normal(size=(3, B, 8, m.text_dim)).astype(np.float32)
    mask = np.ones((3, B, 8), bool)
    mask[:, :, 5:] = False
    for name, g in (("guided", 2.5), ("unguided", 1.0)):
        fn = compile_sampler(make_model(m), D.DiffusionConfig(), sampler="ddim", steps=3, guidance=g, batch=B)
        used[str(B)] = int(fn.mesh.size) if hasattr(fn, "mesh") else 1
        out[f"{name}_{B}"] = np.asarray(fn(params, text, mask, jax.random.PRNGKey(3), None, None))
    # a batch the devices do not divide: the plain one-device program (no ``mesh``), i.e. the very program the
    # reference pass runs, so it is built here and not run (running it would compare a program with itself)
    fn = compile_sampler(make_model(m), D.DiffusionConfig(), sampler="ddim", steps=3, guidance=2.5, batch=3)
    used["3"] = int(fn.mesh.size) if hasattr(fn, "mesh") else 1
    # AR decoding (families.ar.decode.decode): greedy and sampled, one compiled loop (the options are traced)
    from handx_jax.families.ar import decode as AD
    from handx_jax.infra import hostdevices
    from handx_jax.models import prefix_lm as PL

    lm_cfg = dataclasses.replace(PL.PRESETS["tiny"], layers=1)
    lm = PL.PrefixLM(lm_cfg)
    lm_params = _random_params(lambda r: PL.init_lm(lm_cfg, r)[1], 4)
    B = 4
    text = rng.normal(size=(B, 8, lm_cfg.text_dim)).astype(np.float32)
    mask = np.ones((B, 8), bool)
    empty = np.zeros((B, 0), np.int32)
    for name, opts in (("greedy", AD.DecodeOptions()), ("temperature", AD.DecodeOptions(1.0)),
                       ("top_k", AD.DecodeOptions(1.0, top_k=5))):
        toks, lens = AD.decode(lm, lm_params, text, mask, empty, jax.random.PRNGKey(5), opts)
        out[f"ar_{name}"], out[f"ar_{name}_lengths"] = np.asarray(toks), np.asarray(lens)
    mesh = hostdevices.inference_mesh(B)
    used["ar"] = 1 if mesh is None else int(mesh.size)
    return out, used


if __name__ == "__main__":
    from handx_jax.infra import hostdevices

    configured = hostdevices.configure()
    import jax
    import numpy as np

    from handx_jax import train as T

    two, used = samples()
    np.savez(sys.argv[1], **two)
    # the one-device reference: hostdevices' answer on a one-device host (no mesh), so every case runs
    # the unsplit program
    hostdevices.inference_mesh = lambda batch: None
    one, used_one = samples()
    np.savez(sys.argv[2], **one)
    print(json.dumps({"configured": configured, "devices": jax.device_count(), "train_mesh": int(T._mesh().size),
                      "sample_devices": used, "reference_devices": used_one}), flush=True)
