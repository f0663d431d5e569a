"""A corpus build's chunks kept on disk as they come back, so that a killed build resumes where it stopped.

Chunk ``k`` of a build depends only on ``(seed, k)`` and the recipe (dataset/build.py, synthesis/object_build.py),
so a chunk computed before a kill is the chunk a new run would compute, and a resumed corpus is the same bytes
as one built in a go (tests/test_chunk_spool.py). The spool is a folder beside the output, ``.<out>.chunks/``:

    recipe.json        the build's identity without its clip count (a longer or shorter build of the same recipe
                       reuses the chunks; another recipe is refused, and ``--force`` discards them)
    chunk-0000012.npz  one per chunk, written atomically (infra.atomic): its arrays, and the rest as JSON

It is removed once the dataset is written. A build that fails after its synthesis (a full disk when the dataset
is written, a kill) keeps it, so the minutes of synthesis are not lost: the same command picks them up.
No pickle: every field is an array, a dataclass of the types the build names, or JSON.
"""

from __future__ import annotations

import collections
import dataclasses
import io
import itertools
import json
import os
import sys
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from handx_jax.dataset.parallel import map_ordered
from handx_jax.infra.atomic import atomic_write_bytes, atomic_write_json, remove_tree
from handx_jax.infra.errors import DataError

_JSON = "__json__"


class ChunkSpool:
    """The chunks of one build of ``out`` (see the module docstring). ``recipe``: the build's recipe (its clip count
    is left out of the spool's identity); ``types``: the dataclasses a chunk result is made of."""

    def __init__(self, out: str | os.PathLike, recipe: dict, types: tuple[type, ...], *, discard_other: bool = False):
        out = Path(out)
        self.dir = out.with_name(f".{out.name}.chunks")
        self.identity = json.loads(json.dumps({k: v for k, v in recipe.items() if k != "clips"}))  # as it reads back
        self._types = {t.__qualname__: t for t in types}
        self.resumed = 0
        held = self._held_identity()
        if held is not None and held != self.identity:
            n = len(list(self.dir.glob("chunk-*.npz")))
            if not discard_other:
                raise DataError(f"holds {n} chunks of an unfinished build of another recipe (seed {held.get('seed')}, "
                                f"{held.get('kind')}); rerun that build's command to finish it, or pass --force to "
                                "discard them", path=self.dir)
            remove_tree(self.dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        if held != self.identity:
            atomic_write_json(self.dir / "recipe.json", self.identity)

    def _held_identity(self) -> dict | None:
        try:  # recipe.json is written before any chunk: without it the spool holds nothing
            return json.loads((self.dir / "recipe.json").read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            return {}  # unreadable: not this recipe's

    def path(self, k: int) -> Path:
        return self.dir / f"chunk-{k:07d}.npz"

    def save(self, k: int, result: Any) -> None:
        arrays: dict[str, np.ndarray] = {}
        meta = _encode(result, "r", arrays)
        buf = io.BytesIO()
        np.savez(buf, **arrays, **{_JSON: np.frombuffer(json.dumps(meta).encode(), np.uint8)})
        atomic_write_bytes(self.path(k), buf.getvalue())

    def load(self, k: int) -> Any | None:
        """Chunk ``k`` as it was saved, or None where it is missing or unreadable (then it is computed again)."""
        p = self.path(k)
        if not p.exists():
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                arrays = {name: z[name] for name in z.files}
            return _decode(json.loads(arrays.pop(_JSON).tobytes()), arrays, self._types)
        except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as e:
            print(f"handx: {p} is unreadable ({type(e).__name__}); computing that chunk again", file=sys.stderr)
            return None

    def chunks(self, compute: Callable[[int], Any], workers: int) -> Iterator[Any]:
        """Chunk results in order: those saved (from chunk 0 up to the first missing one), then ``compute(k)`` for
        the rest, ``workers`` at a time (dataset.parallel.map_ordered), each saved as it comes back."""
        k = 0
        while (r := self.load(k)) is not None:
            if k == 0:
                print(f"handx: resuming the build from {self.dir}", file=sys.stderr)
            yield r
            k += 1
        self.resumed = k
        for r in map_ordered(compute, itertools.count(k), workers):
            self.save(r.chunk_index, r)
            yield r

    def remove(self) -> None:
        remove_tree(self.dir)


def _encode(x: Any, key: str, arrays: dict[str, np.ndarray]) -> Any:
    if isinstance(x, np.ndarray):
        arrays[key] = x
        return {"array": key}
    if isinstance(x, np.generic):
        return {"scalar": x.dtype.str, "value": x.item()}
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return {"dataclass": type(x).__qualname__,
                "fields": {f.name: _encode(getattr(x, f.name), f"{key}.{f.name}", arrays) for f in dataclasses.fields(x)}}
    if isinstance(x, collections.Counter):
        return {"counter": [[_encode(k, f"{key}.k{i}", arrays), v] for i, (k, v) in enumerate(x.items())]}
    if isinstance(x, dict):
        if not all(isinstance(k, str) for k in x):
            raise TypeError(f"{key}: a dict with keys that are not strings cannot be spooled")
        return {"dict": {k: _encode(v, f"{key}.{k}", arrays) for k, v in x.items()}}
    if isinstance(x, tuple):
        return {"tuple": [_encode(v, f"{key}.{i}", arrays) for i, v in enumerate(x)]}
    if isinstance(x, list):
        return [_encode(v, f"{key}.{i}", arrays) for i, v in enumerate(x)]
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    raise TypeError(f"{key}: a {type(x).__name__} cannot be spooled")


def _decode(x: Any, arrays: dict[str, np.ndarray], types: dict[str, type]) -> Any:
    if isinstance(x, list):
        return [_decode(v, arrays, types) for v in x]
    if not isinstance(x, dict):
        return x
    if "array" in x:
        return arrays[x["array"]]
    if "scalar" in x:
        return np.dtype(x["scalar"]).type(x["value"])
    if "dataclass" in x:
        return types[x["dataclass"]](**{k: _decode(v, arrays, types) for k, v in x["fields"].items()})
    if "counter" in x:
        return collections.Counter({_decode(k, arrays, types): v for k, v in x["counter"]})
    if "dict" in x:
        return {k: _decode(v, arrays, types) for k, v in x["dict"].items()}
    if "tuple" in x:
        return tuple(_decode(v, arrays, types) for v in x["tuple"])
    raise ValueError(f"not a spooled value: {sorted(x)}")
