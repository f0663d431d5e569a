"""Normalisation statistics (reference §1.8): ``NormStats`` (z-scoring, stored in a dataset's ``stats.npz``),
``NormPreset`` (how one representation's statistics are computed; the presets live beside their layouts and
the registry names which a family uses), and their streamed computation over chunks or processes."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, Mapping

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.representation.geometry import Convention


@dataclass(frozen=True)
class NormStats:
    """Z-scoring statistics: ``normalize(x) = (x − mean) / (std + eps)``.

    ``mean`` and ``std`` have the feature shape ((42,4) diffusion, (288,) AR, (126,) evaluator) and are
    stored as float32. ``eps`` is 1e-6 for the AR preset (§1.8: loaders add 1e-6 to the std), else 0.
    The operators also work on JAX arrays.
    """

    mean: np.ndarray
    std: np.ndarray
    eps: float = 0.0

    def __post_init__(self) -> None:
        mean = np.array(self.mean, dtype=np.float32)
        std = np.array(self.std, dtype=np.float32)
        if mean.shape != std.shape:
            raise ValueError(f"NormStats: mean shape {mean.shape} != std shape {std.shape}")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(std))):
            raise ValueError("NormStats: mean/std contain non-finite values")
        if np.any(std + np.float32(self.eps) <= 0):
            raise ValueError("NormStats: std + eps must be positive")
        mean.setflags(write=False)
        std.setflags(write=False)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)
        object.__setattr__(self, "eps", float(self.eps))

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.mean.shape)

    def normalize(self, x):
        return (x - self.mean) / (self.std + np.float32(self.eps))

    def denormalize(self, z):
        return z * (self.std + np.float32(self.eps)) + self.mean

    def to_npz_dict(self, name: str) -> dict[str, np.ndarray]:
        """``{name}_mean``, ``{name}_std`` (the dataset's stats.npz keys) and ``{name}_eps``."""
        return {f"{name}_mean": self.mean, f"{name}_std": self.std, f"{name}_eps": np.asarray(self.eps)}

    @classmethod
    def from_npz_dict(cls, d: Mapping[str, np.ndarray], name: str, *, eps: float | None = None,
                      path=None) -> NormStats:
        """Read back :meth:`to_npz_dict` output. ``eps`` precedence: argument, ``{name}_eps`` key, preset, 0.
        A missing key or unusable values are a ``DataError`` naming ``path`` (the file ``d`` came from)."""
        from handx_jax.infra.errors import DataError

        for key in (f"{name}_mean", f"{name}_std"):
            if key not in d:
                raise DataError(f"normalisation stats {name!r}: missing (the file holds {', '.join(sorted(d)) or 'nothing'})",
                                path=path, field=key)
        mean, std = np.asarray(d[f"{name}_mean"]), np.asarray(d[f"{name}_std"])
        if eps is None:
            if f"{name}_eps" in d:
                eps = float(np.asarray(d[f"{name}_eps"]))
            else:
                try:
                    eps = norm_preset(name).eps
                except ValueError:  # statistics no registered family or trainable declares
                    eps = 0.0
        try:
            return cls(mean=mean, std=std, eps=eps)
        except ValueError as e:
            raise DataError(f"normalisation stats {name!r}: {str(e).removeprefix('NormStats: ')}", path=path) from None

    @classmethod
    def read(cls, path, name: str) -> NormStats:
        """The statistics ``name`` of a ``.npz`` file (a run's norm file, a dataset's stats.npz), through the
        project's one reader (``infra.readers``: a garbage, truncated or object-array file is one line naming it)."""
        from handx_jax.infra.readers import read_npz

        return cls.from_npz_dict(read_npz(path, kind="f"), name, path=path)


@dataclass(frozen=True)
class NormPreset:
    """How stats are computed for one representation (§1.8, §5.3): ``featurize(joints, convention)`` →
    features ending in ``feature_shape``; ``name`` is its ``stats.npz`` prefix. Which presets a family
    normalises with, and so which a dataset's ``stats.npz`` holds, is the registry's (``Family.norm``,
    ``families.TRAINABLE_NORMS``: ``families.norm_presets``, passed down to the dataset writer)."""

    name: str
    feature_shape: tuple[int, ...]
    min_std: float
    eps: float = 0.0
    featurize: Callable[..., np.ndarray] | None = None

    def __post_init__(self):
        # Every preset is known by its name from the moment it is defined (the package's beside their layouts,
        # imported with this package; a family's own when the registry resolves its ``Family.norm``), so this
        # room looks presets up without asking the registry above it; the first of a name stays.
        _PRESETS.setdefault(self.name, self)


_PRESETS: dict[str, NormPreset] = {}


def norm_preset(name: str) -> NormPreset:
    """The preset defined under the ``stats.npz`` prefix ``name`` (the one a family's ``Family.norm`` names)."""
    if name not in _PRESETS:
        raise ValueError(f"unknown normalisation preset {name!r}; expected one of {tuple(_PRESETS)}")
    return _PRESETS[name]


def norm_presets() -> dict[str, NormPreset]:
    """Every preset defined so far, by its ``stats.npz`` prefix, in the order they were defined."""
    return dict(_PRESETS)


def _iter_chunks(x: np.ndarray | Iterable[np.ndarray], chunk_size: int) -> Iterator[np.ndarray]:
    if isinstance(x, np.ndarray):
        if x.ndim == 0:
            raise ValueError("compute_norm_stats: need at least one axis to reduce")
        for i in range(0, x.shape[0], chunk_size):
            yield x[i:i + chunk_size]
    else:
        for c in x:
            yield np.asarray(c)


def compute_norm_stats(x: np.ndarray | Iterable[np.ndarray], *, axis: int | tuple[int, ...] | None = None,
                       min_std: float, eps: float = 0.0, chunk_size: int = 1024) -> NormStats:
    """Mean/std over ``axis`` (reference §1.8), accumulated in float64 and streamed in chunks.

    ``x`` is an array (memory-mapped is fine: it is read ``chunk_size`` entries of axis 0 at a time)
    or an iterable of chunks that are concatenated along axis 0. ``axis`` (default: all but the last)
    must include 0. std = sqrt(max(E[x²] − E[x]², 0)); entries with std < min_std become 1.
    """
    if chunk_size < 1:
        raise ValueError("compute_norm_stats: chunk_size must be ≥ 1")
    s = ss = None
    n = 0
    axes: tuple[int, ...] | None = None
    feat_shape: tuple[int, ...] | None = None
    for c in _iter_chunks(x, chunk_size):
        if axes is None:
            nd = c.ndim
            raw = tuple(range(max(nd - 1, 1))) if axis is None else ((axis,) if isinstance(axis, int) else tuple(axis))
            axes = tuple(sorted({a % nd for a in raw})) if nd else ()
            if 0 not in axes:
                raise ValueError(f"compute_norm_stats: axis {axis} must include axis 0 (the streamed axis)")
            feat_shape = tuple(c.shape[a] for a in range(nd) if a not in axes)
        elif c.ndim != nd or tuple(c.shape[a] for a in range(nd) if a not in axes) != feat_shape:
            raise ValueError(f"compute_norm_stats: chunk shape {c.shape} does not match the first chunk")
        if c.shape[0] == 0:
            continue
        cs, css, cn = _moments(c, axes)
        s, ss = (cs, css) if s is None else (s + cs, ss + css)
        n += cn
    return _stats_from_sums(s, ss, n, min_std=min_std, eps=eps)


def _moments(c: np.ndarray, axes: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, int]:
    c64 = c.astype(np.float64, copy=False)
    return c64.sum(axis=axes), np.square(c64).sum(axis=axes), int(np.prod([c.shape[a] for a in axes]))


def _stats_from_sums(s, ss, n: int, *, min_std: float, eps: float) -> NormStats:
    if n == 0:
        raise ValueError("compute_norm_stats: no data")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(ss))):
        raise ValueError("compute_norm_stats: the data contain NaN or inf")
    mean = s / n
    std = np.sqrt(np.maximum(ss / n - mean * mean, 0.0))
    std = np.where(std < min_std, 1.0, std)
    return NormStats(mean=mean, std=std, eps=eps)


def compute_preset_stats(kind: str, features: np.ndarray | Iterable[np.ndarray], *,
                         chunk_size: int = 1024) -> NormStats:
    """Stats of already-computed features with the preset ``kind`` ("diffusion", "ar", "evaluator").

    Every axis before the preset's feature shape is reduced (e.g. clips and frames).
    """
    pr = norm_preset(kind)
    flat = (_flat_features(kind, c) for c in _iter_chunks(features, chunk_size))
    return compute_norm_stats(flat, axis=0, min_std=pr.min_std, eps=pr.eps, chunk_size=chunk_size)


def _flat_features(kind: str, c: np.ndarray) -> np.ndarray:
    fs = norm_preset(kind).feature_shape
    if c.ndim <= len(fs) or tuple(c.shape[-len(fs):]) != fs:
        raise ValueError(f"{kind} stats: features must end in {fs}, got {c.shape}")
    return c.reshape(-1, *fs)


def preset_moments(kind: str, features: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Float64 sum, sum of squares and count of one chunk of preset ``kind``'s features, reduced over
    every axis before the feature shape: what :func:`compute_preset_stats` adds up per chunk, for
    summing chunks computed elsewhere (another process) and finishing with :func:`stats_from_moments`."""
    return _moments(_flat_features(kind, np.asarray(features)), (0,))


def stats_from_moments(kind: str, s: np.ndarray, ss: np.ndarray, n: int) -> NormStats:
    """Mean/std under preset ``kind`` from summed :func:`preset_moments`."""
    pr = norm_preset(kind)
    return _stats_from_sums(s, ss, n, min_std=pr.min_std, eps=pr.eps)


def motion_norm_stats(kind: str, motion_NxTx2x21x3: np.ndarray, *, convention: Convention = "paper",
                      chunk_size: int = 256) -> NormStats:
    """Stats of representation ``kind`` over a (possibly memory-mapped) motion array, streamed by clips.

    Features are computed ``chunk_size`` clips at a time and reduced over clips and frames, so each
    clip counts once (§1.8).
    """
    featurize = norm_preset(kind).featurize
    m = motion_NxTx2x21x3
    if m.ndim != 5 or tuple(m.shape[2:]) != (2, sk.NUM_JOINTS, 3):
        raise ValueError(f"motion_norm_stats: expected (N, T, 2, 21, 3), got {tuple(m.shape)}")

    def feats() -> Iterator[np.ndarray]:
        for i in range(0, m.shape[0], chunk_size):
            yield featurize(np.asarray(m[i:i + chunk_size]), convention)

    return compute_preset_stats(kind, feats(), chunk_size=chunk_size)
