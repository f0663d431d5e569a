"""AR model size × FSQ codebook size (paper Table 3 / Table 5), family "ar".

Each codebook size needs a motion tokenizer: a shared step, trained and applied once into
``OUT/steps/tokenizer-K<N>-<hash>/`` and used by every LM size (marin-style: the step folder is named
from a hash of its commands; each run's ``provenance.json`` records the step it used). The joined
prompt text cache the LM reads is one more shared step:

    handx text cache --data DATA --encoder ENC --joined                              (step text-joined)
    handx train tokenizer --data DATA --preset P --set model.codebook=N --out STEP   (step tokenizer-KN)
    handx tokenize --tokenizer STEP --data DATA
    handx train ar --data DATA --encoder ENC --preset LM --tokenizer STEP --set ... --out RUN

The codebook size is the tokenizer's config (``model.codebook``), written once: the step is keyed by it
and the LM's run records it from the token cache (``config.json["codebook"]``). The tokenizer step is a
``family_step``: the registry says the ar family is trained from a tokenizer run, so the launcher passes
``--tokenizer STEP`` itself.

    handx sweep run sweeps/ar_size_codebook.py --preset tiny --data D --encoder E --evaluator standard --out S

``paper``: LM {8L-512, 12L-768, 16L-1024} (Table C's AR sizes) × codebook {512, 1024, 2048, 4096},
full data: 12 runs, 4 tokenizers. ``tiny``: LM {2L-64, 3L-64, 4L-128} × codebook {256, 512}.
"""

from __future__ import annotations

from sweeps.common import RESOURCES  # noqa: F401
from sweeps.launcher import RunSpec, Step, family_step, run_id

# (LM preset, extra overrides, layers, dim) — presets from handx_jax.models.prefix_lm.PRESETS.
PAPER_LMS = (("8L-512", (), 8, 512), ("12L-768", (), 12, 768), ("16L-1024", (), 16, 1024))
TINY_LMS = (("tiny", (), 2, 64), ("tiny", ("model.layers=3",), 3, 64), ("small", (), 4, 128))
PAPER_CODEBOOKS = (512, 1024, 2048, 4096)
TINY_CODEBOOKS = (256, 512)

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
    if preset not in ("tiny", "paper"):
        raise ValueError(f"unknown preset {preset!r} (tiny | paper)")
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
