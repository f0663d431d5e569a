"""AR model size × FSQ codebook size (paper Table 3 / Table 5), family "ar".

Each codebook size needs a motion tokenizer. It is a shared step, trained once and tokenized once
into ``OUT/steps/tokenizer-K<N>-<hash>/`` and used by every LM size (marin-style: the step folder is
named from a hash of its commands, and each run's ``provenance.json`` records which one it used):

    handx train tokenizer --data DATA --codebook N --preset P --out STEP
    handx tokenize --tokenizer STEP --data DATA
    handx train ar --data DATA --preset P --set tokenizer=STEP --set model.* ... --out RUN

``paper``: LM {8L-512, 12L-768, 16L-1024} (Table C's AR sizes, FFN = d) × codebook {512, 1024, 2048,
4096}, full data: 12 runs, 4 tokenizers. ``tiny``: LM {2L-32, 3L-48, 4L-64} × codebook {64, 256}.
"""

from __future__ import annotations

from sweeps.common import RESOURCES  # noqa: F401
from sweeps.launcher import RunSpec, Step, run_id

PAPER_LMS = ((8, 512), (12, 768), (16, 1024))
PAPER_CODEBOOKS = (512, 1024, 2048, 4096)
TINY_LMS = ((2, 32), (3, 48), (4, 64))
TINY_CODEBOOKS = (64, 256)


def tokenizer_step(codebook: int, preset: str) -> Step:
    return Step(f"tokenizer-K{codebook}", (
        ("handx", "train", "tokenizer", "--data", "{data}", "--codebook", str(codebook), "--preset", preset,
         "--out", "{out}"),
        ("handx", "tokenize", "--tokenizer", "{out}", "--data", "{data}"),
    ))


def runs(preset: str = "tiny", steps: int | None = None, codebooks: tuple | None = None) -> list[RunSpec]:
    lms = PAPER_LMS if preset == "paper" else TINY_LMS
    books = codebooks or (PAPER_CODEBOOKS if preset == "paper" else TINY_CODEBOOKS)
    st = steps or (100_000 if preset == "paper" else 300)
    out = []
    for K in books:
        tok = tokenizer_step(K, preset)
        for L, d in lms:
            ov = (f"model.layers={L}", f"model.dim={d}", f"model.heads={max(d // 64, 4)}", f"model.ff={d}",
                  f"train.steps={st}", f"tokenizer={{step:{tok.name}}}")
            axes = {"layers": L, "dim": d, "codebook": K}
            out.append(RunSpec(run_id(axes, ov), family="ar", preset=preset, overrides=ov, axes=axes, needs=(tok,)))
    return out
