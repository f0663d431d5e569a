"""Run by tests/test_hostdevices.py in a fresh process (the CPU device count is fixed at JAX start-up),
and imported by it for :func:`samples`, which the test then runs on its own single device.

As a script: configures the host's CPU devices as the CLI does (HANDX_CPU_DEVICES from the environment),
samples a tiny denoiser with the compiled sampler (guided and unguided on a batch the devices divide,
guided on one they do not) and writes the samples to the .npz named by argv[1].
"""

import json
import sys


def samples() -> tuple[dict, dict]:
    """({case: samples}, {batch: devices its sampler used}) of a tiny denoiser with fixed inputs."""
    import dataclasses

    import jax
    import numpy as np

    from handx_jax.families.diffusion import process as D
    from handx_jax.families.diffusion import make_model
    from handx_jax.families.diffusion.sampling import compile_sampler
    from handx_jax.models.dit import PRESETS, init_denoiser

    # one layer: splitting the batch over devices does not depend on depth, and each sampler compiles
    # twice (two devices, then one) for three cases (95 -> 89 s of CPU for the test, 2026-11-27)
    m = dataclasses.replace(PRESETS["tiny"], layers=1)
    # committed to one device, as restored parameters are: the split sampler must copy them itself
    params = jax.device_put(init_denoiser(m, jax.random.PRNGKey(0), 8)[1], jax.devices()[0])
    rng = np.random.default_rng(1)
    out, used = {}, {}
    for B, cases in ((4, (("guided", 2.5), ("unguided", 1.0))), (3, (("guided", 2.5),))):
        text = rng.normal(size=(3, B, 8, m.text_dim)).astype(np.float32)
        mask = np.ones((3, B, 8), bool)
        mask[:, :, 5:] = False
        for name, g in cases:
            fn = compile_sampler(make_model(m), D.DiffusionConfig(), sampler="ddim", steps=3, guidance=g, batch=B)
            used[str(B)] = int(fn.mesh.size) if hasattr(fn, "mesh") else 1
            out[f"{name}_{B}"] = np.asarray(fn(params, text, mask, jax.random.PRNGKey(3), None, None))
    # AR decoding (families.ar.decode.decode): greedy and sampled, one compiled loop (the options are traced)
    from handx_jax.families.ar import decode as AD
    from handx_jax import hostdevices
    from handx_jax.models import prefix_lm as PL

    lm_cfg = PL.PRESETS["tiny"]
    lm, lm_params = PL.init_lm(lm_cfg, jax.random.PRNGKey(4))
    lm_params = jax.device_put(lm_params, jax.devices()[0])
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
    from handx_jax import hostdevices

    configured = hostdevices.configure()
    import jax
    import numpy as np

    from handx_jax import train as T

    out, used = samples()
    np.savez(sys.argv[1], **out)
    print(json.dumps({"configured": configured, "devices": jax.device_count(), "train_mesh": int(T._mesh().size),
                      "sample_devices": used}), flush=True)
