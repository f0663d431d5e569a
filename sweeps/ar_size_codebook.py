"""AR model size × FSQ codebook size (paper Table 3 / Table 5), family "ar".

Each codebook size needs a motion tokenizer: a shared step, trained and applied once into
``OUT/steps/tokenizer-K<N>-<hash>/`` and used by every LM size (marin-style: the step folder is named
from a hash of its commands; each run's ``provenance.json`` records the step it used). The joined
prompt text cache the LM reads is one more shared step:

    handx text cache --data DATA --encoder ENC --joined                              (step text-joined)
    handx train tokenizer --data DATA --preset P --set model.codebook=N --out STEP   (step tokenizer-KN)
    handx data tokens --tokenizer STEP --data DATA
    handx train ar --data DATA --encoder ENC --preset LM --tokenizer STEP --set ... --out RUN

The codebook size is the tokenizer's config (``model.codebook``), written once: the step is keyed by it
and the LM's run records it from the token cache (``config.json["codebook"]``). The tokenizer step is a
``family_step``: the registry says the ar family is trained from a tokenizer run, so the launcher passes
``--tokenizer STEP`` itself.

    handx sweep run sweeps/ar_size_codebook.py --preset tiny --data D --encoder E --evaluator standard --out S

``paper``: LM {8L-512, 12L-768, 16L-1024} (Table C's AR sizes) × codebook {512, 1024, 2048, 4096},
full data: 12 runs, 4 tokenizers. ``tiny``: LM {2L-64, 3L-64, 4L-128} × codebook {256, 512}.

``cpu`` (``make sweep-ar-cpu``, issue 30 item 5; docs/results/ar_cpu_study): the codebook axis end to end on
2 CPU cores in under an hour (measured: 44 min for the sweep, about 46 with the corpus prefix and install,
2 quiet cores). Top-3 rises log-linearly with the LM's FLOPs (slope +0.042 per decade, r 0.95); the codebook
does not move it. With the earlier 400-step width-64 tokenizers every run sat at chance: they lost the fingers'
motion the standard evaluator reads (see that README's ceiling table). LM {CPU_LMS} ×
codebook {CPU_CODEBOOKS}, each tokenizer the ``small`` width at CPU_TOKENIZER_STEPS × 64 windows (~8.5 min of
both cores each). Why the LMs are this
small: every LM layer runs over the joined text prefix (~110 of 128 slots) as well as the 31 motion slots,
so even the ``small`` preset (4L-128) took ~1.1 s per step of 64 on 2 quiet cores, a 3L-96 step of 64
~0.7 s (600 steps in 403 s), and nine LMs must share well under an hour of both cores. The sizes' steps grow with size
(CPU_STEPS: more data seen with more capacity, as the diffusion CPU study's ``matched``), on the level-0
captions with conditioning dropout (CPU_LM_DATA). Generation samples
at temperature 0.6 (CPU_SAMPLE; chosen once from pilots at greedy / 0.6 / 1.0) rather than decoding
greedily: greedy decoding of a short-trained LM repeats one motion for most prompts (a 3-layer LM's
diversity was 0), and with ``--eval-samples 4`` the evaluator's ± is then over 4 generation groups.
"""

from __future__ import annotations

from sweeps.diffusion_common import RESOURCES as _RESOURCES
from sweeps.launcher import RunSpec, Step, family_step, run_id

# (LM preset, extra overrides, layers, dim) — presets from handx_jax.models.prefix_lm.PRESETS.
PAPER_LMS = (("8L-512", (), 8, 512), ("12L-768", (), 12, 768), ("16L-1024", (), 16, 1024))
TINY_LMS = (("tiny", (), 2, 64), ("tiny", ("model.layers=3",), 3, 64), ("small", (), 4, 128))
PAPER_CODEBOOKS = (512, 1024, 2048, 4096)
TINY_CODEBOOKS = (256, 512)
# ``cpu``: (preset, overrides, layers, dim) and each size's LM steps (batch CPU_BATCH).
CPU_LMS = (("tiny", ("model.layers=1", "model.dim=32", "model.heads=2"), 1, 32), ("tiny", (), 2, 64),
           ("tiny", ("model.layers=3", "model.dim=96"), 3, 96))
CPU_STEPS = (150, 300, 600)
CPU_BATCH = 64
CPU_CODEBOOKS = (256, 1024, 4096)
# The `small` tokenizer (width 128) at its full 3,000 steps: the 400-step width-64 recipe lost the fingers'
# motion the evaluator reads (ground truth through it scored top-3 0.08-0.10, chance); this one keeps enough
# (0.150 at K1024) for the LMs to show a log-linear trend (docs/results/ar_cpu_study).
CPU_TOKENIZER_STEPS = 3000
CPU_TOKENIZER = ("model.width=128", "train.eval_every=1000")
CPU_SAMPLE = ("sample.temperature=0.6",)
# The LMs train on the concise (level-0) captions with 10% conditioning dropout: the only recipe under which a
# CPU-sized LM's held-out NLL depends on its text (docs/results/ar_text: text gap +0.05 against ~0 for all five
# levels, whose joined prompts are cut at 128 tokens for most clips at levels 2-4).
CPU_LM_DATA = ("data.levels=0", "data.text_drop=0.1")
RESOURCES = {**_RESOURCES, "cpu": {"timeout_min": 90, "cpus_per_task": 1, "mem_gb": 4}}

TEXT_JOINED = Step("text-joined", (("handx", "text", "cache", "--data", "{data}", "--encoder", "{encoder}",
                                    "--joined"),))


def tokenizer_step(codebook: int, preset: str, steps: int | None = None, overrides: tuple = ()) -> Step:
    """The one tokenizer of ``codebook`` that every LM size of the sweep trains from."""
    ov = (f"model.codebook={codebook}", *(() if steps is None else (f"train.steps={steps}",)), *overrides)
    return family_step("tokenizer", f"tokenizer-K{codebook}", preset, ov)


def runs(preset: str = "tiny", steps: int | None = None, tokenizer_steps: int | None = None,
         codebooks: tuple | None = None, lm_set: tuple = (), tokenizer_set: tuple = ()) -> list[RunSpec]:
    """``lm_set``/``tokenizer_set``: more dotted overrides of every LM run / every tokenizer step, e.g.
    ``--arg 'lm_set=["train.batch_size=32"]'`` (they change the run ids and step keys, as any setting does)."""
    if preset not in ("tiny", "paper", "cpu"):
        raise ValueError(f"unknown preset {preset!r} (tiny | paper | cpu)")
    if preset == "cpu":
        return _cpu_runs(steps, tokenizer_steps, codebooks, lm_set, tokenizer_set)
    lms = PAPER_LMS if preset == "paper" else TINY_LMS
    books = codebooks or (PAPER_CODEBOOKS if preset == "paper" else TINY_CODEBOOKS)
    st = steps or (100_000 if preset == "paper" else 300)
    tok_steps = tokenizer_steps or (None if preset == "paper" else 300)
    out = []
    for K in books:
        tok = tokenizer_step(K, preset, tok_steps, tuple(tokenizer_set))
        for lm, extra, L, d in lms:
            ov = (*extra, f"train.steps={st}", *lm_set)
            axes = {"layers": L, "dim": d, "codebook": K}
            out.append(RunSpec(run_id(axes, (lm, tok.key, *ov)), "ar", preset=lm, overrides=ov, axes=axes,
                               needs=(TEXT_JOINED, tok)))
    return out


def _cpu_runs(steps, tokenizer_steps, codebooks, lm_set, tokenizer_set) -> list[RunSpec]:
    """``steps``: one LM step count for every size instead of CPU_STEPS. Largest LM first (longest first: two
    runs at a time finish together), each codebook's tokenizer built by the first run that needs it."""
    out = []
    toks = {K: tokenizer_step(K, "tiny", tokenizer_steps or CPU_TOKENIZER_STEPS, (*CPU_TOKENIZER, *tokenizer_set))
            for K in codebooks or CPU_CODEBOOKS}
    for (lm, extra, L, d), st in reversed(list(zip(CPU_LMS, CPU_STEPS))):
        st = steps or st
        for K, tok in toks.items():
            ov = (*extra, f"train.steps={st}", f"train.batch_size={CPU_BATCH}", f"train.log_every={max(st // 10, 1)}",
                  f"train.eval_every={st}", f"train.ckpt_every={st}", f"train.optim.warmup_steps={min(100, st // 10)}",
                  "train.wandb=disabled", *CPU_LM_DATA, *CPU_SAMPLE, *lm_set)
            axes = {"layers": L, "dim": d, "codebook": K}
            out.append(RunSpec(run_id(axes, (lm, tok.key, *ov)), "ar", preset=lm, overrides=ov, axes=axes,
                               needs=(TEXT_JOINED, tok)))
    return out
