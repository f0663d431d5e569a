"""A probe, not a feature: diffusion prediction with a soft band after the observation (README, "The boundary").

The committed prediction task keeps the observed frames with γ = 1 and puts no band after them, so nothing of the
hidden future enters the target. This probe adds App. D's band there, γ falling from p_hard (0.85) to p_soft (0.10)
over BAND frames, with the last observed frame held as its target (the last-frame baseline's guess: still nothing
from the future), and scores frames 17, 18–20, 21–32 and 17–60 as `handx eval prediction` does.

    python docs/results/prediction/band_probe.py RUN DATA BAND   # the first 20 test clips, 4 samples, DDIM-50
"""

import sys

import numpy as np

from handx_jax import representation as rep
from handx_jax.dataset.format import Dataset
from handx_jax.evaluation import prediction as PR
from handx_jax.families.diffusion import load
from handx_jax.families.diffusion.sampling import SampleOptions, sample_normalised, to_joints
from handx_jax.generation import split_prompts

run_dir, data, band = sys.argv[1], sys.argv[2], int(sys.argv[3])
run = load(run_dir)
clips, prompts, sources = split_prompts(Dataset.open(data), "test", 20, -1)
N, G, F = 16, 4, run.cfg.model.frames
src = np.stack(sources).astype(np.float64)
held = PR.last_frame(src, N).astype(np.float64)  # the observed frames, then frame N held
c = rep.diffusion_center(held[:, :N])  # the observation's own centre, as the prediction task uses
x = rep.to_diffusion(held)
x[..., :3] += (rep.diffusion_center(held) - c)[:, None, None, :]  # re-centred on the observation
gamma = np.zeros((F, 42), np.float32)
gamma[:N] = 1.0
d = run.cfg.diffusion
for i in range(band):
    gamma[N + i] = d.p_hard - (d.p_hard - d.p_soft) * (i + 1) / band
xs = sample_normalised(run, [p for p in prompts for _ in range(G)], SampleOptions(sampler="ddim", steps=50),
                       targets_BxFx42x4=np.repeat(run.norm.normalize(x.astype(np.float32)), G, 0), gamma_FxJ=gamma)
j = to_joints(run, xs, np.repeat(c, G, 0)).reshape(len(prompts), G, F, 2, 21, 3)
res = PR.score(np.swapaxes(j, 0, 1), src.astype(np.float32), N, PR.parse_horizons("17-17,18-20,21-32", N))
print(f"band {band}:")
print(PR.format_table(res))
