"""The card: what it keeps of a validity report, and CARD.md rendered from card.json (one source of truth)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from handx_jax.dataset.format import MOTION_ATOL
from handx_jax.standard.recipe import Recipe


def _row(r: Mapping[str, Any]) -> str:
    f = lambda k: f"{r[k]:.3f} ± {r[k + '_ci']:.3f}"  # noqa: E731
    return f"{f('rprec_top1')} | {f('rprec_top2')} | {f('rprec_top3')} | {f('mm_dist')} | {f('diversity')}"


def _ci_note(gt: Mapping[str, Any]) -> str:
    """What the rows' ± is (``metrics.ci_method``): the GT row is one group, so a prompt bootstrap."""
    r = next(iter(gt.values()), {})
    reps, boot = r.get("replications", "?"), r.get("bootstrap") or 200
    if r.get("ci_method", "bootstrap_prompts") == "bootstrap_prompts":
        return (f"Point values average {reps} re-blockings of the prompts; ± is a 95% interval for the mean: 1.96 × "
                f"the spread over {boot} bootstrap resamples of the test prompts (`handx_jax/metrics/intervals.py`, "
                f"`ci_method` `bootstrap_prompts`).")
    return f"± is a 95% interval (`ci_method` `{r.get('ci_method')}`, `handx_jax/metrics/intervals.py`)."


def validity_summary(report: Mapping[str, Any]) -> dict:
    """What the card keeps of a validity report (``handx standard validity``): per case, the top-3
    ratio to the ground truth's, FID and the level-0 captions left unchanged."""
    rows = []
    for c in list(report.get("cases", [])) + list(report.get("tokenizers", [])):
        name = c.get("label") or f"tokenizer {Path(str(c.get('tokenizer'))).name} reconstruction"
        if c.get("amplitude_mm"):
            name += f", {c['amplitude_mm']:g} mm"
        rows.append({"case": name, "mean_shift_mm": round(c["mean_shift_mm"], 2),
                     "top3_ratio": round(c["top3_ratio"], 3) if "top3_ratio" in c else None,
                     "fid": round(c["eval_fid"], 3) if "eval_fid" in c else None,
                     **({"caption_reader_ratio": round(c["caption_reader_ratio"], 3)} if "caption_reader_ratio" in c else {}),
                     "level0_unchanged": round(c["captions_unchanged"][0], 3),
                     "events_unchanged": round(c["events_unchanged"], 3)})
    gt = report.get("ground_truth") or {}
    return {"test_clips": report.get("test_clips"), "block": report.get("block"), "annotation": report.get("annotation"),
            "ground_truth_top3": gt.get("rprec_top3"), "rows": rows}


def card_markdown(card: Mapping[str, Any]) -> str:
    """CARD.md from card.json (one source of truth)."""
    rec, c, e, tr = card["recipe"], card["corpus"], card["evaluator"], card.get("training_run", {})
    t = e["training"]
    gt = card.get("ground_truth", {})
    lines = [
        f"# Standard evaluator v{card['version']}",
        "",
        "The evaluator `handx eval run` uses when no `--evaluator` is given. Its identity is the corpus recipe:",
        "",
        f"- generator version **{rec['generator']}**, seed **{rec['seed']}**, **{rec['clips']:,}** clips, default "
        f"build options (`handx standard corpus --out DIR` = `handx data synth --clips {rec['clips']} "
        f"{Recipe.from_card(rec).synth_flags()}`)",
        f"- splits {c['split_sizes']}; content hash on the packaging machine `{c['fingerprint']}` (another "
        f"numpy/jax build may give other float bytes: the check compares ids, captions and motion within "
        f"{MOTION_ATOL:g} m instead)",
        f"- a corpus of the first M clips (`--clips M`) is a *prefix*: its train split lies inside the standard "
        f"train split and its test split is the first test clips of the standard one; it is accepted, so small "
        f"experiments (`make demo`) are scored on a subset of the same test split",
        "",
        "## Training",
        "",
        f"- evaluator preset `{e['preset']}`, {e['params']:,} parameters, motion input "
        f"`{e['config'].get('motion_input')}`, latent {e['config'].get('latent')}; frozen tiny T5 text encoder "
        f"(`encoder/`, fingerprint `{e['encoder_fingerprint']}`, tokenizer `{e['tokenizer_fingerprint']}`)",
        f"- {t['steps']:,} steps × batch {t['batch_size']}, AdamW lr {t['lr']:g}, warm-up {t['warmup']}, "
        f"{t['schedule']} decay, weight decay {t['weight_decay']:g}, caption level(s) "
        f"{e['text'].get('train_levels')}, scored at level {e['text'].get('eval_level')}",
    ]
    if e["config"].get("hard_negatives"):  # v8 on (issue 55); absent from the earlier cards
        lines.append(f"- hard negatives: each clip's {', '.join(e['config']['hard_negatives'])} edit (validity.perturb) "
                     f"is one more negative of its own caption, left out where it reads the same")
    for k, v in tr.items():
        lines.append(f"- {k}: {v}")
    lines += [
        f"- packaged on: {card['packaged']['machine']}; python {card['packaged']['python']}, numpy "
        f"{card['packaged']['numpy']}, jax {card['packaged']['jax']}; {card['packaged']['date_utc']} UTC",
        "",
        f"## Ground Truth rows (standard test split, level-{e['text'].get('eval_level', 0)} captions)",
        "",
        _ci_note(gt),
        "",
        "| block | top-1 | top-2 | top-3 | MM-Dist | Diversity |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for b, r in gt.items():
        lines.append(f"| {b} | {_row(r)} |")
    lines += ["", f"{c['test_clips']:,} test prompts. Reproduce: `handx eval run --ground-truth --data DIR "
              f"[--block 16]` on the standard corpus.", ""]
    v = card.get("validity")
    if v:
        # The caption reader's column (issue 55's target: the evaluator loses what the captions lose) is on the cards
        # packaged since v8; earlier cards render as they were.
        reader = any("caption_reader_ratio" in r for r in v["rows"])
        lines += ["## Validity (`handx standard validity`, docs/validity.md)", "",
                  f"{v['test_clips']} test clips of a prefix, block {v['block']}, annotation `{v['annotation']}`; ground "
                  f"truth top-3 {v['ground_truth_top3']:.3f}.", "",
                  "| ground truth, perturbed | mean shift (mm) | top-3 × GT | FID | level-0 captions unchanged |"
                  + (" caption reader × |" if reader else ""),
                  "| --- | ---: | ---: | ---: | ---: |" + (" ---: |" if reader else "")]
        for r in v["rows"]:
            ratio = "–" if r["top3_ratio"] is None else f"{r['top3_ratio']:.2f}"
            fid = "–" if r["fid"] is None else f"{r['fid']:.2f}"
            cells = f"| {r['case']} | {r['mean_shift_mm']:.1f} | {ratio} | {fid} | {r['level0_unchanged']:.2f} |"
            if reader:
                cells += " – |" if r.get("caption_reader_ratio") is None else f" {r['caption_reader_ratio']:.2f} |"
            lines.append(cells)
        lines.append("")
    return "\n".join(lines)
