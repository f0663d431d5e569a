"""SentencePiece tokenizer with T5's special ids, trained on a dataset's captions or loaded from disk.

Id layout follows T5: pad = 0 (also the decoder start token), eos = 1, unk = 2. The sentinels
``<extra_id_N>`` do double duty, as in the reference: span-corruption sentinels during pretraining,
and field separators in the AR prefix ``"<extra_id_0> L <extra_id_1> R <extra_id_2> I"``
(reference §1.2). They are always single tokens:

- a tokenizer we train stores them as SentencePiece user-defined pieces ``<extra_id_0..N-1>``;
- a stock T5 ``spiece.model`` has no such pieces; there, as in Hugging Face's ``T5Tokenizer``,
  ``<extra_id_N>`` is id ``piece_size + 99 - N`` (the 100 extra ids sit past the SentencePiece vocab).

Text is split on the sentinel pattern before SentencePiece sees it, so a sentinel never picks up the
stray ``▁`` piece that SentencePiece puts in front of a user-defined symbol.
"""

from __future__ import annotations

import hashlib
import io
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import sentencepiece as spm

from handx_jax.infra.atomic import atomic_write_bytes, atomic_write_json
from handx_jax.infra.errors import DataError

PAD_ID, EOS_ID, UNK_ID = 0, 1, 2
HF_EXTRA_IDS = 100  # number of sentinels Hugging Face appends after a stock T5 vocabulary
NUM_SEPARATORS = 4  # <extra_id_0..3>: the reference's field separators (§1.2)
SENTINEL_RE = re.compile(r"<extra_id_(\d+)>")
TOKENIZER_DIRNAME = "tokenizer"
MODEL_FILENAME = "spiece.model"


def sentinel(i: int) -> str:
    return f"<extra_id_{i}>"


def join_fields(left: str, right: str, interaction: str) -> str:
    """The AR prefix text of the reference (§1.2): the three prompts behind sentinel separators."""
    return f"{sentinel(0)} {left} {sentinel(1)} {right} {sentinel(2)} {interaction}"


@dataclass(frozen=True)
class Encoded:
    """A padded batch. ``ids_BxL`` int32, ``mask_BxL`` int32 (1 = real token), ``lengths_B`` with eos."""

    ids_BxL: np.ndarray
    mask_BxL: np.ndarray
    lengths_B: np.ndarray
    num_truncated: int


class Tokenizer:
    """A SentencePiece model plus T5's id conventions. Build with ``load`` or ``train``."""

    def __init__(self, model_proto: bytes, path: Path | None = None):
        self.model_proto = bytes(model_proto)
        self.path = path
        self.sp = spm.SentencePieceProcessor(model_proto=self.model_proto)
        n = self.sp.get_piece_size()
        for want, name in ((PAD_ID, "pad"), (EOS_ID, "eos"), (UNK_ID, "unk")):
            got = {"pad": self.sp.pad_id(), "eos": self.sp.eos_id(), "unk": self.sp.unk_id()}[name]
            if got != want:
                raise DataError(f"SentencePiece {name} id is {got}, T5 layout needs {want}", path=path)
        self.piece_size = n
        # Sentinels stored as pieces (our trained tokenizers) or appended past the vocab (stock T5).
        internal = {}
        for i in range(n):
            m = SENTINEL_RE.fullmatch(self.sp.id_to_piece(i))
            if m and not self.sp.is_control(i):
                internal[int(m.group(1))] = i
        self._sentinel_to_id = internal or {k: n + HF_EXTRA_IDS - 1 - k for k in range(HF_EXTRA_IDS)}
        self._id_to_sentinel = {v: k for k, v in self._sentinel_to_id.items()}
        self.num_sentinels = len(self._sentinel_to_id)
        self.sentinels_internal = bool(internal)
        if self.num_sentinels < NUM_SEPARATORS or any(k not in self._sentinel_to_id for k in range(self.num_sentinels)):
            raise DataError(f"tokenizer must define <extra_id_0..{self.num_sentinels - 1}> contiguously and at least "
                            f"<extra_id_0..{NUM_SEPARATORS - 1}>; found {sorted(self._sentinel_to_id)}", path=path)

    # ----------------------------------------------------------------------------------------------
    # Construction

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Tokenizer":
        """Load ``spiece.model`` (a file, or a directory containing one)."""
        path = Path(path)
        if path.is_dir():
            path = path / MODEL_FILENAME
        if not path.is_file():
            raise DataError(f"missing {MODEL_FILENAME}", path=path.parent if path.name == MODEL_FILENAME else path)
        data = path.read_bytes()
        try:
            return cls(data, path)
        except RuntimeError as e:  # sentencepiece's parse error
            raise DataError(f"not a SentencePiece model ({e})", path=path) from None

    @classmethod
    def train(cls, texts: Iterable[str], *, vocab_size: int = 4000, num_extra_ids: int = 32,
              out: str | os.PathLike | None = None) -> "Tokenizer":
        """Train a unigram model (as T5's) on ``texts``; write it atomically to ``out`` if given.

        Sentences are de-duplicated and sorted first, so the model depends only on the set of captions
        (not their order or multiplicity) and training is single-threaded: same captions, same bytes.
        ``vocab_size`` is a soft limit: a small template corpus yields fewer pieces rather than an error.
        """
        if num_extra_ids < NUM_SEPARATORS:
            raise ValueError(f"num_extra_ids must be >= {NUM_SEPARATORS} (the reference's separators)")
        sentences = sorted({t.strip() for t in texts if t and t.strip()})
        if not sentences:
            raise DataError("no captions to train the tokenizer on")
        buf = io.BytesIO()
        spm.SentencePieceTrainer.train(
            sentence_iterator=iter(sentences), model_writer=buf, model_type="unigram",
            vocab_size=int(vocab_size), hard_vocab_limit=False,
            pad_id=PAD_ID, eos_id=EOS_ID, unk_id=UNK_ID, bos_id=-1,
            pad_piece="<pad>", eos_piece="</s>", unk_piece="<unk>",
            user_defined_symbols=[sentinel(i) for i in range(num_extra_ids)],
            character_coverage=1.0, num_threads=1, shuffle_input_sentence=False,
            max_sentence_length=1 << 16, minloglevel=2,
        )
        tok = cls(buf.getvalue())
        if out is not None:
            out = Path(out)
            if out.suffix != ".model":
                out = out / MODEL_FILENAME
            atomic_write_bytes(out, tok.model_proto)
            tok.path = out
        return tok

    # ----------------------------------------------------------------------------------------------
    # Properties

    @property
    def vocab_size(self) -> int:
        """Number of ids this tokenizer can emit (a model's embedding needs at least this many rows)."""
        return self.piece_size if self.sentinels_internal else self.piece_size + HF_EXTRA_IDS

    @property
    def fingerprint(self) -> str:
        return hashlib.sha256(self.model_proto).hexdigest()[:16]

    def sentinel_id(self, i: int) -> int:
        try:
            return self._sentinel_to_id[i]
        except KeyError:
            raise ValueError(f"<extra_id_{i}> is not in this tokenizer (it has {self.num_sentinels})") from None

    # ----------------------------------------------------------------------------------------------
    # Encoding

    def encode_one(self, text: str, *, add_eos: bool = True) -> list[int]:
        ids: list[int] = []
        pos = 0
        for m in SENTINEL_RE.finditer(text):
            ids += self._sp_encode(text[pos:m.start()])
            k = int(m.group(1))
            if k in self._sentinel_to_id:
                ids.append(self._sentinel_to_id[k])
            else:  # an unknown sentinel number is plain text, as for any other string
                ids += self._sp_encode(m.group(0))
            pos = m.end()
        ids += self._sp_encode(text[pos:])
        if add_eos:
            ids.append(EOS_ID)
        return ids

    def _sp_encode(self, chunk: str) -> list[int]:
        chunk = chunk.strip()
        return self.sp.encode(chunk) if chunk else []

    def encode(self, texts: Sequence[str], max_len: int | None = None, *, add_eos: bool = True) -> Encoded:
        """Encode a batch, padded to ``max_len`` (or to the longest text when None).

        A text longer than ``max_len`` keeps its first ``max_len - 1`` tokens and its eos (as Hugging
        Face truncates); such texts are counted in ``num_truncated``.
        """
        seqs = [self.encode_one(t, add_eos=add_eos) for t in texts]
        L = max_len if max_len is not None else max((len(s) for s in seqs), default=1)
        if L < 1 + add_eos:
            raise ValueError(f"max_len must be >= {1 + add_eos}, got {L}")
        ids = np.full((len(seqs), L), PAD_ID, np.int32)
        mask = np.zeros((len(seqs), L), np.int32)
        truncated = 0
        for i, s in enumerate(seqs):
            if len(s) > L:
                truncated += 1
                s = s[:L - 1] + [EOS_ID] if add_eos else s[:L]
            ids[i, :len(s)] = s
            mask[i, :len(s)] = 1
        return Encoded(ids, mask, mask.sum(1).astype(np.int32), truncated)

    def decode(self, ids_BxL: np.ndarray | Sequence[Sequence[int]]) -> list[str]:
        """Ids back to text; stops at eos, drops pad, writes sentinels as ``<extra_id_N>``."""
        out = []
        for row in ids_BxL:
            parts: list[str] = []
            run: list[int] = []
            for t in map(int, row):
                if t == EOS_ID:
                    break
                if t == PAD_ID:
                    continue
                if t in self._id_to_sentinel:
                    if run:
                        parts.append(self.sp.decode(run))
                        run = []
                    parts.append(sentinel(self._id_to_sentinel[t]))
                elif 0 <= t < self.piece_size:
                    run.append(t)
                else:
                    raise ValueError(f"id {t} is outside this tokenizer's vocabulary ({self.vocab_size})")
            if run:
                parts.append(self.sp.decode(run))
            out.append(" ".join(p for p in parts if p))
        return out


# --------------------------------------------------------------------------------------------------
# Dataset-side storage: DIR/tokenizer/spiece.model (+ tokenizer.json describing how it was built)


def dataset_captions(ds, splits: Sequence[str] | None = None) -> list[str]:
    """Every caption (3 fields × all levels) of the chosen clips, in dataset order."""
    from handx_jax.dataset.format import TEXT_FIELDS

    idx = range(len(ds.texts)) if splits is None else sorted(set(np.concatenate(
        [np.asarray(ds.split(s), np.int64) for s in splits]).tolist()))
    return [c for i in idx for f in TEXT_FIELDS for c in ds.texts[i][f]]


def tokenizer_dir(data_dir: str | os.PathLike) -> Path:
    return Path(data_dir) / TOKENIZER_DIRNAME


def train_for_dataset(data_dir: str | os.PathLike, *, vocab_size: int = 4000, num_extra_ids: int = 32,
                      overwrite: bool = False) -> Tokenizer:
    """Train on the dataset's train-split captions and store beside it, ``DIR/tokenizer/``.

    Training on the train split only keeps validation captions unseen by every text component.
    """
    from handx_jax.dataset.format import Dataset

    ds = Dataset.open(data_dir)
    out = tokenizer_dir(data_dir) / MODEL_FILENAME
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass --force to retrain it")
    caps = dataset_captions(ds, ["train"])
    tok = Tokenizer.train(caps, vocab_size=vocab_size, num_extra_ids=num_extra_ids, out=out)
    atomic_write_json(out.parent / "tokenizer.json", {
        "model": MODEL_FILENAME, "fingerprint": tok.fingerprint, "dataset_fingerprint": ds.fingerprint,
        "trained_on": "train split, all fields and levels", "num_captions": len(caps),
        "vocab_size_requested": vocab_size, "vocab_size": tok.vocab_size, "num_extra_ids": num_extra_ids,
    })
    return tok


def load_for_dataset(data_dir: str | os.PathLike) -> Tokenizer:
    return Tokenizer.load(tokenizer_dir(data_dir) / MODEL_FILENAME)
