"""Text stack: what every generator conditions on (reference §1.2, §3.1, §4.5, §5.1).

- ``tokenizer``: SentencePiece (unigram) with T5's ids and ``<extra_id_N>`` sentinels/separators.
- ``t5``: Flax T5 encoder (+ the small decoder used for pretraining), Hugging Face folder load/export,
  analytic encoder FLOPs.
- ``pretrain``: span-corruption pretraining when no pretrained T5 is on disk.
- ``cache``: every caption encoded once by the frozen encoder, memory-mapped, fingerprinted.
- ``toy``: a seconds-sized caption dataset for tests and benchmarks.
- ``cli``: the ``handx text`` commands.
"""
