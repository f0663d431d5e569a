"""A reader of captions that needs no evaluator: Top-3 R-Precision (block 32) of the perturbed test clips'
own level-0 captions against the clean ones, ranked by word overlap (Jaccard of the three texts' words).
The evaluator-independent check on the validity suite's "caption reader" column.

    python docs/results/validity/word_reader.py DATA      # e.g. the 4,000-clip prefix of corpus v2
"""

import re
import sys

import numpy as np

from handx_jax.dataset.build import corpus_seed, reading_of
from handx_jax.annotation.caption import TemplateCaptioner
from handx_jax.dataset.format import Dataset
from handx_jax.annotation.events import annotation_config
from handx_jax.generation import split_prompts
from handx_jax.validity import perturb as P
from handx_jax.validity import stability as S


def words(c) -> set:
    return set(re.findall(r"[a-z]+", " ".join(c).lower()))


def word_rprec_top3(clean, pert, block: int = 32) -> float:
    """Each perturbed caption ranks the block's clean captions by overlap; ties split uniformly (metrics)."""
    n = len(clean) // block * block
    hits = 0.0
    for s in range(0, n, block):
        A = [words(x) for x in clean[s:s + block]]
        for i, b in enumerate(words(x) for x in pert[s:s + block]):
            sim = np.array([len(b & a) / max(len(b | a), 1) for a in A])
            closer, tied = (sim > sim[i]).sum(), (sim == sim[i]).sum() - 1
            hits += np.clip((3 - closer) / (tied + 1), 0, 1)
    return hits / n


def main(data: str) -> None:
    ds = Dataset.open(data)
    clips, _, motion = split_prompts(ds, "test", None, 0)
    gt = np.stack(motion).astype(np.float32)
    reading, wording = reading_of(ds)
    ann = S.Annotator(gt, [ds.ids[c] for c in clips], corpus_seed(ds), annotation_config(reading),
                      TemplateCaptioner(wording))
    clean = [c[0] for c in ann.clean_captions]
    for kind, amp in [("white", 0.001), ("lowfreq", 0.003), ("reverse", 0.0), ("other", 0.0)]:
        _, caps = ann.records_and_captions(P.apply(kind, gt, amp, 0))
        print(f"{kind} {amp * 1000:g} mm: word-overlap reader top-3 {word_rprec_top3(clean, [c[0] for c in caps]):.3f} "
              f"(clean {word_rprec_top3(clean, clean):.3f})")


if __name__ == "__main__":
    main(sys.argv[1])
