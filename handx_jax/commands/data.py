"""``handx data``: build, import, export, inspect and render datasets."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from handx_jax.cliargs import deprecated_positional
from handx_jax.infra.errors import DataError
from handx_jax.infra.values import number_flag, whole_flag


def _data_arg(s) -> None:
    """``--data DIR``; the positional spelling of earlier releases still works, with a notice."""
    deprecated_positional(s, s.add_argument("--data", required=True, metavar="DIR", help="dataset directory"), "data")


def _build_args(s) -> None:
    """The corpus-build options of ``handx data synth`` and ``handx data objects``, each checked while the command
    line is parsed (``infra.values``): nothing is built or written for a bad value."""
    s.add_argument("--clips", type=whole_flag(1), required=True, help="number of clips to keep")
    s.add_argument("--seed", type=whole_flag(0), default=0)
    s.add_argument("--out", required=True, help="dataset directory to create")
    s.add_argument("--workers", type=whole_flag(0), default=0, help="processes (0 = one per core)")
    s.add_argument("--val-fraction", type=number_flag(above=0, below=1), default=0.05,
                   help="share of the sequences in the validation split, in (0, 1) (default 0.05)")
    s.add_argument("--test-fraction", type=number_flag(above=0, below=1), default=0.05,
                   help="share of the sequences in the test split, in (0, 1); with --val-fraction below 1 "
                        "(default 0.05)")
    s.add_argument("--force", action="store_true", help="replace an existing dataset directory")
    s.add_argument("--quiet", action="store_true", help="no progress bar")


def add_parser(subparsers) -> None:
    from handx_jax.dataset.clips import defect_reasons_help
    from handx_jax.standard.recipe import STANDARD_ANNOTATION, STANDARD_MOTION
    from handx_jax.synthesis.bimanual import MOTIONS

    p = subparsers.add_parser("data", help="datasets: synthesise, import/export HandX .npz, stats, render",
                              description="Build, import, export, inspect and render datasets.")
    sub = p.add_subparsers(dest="data_command", metavar="SUBCOMMAND")
    sub.required = True

    s = sub.add_parser("synth", help="build the procedural bimanual corpus",
                       description="Synthesise two-hand motion with forward kinematics, cut and filter clips "
                                   "(paper A.3-A.4), annotate them (App. B) and write a dataset.",
                       epilog="Cut report: " + defect_reasons_help())
    _build_args(s)
    # The defaults build the standard corpus's recipe (corpus v5, standard.Recipe; issues 51 item 3, 55): with
    # the default seed and fractions, the first --clips clips of the standard corpus, a prefix `handx standard
    # check` accepts. The older readings and motions stay by name for the committed results that used them
    # (corpus v4, 'gist' on 'chain', is the archived evaluator v7's: --evaluator standard-v7).
    s.add_argument("--annotation", default=STANDARD_ANNOTATION, choices=("reference", "stable", "gist", "surface"),
                   help=f"annotation reading (default {STANDARD_ANNOTATION!r}, the standard corpus's): 'gist' (stable, "
                        "plus each finger's curl swings, which level 0 says; corpora v3-v4), 'surface' (gist, with the "
                        "hands' contacts read from the hand surface; corpus v5), 'stable' (smoothed, "
                        "hysteretic states, per-fact wording; corpus v2, docs/validity.md) or 'reference' "
                        "(§6.1-6.2, no smoothing; corpus v1, and what imported official data is read with)")
    s.add_argument("--motion", default=STANDARD_MOTION, choices=MOTIONS,
                   help=f"what a segment's actions do (default {STANDARD_MOTION!r}, the standard corpus's): 'chain' "
                        "(go once from one pose to another, then up to twice more: A to B to C to D; corpus v4), "
                        "'surface' (chain, with the hands resolved against the hand surface: contacts surface to "
                        "surface, no hand through the other; corpus v5), "
                        "'transition' (once, one segment per sequence, the clip filter at 7 deg/s; corpus v3) or "
                        "'oscillate' (go back and forth; corpora v1-v2)")
    s.set_defaults(func=_synth)

    s = sub.add_parser("objects", help="build the procedural hand-object corpus (BimArt, issue 52)",
                       description="Synthesise two hands that take an articulated object (box, laptop, scissors, "
                                   "cabinet, bottle) and lift it (grab) or open and close it (use), keep the clips "
                                   "whose physics holds on every frame, annotate contact maps, held parts and "
                                   "captions, and write a dataset (synthesis/object_build.py).")
    _build_args(s)
    s.add_argument("--categories", default=None,
                   help="comma-separated object categories (default: all of objects.CATEGORIES)")
    s.set_defaults(func=_objects)

    s = sub.add_parser("stats", help="corpus statistics (Table 1(b) quantities, caption uniqueness)")
    _data_arg(s)
    s.add_argument("--json", action="store_true", help="print JSON")
    s.set_defaults(func=_stats)

    s = sub.add_parser("show", help="render one clip as an animated GIF")
    _data_arg(s)
    s.add_argument("--clip", required=True, help="clip index or id")
    s.add_argument("--out", required=True, help="output .gif")
    s.add_argument("--level", type=int, default=0, help="caption level shown (0 = concise, -1 = most detailed)")
    s.set_defaults(func=_show)

    s = sub.add_parser("prompt", help="write the LLM captioning prompt for one clip")
    _data_arg(s)
    s.add_argument("--clip", required=True, help="clip index or id")
    s.add_argument("--out", help="write to this file instead of stdout")
    s.set_defaults(func=_prompt)

    s = sub.add_parser("import-handx", help="import official HandX .npz files into a dataset",
                       description="Import {train,test}_can_pos_all_wotextfeat.npz. The split comes from the "
                                   "file name unless --split is given.",
                       epilog="Cut report: " + defect_reasons_help())
    s.add_argument("files", nargs="+", help="official .npz files")
    s.add_argument("--out", required=True, help="dataset directory to create")
    s.add_argument("--split", choices=("train", "val", "test"), help="split for all given files")
    s.add_argument("--no-events", action="store_true", help="skip computing event records")
    s.add_argument("--force", action="store_true", help="replace an existing dataset directory")
    s.set_defaults(func=_import)

    s = sub.add_parser("export-handx", help="export a dataset in the official HandX .npz layout")
    _data_arg(s)
    s.add_argument("--out", required=True, help="output .npz")
    s.add_argument("--split", choices=("all", "train", "val", "test"), default="all")
    s.set_defaults(func=_export)

    s = sub.add_parser("reverse", help="a split's clips played backwards, annotated and captioned again",
                       description="Write a dataset of DATA's clips time-reversed, annotated with DATA's own reading "
                                   "and captioned with its wording and caption seeds, all in its train split: the "
                                   "order of events as training pairs for the evaluator "
                                   "(handx train evaluator --set data.reversed_path=OUT; docs/validity.md).")
    _data_arg(s)
    s.add_argument("--out", required=True, help="dataset directory to create")
    s.add_argument("--split", choices=("train", "val", "test"), default="train", help="the split to reverse")
    s.add_argument("--clips", type=whole_flag(1), default=None,
                   help="at most this many clips, evenly spaced over the split")
    s.add_argument("--workers", type=whole_flag(0), default=0, help="processes (0 = one per core)")
    s.add_argument("--force", action="store_true", help="replace an existing dataset directory")
    s.set_defaults(func=_reverse)

    s = sub.add_parser("verify", help="check a dataset's files against its recorded fingerprint")
    _data_arg(s)
    s.set_defaults(func=_verify)


def _clip_index(ds, clip: str) -> int:
    if clip.lstrip("-").isdigit():
        i = int(clip)
        if not -len(ds) <= i < len(ds):
            raise DataError(f"clip index {i} out of range (dataset has {len(ds)} clips)")
        return i % len(ds)
    try:
        return ds.ids.index(clip)
    except ValueError:
        raise DataError(f"no clip with id {clip!r} in {ds.root}") from None


def dataset_norms() -> tuple:
    """The normalisation presets a dataset's ``stats.npz`` holds: every one the family registry declares,
    asked for here, above the dataset room, and passed down to its writer."""
    from handx_jax.families import norm_presets

    return tuple(norm_presets().values())


def _synth(a: argparse.Namespace) -> int:
    from handx_jax.dataset.build import BuildConfig, build_corpus, with_motion, with_reading
    from handx_jax.dataset.format import Dataset
    from handx_jax.dataset.stats import dataset_stats, format_stats
    from handx_jax.commands import fail
    from handx_jax.config import ConfigError
    from handx_jax.infra.values import check_split_fractions

    try:  # the two fractions together (each flag was checked as it was parsed)
        check_split_fractions(a.val_fraction, a.test_fraction, names=("--val-fraction", "--test-fraction"))
    except ConfigError as e:
        return fail("handx data synth", e)
    cfg = with_reading(with_motion(BuildConfig(clips=a.clips, seed=a.seed, workers=a.workers,
                                               val_fraction=a.val_fraction, test_fraction=a.test_fraction),
                                   a.motion), a.annotation)
    out = build_corpus(a.out, cfg, overwrite=a.force, progress=not a.quiet, stats=dataset_norms())
    ds = Dataset.open(out)
    rep = ds.report
    print(f"wrote {out}  ({len(ds)} clips in {rep.get('seconds')} s, {rep.get('clips_per_second')} clips/s)")
    c = rep.get("clips", {})
    print(f"cut: {c.get('windows', 0)} windows from {c.get('sequences', 0)} sequences; "
          f"defective frames {c.get('defective_frames', {})}; rejected by intensity {c.get('rejected_intensity', {})}")
    print(format_stats(dataset_stats(ds, workers=a.workers or os.cpu_count() or 1)))
    return 0


def _objects(a: argparse.Namespace) -> int:
    import dataclasses

    from handx_jax.dataset.format import Dataset
    from handx_jax.infra.errors import DataError
    from handx_jax.objects import CATEGORIES
    from handx_jax.synthesis.object_build import ObjectBuildConfig, build_object_corpus

    if a.clips < 1:
        raise DataError(f"--clips is {a.clips}; it must be a whole number >= 1")
    cfg = ObjectBuildConfig(clips=a.clips, seed=a.seed, workers=a.workers, val_fraction=a.val_fraction,
                            test_fraction=a.test_fraction)
    if a.categories:
        cats = tuple(c.strip() for c in a.categories.split(",") if c.strip())
        bad = [c for c in cats if c not in CATEGORIES]
        if bad or not cats:
            raise DataError(f"--categories: unknown {', '.join(bad) or '(none given)'}; known: {', '.join(CATEGORIES)}")
        cfg = dataclasses.replace(cfg, synth=dataclasses.replace(cfg.synth, categories=cats))
    out = build_object_corpus(a.out, cfg, overwrite=a.force, progress=not a.quiet)
    ds = Dataset.open(out)
    rep = ds.report
    print(f"wrote {out}  ({len(ds)} clips in {rep.get('seconds')} s, {rep.get('clips_per_second')} clips/s; "
          f"splits {ds.meta['split_sizes']})")
    print(f"synthesised {rep['synthesised_clips']}, rejected by physics {rep['rejected_by_physics']}")
    print(json.dumps(rep["statistics"], indent=1))
    return 0


def _reverse(a: argparse.Namespace) -> int:
    from handx_jax.dataset.reverse import build_reversed

    out = build_reversed(a.data, a.out, split=a.split, limit=a.clips, workers=a.workers, overwrite=a.force,
                         stats=dataset_norms())
    print(f"wrote {out}")
    return 0


def _stats(a: argparse.Namespace) -> int:
    from handx_jax.dataset.format import Dataset
    from handx_jax.dataset.stats import dataset_stats, format_stats

    st = dataset_stats(Dataset.open(a.data))
    print(json.dumps(st, indent=2) if a.json else format_stats(st))
    return 0


def _show(a: argparse.Namespace) -> int:
    import numpy as np

    from handx_jax.dataset.format import Dataset
    from handx_jax.dataset.render import render_gif

    ds = Dataset.open(a.data)
    i = _clip_index(ds, a.clip)
    t = ds.texts[i]
    lv = a.level
    levels = len(t["left"])
    if not -levels <= lv < levels:
        raise DataError(f"--level {lv} out of range: {ds.root} has {levels} caption levels "
                        f"(0..{levels - 1}, or -{levels}..-1 from the most detailed)")
    texts = (t["left"][lv], t["right"][lv], t["interaction"][lv])
    if (ds.root / "objects.jsonl").exists():  # a hand-object corpus: the object beside the hands
        from handx_jax.synthesis.object_render import render_object_clip

        out = render_object_clip(ds.root, i, a.out, texts=texts, title=t["id"])
    else:
        out = render_gif(np.asarray(ds.motion[i]), a.out, texts=texts, title=t["id"])
    print(f"wrote {out}")
    return 0


def _prompt(a: argparse.Namespace) -> int:
    import numpy as np

    from handx_jax.annotation.caption import build_prompt
    from handx_jax.dataset.format import Dataset
    from handx_jax.annotation.events import annotate
    from handx_jax.infra.atomic import atomic_write_text

    ds = Dataset.open(a.data)
    i = _clip_index(ds, a.clip)
    record = ds.events[i] if ds.events is not None else annotate(np.asarray(ds.motion[i:i + 1]))[0]
    text = build_prompt(record)
    if a.out:
        atomic_write_text(a.out, text)
        print(f"wrote {a.out}", file=sys.stderr)
    else:
        print(text)
    return 0


def _import(a: argparse.Namespace) -> int:
    from handx_jax.interop.convert import import_handx
    from handx_jax.dataset.format import Dataset

    out = import_handx(a.files, a.out, split=a.split, annotate_events=not a.no_events, overwrite=a.force,
                       stats=dataset_norms())
    ds = Dataset.open(out)
    print(f"imported {len(ds)} clips into {out}; splits {ds.meta['split_sizes']}; report {json.dumps(ds.report.get('dropped_nonfinite_clips', {}))}")
    return 0


def _export(a: argparse.Namespace) -> int:
    from handx_jax.interop.convert import export_handx

    print(f"wrote {export_handx(a.data, a.out, split=a.split)}")
    return 0


def _verify(a: argparse.Namespace) -> int:
    from handx_jax.dataset.format import Dataset

    ds = Dataset.open(a.data)
    ds.verify()
    print(f"{Path(a.data)}: ok ({len(ds)} clips, fingerprint {ds.fingerprint})")
    return 0
