"""One name per concept, one concept per name, across every ``handx`` command (issue 42 item 1).

The walk covers every parser the ``handx`` command builds, every family's ``train``, ``params`` and
``generate --run`` options and the other trainables' (``families.TRAINABLES``). A concept's help text
says what it is; the table below gives each concept its one spelling. An old spelling may stay only
as a ``cliargs.Deprecated`` action (hidden, one line of notice); ``handx_jax/cliargs.py`` explains.
"""

from __future__ import annotations

import argparse
import re

import pytest

from handx_jax.cli import build_parser, main
from handx_jax.cliargs import Deprecated
from handx_jax.commands import params, train
from handx_jax.families import TRAINABLES, get_family, names

# concept: (its one spelling, what the help of a flag of that concept says)
CONCEPTS = {
    "dataset (read)": ("--data", r"^(batch mode: )?(the |the sweep's |handx-jax )?(dataset|standard corpus)\b"
                                 r"(?! directory to create)"),
    "R-Precision block": ("--block", r"R-Precision block"),
    "sweep folder": ("--out", r"^sweep folder"),
    "caption level": ("--level", r"^caption level"),
    "confidence level": ("--confidence", r"^confidence level"),
    "training steps": ("--steps", r"^training steps"),
    "sampler steps": ("--sample-steps", r"sampler steps"),
    "encoder folder": ("--encoder", r"\b(T5|encoder) folder"),
}
SHARED = {"--out"}  # spellings that also name other things (what a command writes); the rest mean one concept
# spellings of the release before, each kept only as a Deprecated alias; positional folders likewise
OLD = {"--reference", "--rprec-block", "--weights", "--dataset"}
OLD_POSITIONAL = {"data", "out"}


def _walk(p, path):
    yield path, p
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sp in a.choices.items():
                yield from _walk(sp, f"{path} {name}")


def all_parsers():
    yield from _walk(build_parser(), "handx")
    for n in names():
        yield f"handx train {n}", train.family_parser(n)
        yield f"handx params {n}", params.family_parser(n)
        g = argparse.ArgumentParser(add_help=False)
        get_family(n).add_generate_args(g)
        yield f"handx generate --run <{n} run>", g
    for n in TRAINABLES:
        yield f"handx train {n}", train.trainable_parser(n)


def problems(parsers) -> list[str]:
    out = []
    for path, p in parsers:
        spelled = {s for a in p._actions for s in a.option_strings}
        for a in p._actions:
            if isinstance(a, (argparse._SubParsersAction, argparse._HelpAction)):
                continue
            name = ",".join(a.option_strings) or a.dest
            if isinstance(a, Deprecated):
                if a.new not in spelled:
                    out.append(f"{path} {name}: deprecated in favour of {a.new}, which it does not have")
                continue
            if set(a.option_strings) & OLD or (not a.option_strings and a.dest in OLD_POSITIONAL):
                out.append(f"{path} {name}: an old spelling that is not marked deprecated")
            for concept, (spelling, says) in CONCEPTS.items():
                means = re.search(says, a.help or "") is not None
                if means and spelling not in a.option_strings:  # one name per concept
                    out.append(f"{path} {name}: means {concept}, which is spelled {spelling}")
                if spelling in a.option_strings and spelling not in SHARED and not means:  # one concept per name
                    out.append(f"{path} {name}: {spelling} means {concept}, but its help says {a.help!r}")
    return out


def test_every_command_spells_each_concept_one_way():
    assert problems(all_parsers()) == []


def test_the_walk_catches_a_second_name_and_a_second_meaning():
    bad = argparse.ArgumentParser(prog="handx bad")
    bad.add_argument("--rprec-block", type=int, help="R-Precision block")  # old spelling, not deprecated
    bad.add_argument("--dataset", help="dataset directory")  # a second name for --data
    bad.add_argument("--level", type=float, help="confidence level of the CIs")  # --level meaning two things
    bad.add_argument("--steps", type=int, help="= --set sample.steps: sampler steps")
    bad.add_argument("data", help="dataset directory")  # positional dataset
    found = "\n".join(problems([("handx bad", bad)]))
    for what in ("--rprec-block: an old spelling", "--rprec-block: means R-Precision block, which is spelled --block",
                 "--dataset: means dataset (read)", "--level: means confidence level",
                 "--level: --level means caption level", "--steps: means sampler steps",
                 "--steps: --steps means training steps", "data: an old spelling"):
        assert what in found, (what, found)


@pytest.mark.parametrize("old,new", [
    (["sweep", "collect", "SWEEP"], ["sweep", "collect", "--out", "SWEEP"]),
    (["sweep", "rescore", "--out", "SWEEP", "--rprec-block", "16"], ["sweep", "rescore", "--out", "SWEEP", "--block", "16"]),
    (["data", "stats", "D"], ["data", "stats", "--data", "D"]),
    (["standard", "check", "D"], ["standard", "check", "--data", "D"]),
    (["eval", "run", "--reference", "D", "--ground-truth"], ["eval", "run", "--data", "D", "--ground-truth"]),
    (["generate", "--reference", "D"], ["generate", "--data", "D"]),
    (["text", "encode", "--weights", "E", "hi"], ["text", "encode", "--encoder", "E", "hi"]),
    (["analyze", "fit", "R", "--level", "0.9"], ["analyze", "fit", "R", "--confidence", "0.9"]),
])
def test_old_spellings_parse_as_the_new_with_one_line_of_notice(old, new, capsys):
    p = build_parser()
    a_new = p.parse_known_args(new)[0]
    assert capsys.readouterr().err == ""
    a_old = p.parse_known_args(old)[0]
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "deprecated" in err and "use " in err, err
    assert vars(a_old) == vars(a_new)


def test_old_diffusion_sample_steps_flag(capsys):
    g = argparse.ArgumentParser(prog="handx generate --run RUN")
    get_family("diffusion").add_generate_args(g)
    assert g.parse_args(["--steps", "8"]).sample_steps == 8
    assert "use --sample-steps" in capsys.readouterr().err


def test_a_missing_flag_given_neither_way_is_argparses_error(capsys):
    with pytest.raises(SystemExit) as e:
        build_parser().parse_args(["sweep", "status"])
    assert e.value.code == 2
    assert "the following arguments are required: --out" in capsys.readouterr().err


def test_one_training_verb_and_the_old_ones(tmp_path, capsys):
    """``handx train evaluator|t5`` and their old spellings build the same config."""
    d = str(tmp_path / "d")
    assert main(["train", "t5", "--data", d, "--out", "o", "--preset", "tiny", "--set", "noise_density=0.2",
                 "--print-config"]) == 0
    new = capsys.readouterr()
    assert '"noise_density": 0.2' in new.out and new.err == ""
    assert main(["text", "pretrain", "--data", d, "--out", "o", "--preset", "tiny", "--set", "noise_density=0.2",
                 "--print-config"]) == 0
    old = capsys.readouterr()
    assert old.out == new.out and "use handx train t5" in old.err and old.err.count("\n") == 1
    args = ["--data", d, "--encoder", "e", "--out", "E", "--preset", "tiny", "--steps", "7", "--print-config"]
    assert main(["train", "evaluator", *args]) == 0
    new = capsys.readouterr()
    assert main(["eval", "train-evaluator", *args]) == 0
    old = capsys.readouterr()
    assert old.out == new.out and '"steps": 7' in new.out and "use handx train evaluator" in old.err
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    text = next(a for a in sub.choices["text"]._actions if isinstance(a, argparse._SubParsersAction))
    assert text.choices["tokenizer"].get_default("func").deprecated == ("handx text tokenizer",
                                                                        "handx text sentencepiece")
    # the token cache is a dataset's derived cache: `handx data tokens`; `handx tokenize` is its old spelling
    assert sub.choices["tokenize"].get_default("func").deprecated == ("handx tokenize", "handx data tokens")
    data = next(a for a in sub.choices["data"]._actions if isinstance(a, argparse._SubParsersAction))
    assert "tokens" in data.choices and not hasattr(data.choices["tokens"].get_default("func"), "deprecated")
