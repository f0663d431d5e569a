"""The validity suite (issue 40): does the yardstick read what the captions say?

``handx standard validity --data D --out DIR`` perturbs the ground-truth test clips of D
(``perturb.KINDS``: caption-preserving noise, offsets and shifts across amplitudes; time reversal, another
clip's motion and the edits of which hand or finger does what, which change the meaning) and reports, per
perturbation and amplitude:

- caption stability (``stability``): the share of descriptor event lists (their labels: states,
  speeds, directions; and with their frames) and of captions per level left unchanged when the
  perturbed clips are annotated and captioned again with the corpus's own reading and seeds;
- the evaluator (``scores``): Top-3 R-Precision and FID of the perturbed clips scored as generated,
  Top-3 as a ratio to the ground truth's; and the same for each ``--tokenizer``'s reconstruction of
  the ground truth (with its wrist-relative finger error in mm).

Writes ``DIR/validity.json``, ``DIR/validity.md`` (the tables) and ``DIR/validity.png`` (Top-3 ratio
and level-0 captions unchanged against the millimetres moved, one curve per kind).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from handx_jax.config import ConfigError
from handx_jax.infra.atomic import atomic_write_text
from handx_jax.infra.outputs import check_out_apart, remove_stale_temporaries
from handx_jax.infra.values import check
from handx_jax.validity import perturb as P
from handx_jax.validity import stability as S
from handx_jax.dataset.build import corpus_seed, reading_of
from handx_jax.validity.scores import Scorer, caption_reader_top3, order_test

SCHEMA = 1
REPORT_FILES = ("validity.json", "validity.md", "validity.png")  # validity.json first: it marks a whole report
# Top-3 R-Precision ranks each clip's caption among ``block`` candidates: with 3 or fewer it is 1 for any
# motion at all (``block`` 1 scored 1.000 at every amplitude), so a block must hold more than 3.
MIN_BLOCK = 4
BLOCK_WHY = "top-3 R-Precision among 3 or fewer candidates is 1 for any motion"


def check_args(*, block: int, seed: int, limit: int | None, kinds: Sequence[str] | None) -> None:
    """The suite's settings, refused (``ConfigError``, a ValueError naming the flag) before any work."""
    check(block, "--block", whole=True, minimum=MIN_BLOCK, why=BLOCK_WHY)
    check(seed, "--seed", whole=True, minimum=0)
    if limit is not None:
        check(limit, "--limit", whole=True, minimum=2, why="another clip's motion needs two clips")
    if kinds is not None:
        if not kinds:
            raise ConfigError(f"--kinds names no perturbation kind; choose from {', '.join(P.KINDS)} (or leave "
                              "--kinds out for all of them)")
        bad = [k for k in kinds if k not in P.KINDS]
        if bad:
            raise ConfigError(f"--kinds {','.join(bad)}: unknown; choose from {', '.join(P.KINDS)}")


def run(data: str, out: str, *, evaluator: str | None = "standard", tokenizers: Sequence[str] = (),
        annotation: str | None = None, limit: int | None = None, block: int = 32, seed: int = 0,
        kinds: Sequence[str] | None = None, log=print) -> dict:
    """Run the suite on ``data``'s test split and write the report into the folder ``out`` (see the module
    doc). Everything it is given is checked first (settings, ``out`` apart from ``data``, each tokenizer
    run loaded); ``out``'s lock is held from then on, so a second suite writing the same folder is refused."""
    from handx_jax.infra.runlock import RunLock

    check_args(block=block, seed=seed, limit=limit, kinds=kinds)
    check_out_apart(out, data, replaces=False)
    with RunLock.for_output(out):
        remove_stale_temporaries(Path(out))
        _remove_partial_report(Path(out))
        return _run(data, out, evaluator=evaluator, tokenizers=tokenizers, annotation=annotation, limit=limit,
                    block=block, seed=seed, kinds=kinds, log=log)


def _run(data, out, *, evaluator, tokenizers, annotation, limit, block, seed, kinds, log) -> dict:
    from handx_jax.annotation.caption import TemplateCaptioner
    from handx_jax.dataset.format import Dataset
    from handx_jax.annotation.events import annotation_config
    from handx_jax.families import tokenizer as T
    from handx_jax.generation import split_prompts

    loaded = [(str(t), T.load(t)) for t in tokenizers]  # a bad run is refused now, not after the scoring
    ds = Dataset.open(data)
    named = None
    if evaluator:  # a bad --evaluator, or one that does not score this dataset: refused before any work
        from handx_jax.standard.naming import resolve_evaluator

        named = resolve_evaluator(evaluator)
        named.check_data(ds)
    clips, prompts, motion = split_prompts(ds, "test", limit, 0)
    if len(clips) < 2:
        raise ValueError(f"{data}: the test split has {len(clips)} clip(s); the suite needs at least 2")
    gt = np.stack(motion).astype(np.float32)
    ids = [ds.ids[c] for c in clips]
    found_reading, wording = reading_of(ds)
    reading = annotation or found_reading
    if reading != found_reading:  # another reading than the corpus's: its own wording goes with it
        from handx_jax.dataset.build import WORDING

        wording = WORDING[reading]
    t0 = time.perf_counter()
    ann = S.Annotator(gt, ids, corpus_seed(ds), annotation_config(reading), TemplateCaptioner(wording))
    stored = [tuple(ds.texts[c][f][0] for f in ("left", "right", "interaction")) for c in clips]
    reproduces = float(np.mean([s == c[0] for s, c in zip(stored, ann.clean_captions)]))
    report: dict = {
        "schema": SCHEMA, "data": str(Path(data).resolve()), "test_clips": len(clips), "block": block,
        "annotation": reading, "wording": wording, "perturbation_seed": seed,
        "stored_captions_reproduced": reproduces,
        "clean": S.variety(ann.clean_records, ann.clean_captions),
        "cases": [],
    }
    log(f"{len(clips)} test clips; annotation {reading!r}, wording {wording!r}; the clean re-annotation "
        f"reproduces {reproduces:.0%} of the stored level-0 captions")
    scorer = None
    if named is not None:
        ev, cache = named.load(), named.reference_cache(default=False)
        report["evaluator"] = {"name": named.name, "id": str(evaluator)} if named.standard else {"name": str(evaluator)}
        scorer = Scorer(ev, ds, clips, prompts, block=block, cache=cache)
        report["ground_truth"] = scorer.score(gt)
        clean0 = [c[0] for c in ann.clean_captions]
        clean_text = scorer.ev.embed_text(*zip(*clean0))  # once: every case's reader ranks against it
        report["ground_truth"]["caption_reader_top3"] = caption_reader_top3(scorer.ev, clean_text, clean0, block=block)
        log(f"ground truth: top-3 {report['ground_truth']['rprec_top3']:.3f}")
    names = list(kinds) if kinds else list(P.KINDS)
    for name in names:
        kind = P.KINDS[name]
        for amp in kind.amplitudes_m:
            y = P.apply(name, gt, amp, seed)
            recs, caps = ann.records_and_captions(y)
            case = {"kind": name, "label": kind.label, "preserving": kind.preserving, "amplitude_mm": amp * 1000,
                    "mean_shift_mm": P.mean_shift_mm(gt, y),
                    **S.compare(ann.clean_records, recs, ann.clean_captions, caps)}
            if scorer is not None:
                case.update(_eval_row(scorer.score(y), report["ground_truth"]))
                case.update(_reader_row(scorer.ev, clean_text, caps, report["ground_truth"], block))
                if name == "reverse":
                    report["order"] = order_test(scorer.ev, gt, y, clean0, [c[0] for c in caps], clean_text)
                    log(_order_line(report["order"]))
                elif name in P.HARD_NEGATIVE_KINDS:  # the same two-way choice for the which/who edits (issue 55)
                    report.setdefault("which", {})[name] = order_test(scorer.ev, gt, y, clean0, [c[0] for c in caps],
                                                                      clean_text)
                    log(_order_line(report["which"][name], kind.label))
            report["cases"].append(case)
            log(_line(case))
    report["tokenizers"] = []
    for tok, tok_run in loaded:
        from handx_jax.validity.scores import finger_error_mm, hybrids, tokenizer_reconstruction, wrist_path_error_mm

        y = tokenizer_reconstruction(tok_run, gt)
        recs, caps = ann.records_and_captions(y)
        case = {"tokenizer": str(tok), "mean_shift_mm": P.mean_shift_mm(gt, y), "finger_error_mm": finger_error_mm(gt, y),
                "wrist_path_error_mm": wrist_path_error_mm(gt, y),
                **S.compare(ann.clean_records, recs, ann.clean_captions, caps)}
        if scorer is not None:
            case.update(_eval_row(scorer.score(y), report["ground_truth"]))
            case.update(_reader_row(scorer.ev, clean_text, caps, report["ground_truth"], block))
            # Which error costs the score: each part of the reconstruction alone on the ground truth.
            for part, z in hybrids(gt, y).items():
                case[f"{part}_only_top3_ratio"] = _eval_row(scorer.score(z), report["ground_truth"])["top3_ratio"]
                if part == "articulation":
                    case["articulation_error_mm"] = finger_error_mm(gt, z)
        report["tokenizers"].append(case)
        log(f"tokenizer {tok}: {_line(case)}")
    report["seconds"] = round(time.perf_counter() - t0, 1)
    write_report(Path(out), report)
    return report


def write_report(out: Path, report: dict) -> None:
    """``validity.json``, ``.md`` and ``.png`` as one unit. All three are rendered into a temporary sibling
    of ``out`` first (a kill there leaves ``out`` as it was; the next run removes the temporary); then the
    old report's files go, ``validity.json`` first, and the new ones move in with ``validity.json`` last.
    ``validity.json`` therefore marks a whole report: the md and png beside it are of the same run. Other
    files in ``out`` (a results folder's README) are left alone."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        atomic_write_text(tmp / REPORT_FILES[0], json.dumps(report, indent=1) + "\n")
        atomic_write_text(tmp / REPORT_FILES[1], markdown(report))
        figure(report, tmp / REPORT_FILES[2])
        out.mkdir(exist_ok=True)
        for name in REPORT_FILES:  # the marker first: never an old json beside a new md
            (out / name).unlink(missing_ok=True)
        for name in reversed(REPORT_FILES):  # the marker last
            os.replace(tmp / name, out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _remove_partial_report(out: Path) -> None:
    """A report without its ``validity.json`` (a writer killed while moving the files in): removed, with a line."""
    left = [n for n in REPORT_FILES[1:] if (out / n).is_file()]
    if left and not (out / REPORT_FILES[0]).is_file():
        for name in left:
            (out / name).unlink(missing_ok=True)
        print(f"handx: removed {', '.join(left)} in {out}: a report without its validity.json, left by a suite "
              "that was killed", file=sys.stderr)


def _reader_row(ev, clean_text_NxD, caps, gt: dict, block: int) -> dict:
    top3 = caption_reader_top3(ev, clean_text_NxD, [c[0] for c in caps], block=block)
    return {"caption_reader_top3": top3, "caption_reader_ratio": top3 / gt["caption_reader_top3"]}


def _order_line(o: dict, edit: str | None = None) -> str:
    """The order test's line, or with ``edit`` (a kind's label) the same two-way choice for that edit."""
    if edit is None:
        test, what, done = "order test", "reversal", "reversed"
    else:
        test, what, done = f"which test, {edit}", "edit", "edited"
    if not o.get("clips"):
        return f"{test}: no clip's {what} reads differently"
    return (f"{test} on {o['clips']} clips whose {what} reads differently (chance 0.5): {'forward ' if edit is None else ''}"
            f"clip nearer its caption {o['forward_picks_own']:.3f}, {done} clip nearer the {done} caption "
            f"{o['reversed_picks_reversed']:.3f}")


def _eval_row(res: dict, gt: dict) -> dict:
    row = {f"eval_{k}": v for k, v in res.items()}
    row["top3_ratio"] = res["rprec_top3"] / gt["rprec_top3"] if gt["rprec_top3"] > 0 else float("nan")
    return row


def _line(c: dict) -> str:
    head = f"{c.get('label', 'reconstruction')}" + (f" {c['amplitude_mm']:g} mm" if c.get("amplitude_mm") else "")
    txt = (f"{head}: moved {c['mean_shift_mm']:.1f} mm; event lists unchanged {c['events_unchanged']:.3f}, "
           f"level-0 captions unchanged {c['captions_unchanged'][0]:.3f}")
    if "eval_rprec_top3" in c:
        txt += f"; top-3 {c['eval_rprec_top3']:.3f} ({c['top3_ratio']:.2f}x GT), FID {c['eval_fid']:.2f}"
    return txt


def markdown(r: dict) -> str:
    ev = r.get("evaluator", {}).get("name")
    lines = [f"# Validity suite: {r['test_clips']} test clips of `{Path(r['data']).name}`", "",
             f"Annotation `{r['annotation']}`, wording `{r['wording']}`; the clean re-annotation reproduces "
             f"{r['stored_captions_reproduced']:.0%} of the stored level-0 captions. Clean: "
             f"{r['clean']['events_per_clip']:.1f} events per clip, distinct level-0 captions "
             f"{r['clean']['distinct_captions'][0]:.0%}.", ""]
    if ev:
        g = r["ground_truth"]
        lines += [f"Evaluator `{ev}`, block {r['block']}: ground truth top-3 {g['rprec_top3']:.3f}, "
                  f"top-1 {g['rprec_top1']:.3f}.", ""]
    hdr = "| perturbation | kind | mean shift (mm) | event lists unchanged (labels / with frames) | captions unchanged L0 / L1 / L4 |"
    sep = "|---|---|---:|---:|---:|"
    if ev:
        hdr += " top-3 | × GT | caption reader × | FID |"
        sep += "---:|---:|---:|---:|"
    lines += [hdr, sep]
    rows = list(r["cases"]) + list(r.get("tokenizers", []))
    for c in rows:
        name = c.get("label") or f"tokenizer `{Path(c['tokenizer']).name}` (fingers {c['finger_error_mm']:.1f} mm)"
        if c.get("amplitude_mm"):
            name += f", {c['amplitude_mm']:g} mm"
        kind = ("keeps meaning" if c["preserving"] else "changes meaning") if "kind" in c else ""
        cu = c["captions_unchanged"]
        line = (f"| {name} | {kind} | {c['mean_shift_mm']:.1f} | {c['events_unchanged']:.3f} / "
                f"{c['events_exact_unchanged']:.3f} | {cu[0]:.3f} / {cu[1]:.3f} / {cu[4]:.3f} |")
        if ev:
            reader = f"{c['caption_reader_ratio']:.2f}" if "caption_reader_ratio" in c else ""
            line += f" {c['eval_rprec_top3']:.3f} | {c['top3_ratio']:.2f} | {reader} | {c['eval_fid']:.2f} |"
        lines.append(line)
    for c in r.get("tokenizers", []):
        if "shape_only_top3_ratio" in c:
            lines += ["", f"Tokenizer `{Path(c['tokenizer']).name}`, its errors apart: the wrist path is "
                      f"{c['wrist_path_error_mm']:.1f} mm off and the fingers {c['finger_error_mm']:.1f} mm about the "
                      f"wrists. The reconstructed shape on the true wrist path keeps {c['shape_only_top3_ratio']:.2f}× "
                      f"the ground truth's top-3, and {c['articulation_only_top3_ratio']:.2f}× once each hand is "
                      f"also turned onto the true palm orientation (the fingers' articulation alone, "
                      f"{c['articulation_error_mm']:.1f} mm); the true shape on the reconstructed wrist path keeps "
                      f"{c['wrist_path_only_top3_ratio']:.2f}×."]
    if r.get("order"):
        lines += ["", f"Order: {_order_line(r['order'])}."]
    for name, o in r.get("which", {}).items():
        label = P.KINDS[name].label if name in P.KINDS else name
        line = _order_line(o, label)
        lines += ["", f"{line[0].upper()}{line[1:]}."]
    if ev:
        lines += ["", "Caption reader ×: the top-3 a reader of the perturbed clips' own captions would get (their "
                  "level-0 captions through the evaluator's text side, ranked against the clean ones), over the "
                  "same reader's on the clean captions."]
    lines += ["", "How to read it: docs/validity.md.", ""]
    return "\n".join(lines)


def figure(r: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    has_ev = "ground_truth" in r
    fig, axes = plt.subplots(1, 2 if has_ev else 1, figsize=(11 if has_ev else 5.5, 4.2), squeeze=False)
    panels = [("captions_unchanged", "level-0 captions unchanged")]
    if has_ev:
        panels.insert(0, ("top3_ratio", "top-3 / ground truth's top-3"))
    by_kind: dict[str, list] = {}
    for c in r["cases"]:
        by_kind.setdefault(c["kind"], []).append(c)
    for ax, (key, ylabel) in zip(axes[0], panels):
        for kind, cs in by_kind.items():
            xs = [max(c["mean_shift_mm"], 1e-2) for c in cs]
            ys = [c[key][0] if key == "captions_unchanged" else c[key] for c in cs]
            style = "-o" if cs[0]["preserving"] else "s"
            ax.plot(xs, ys, style, label=cs[0]["label"] + ("" if cs[0]["preserving"] else " (changes meaning)"))
        for c in r.get("tokenizers", []):
            y = c[key][0] if key == "captions_unchanged" else c[key]
            ax.plot([c["mean_shift_mm"]], [y], "k*", ms=11, label=f"tokenizer {Path(c['tokenizer']).name}")
        if key == "top3_ratio":
            ax.axhline(1.0, color="0.6", lw=0.8)
            chance = min(3, r["block"]) / r["block"] / r["ground_truth"]["rprec_top3"]
            ax.axhline(chance, color="0.6", lw=0.8, ls="--")
            ax.text(0.01, chance, " chance", va="bottom", fontsize=8, color="0.4", transform=ax.get_yaxis_transform())
        ax.set_xscale("log")
        ax.set_xlabel("mean joint shift (mm)")
        ax.set_ylabel(ylabel)
        ax.set_ylim(-0.02, 1.08)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="lower left")
    ev = r.get("evaluator", {}).get("name", "no evaluator")
    fig.suptitle(f"validity: {ev}, annotation {r['annotation']} ({r['test_clips']} test clips)", fontsize=10)
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)
