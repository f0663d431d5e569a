"""The validity suite's edits of *which* hand or finger does what (issue 55), and the evaluator's hard negatives
made from them.

Known answers on hand-built clips (a mirror through a known plane, a finger bent by a known angle on a palm
laid out in a plane), physical validity on generated clips (bone lengths, handedness, the distances between the
two hands, the palm), the involutions, the captions of a tiny corpus-v5 build changing under each edit, and the
loss and batches that take the edits as negatives."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from handx_jax import skeleton as sk
from handx_jax.validity import perturb as P

NEW_KINDS = ("swap_hands", "swap_fingers", "still_fingers")


@pytest.fixture(scope="module")
def clips():
    """Eight generated clips in the corpus's canonical frame (the synthesizer's own, as tests/test_validity.py)."""
    from handx_jax.dataset.clips import ClipConfig, extract_clips
    from handx_jax.synthesis.bimanual import SynthConfig, synth_chunk

    out = []
    for seq in synth_chunk(0, 0, SynthConfig()).joints:
        out.extend(extract_clips(sk.canonicalize(seq, ref_frame=0), ClipConfig())[0])
        if len(out) >= 8:
            break
    return np.stack(out[:8]).astype(np.float32)


def _handedness(x):
    """Sign of det[index MCP − wrist, pinky MCP − wrist, thumb CMC − wrist] per hand and frame: a reflection flips it,
    a rotation keeps it, so it tells a right hand from a left one."""
    w = x[..., 0, :]
    return np.sign(np.linalg.det(np.stack([x[..., 1, :] - w, x[..., 7, :] - w, x[..., 13, :] - w], -1)))


def _pair_distances(x):
    """Every left joint to every right joint, (..., 21, 21)."""
    return np.linalg.norm(x[..., 0, :, None, :] - x[..., 1, None, :, :], axis=-1)


def _rotation(rng):
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_swap_hands_is_the_mirror_through_the_wrists_bisector(clips):
    rng = np.random.default_rng(0)
    x = rng.normal(0, 0.05, (1, 4, 2, 21, 3))
    x[0, 0, 0, 0], x[0, 0, 1, 0] = (-0.3, 0, 0), (0, 0, 0)  # canonical frame 0: the plane is x = -0.15
    y = P.apply("swap_hands", x, 0.0, 0)
    for new, old in ((1, 0), (0, 1)):  # known answer: x -> -0.3 - x, y and z kept, the hands exchanged
        assert np.allclose(y[:, :, new, :, 0], -0.3 - x[:, :, old, :, 0], atol=1e-6)
        assert np.allclose(y[:, :, new, :, 1:], x[:, :, old, :, 1:], atol=1e-6)
    assert np.allclose(y[0, 0, 1, 0], 0, atol=1e-7)  # canonical again: the new right wrist starts at the origin
    # Generated clips: each hand stays its own side's hand, bones and inter-hand distances (contacts) kept.
    s = P.apply("swap_hands", clips, 0.0, 0)
    assert np.all(_handedness(clips)[..., 0] == -1) and np.all(_handedness(clips)[..., 1] == 1)
    assert np.array_equal(_handedness(s), _handedness(clips))
    assert np.allclose(sk.bone_lengths(s)[..., ::-1, :], sk.bone_lengths(clips), atol=1e-6)
    assert np.allclose(_pair_distances(s), np.swapaxes(_pair_distances(clips), -1, -2), atol=2e-6)
    assert np.allclose(P.apply("swap_hands", s, 0.0, 0), clips, atol=1e-6)  # an involution
    # The plane is the clip's own: a rigid move of the clip moves the swap with it (not a fixed world plane).
    R, t = _rotation(rng), np.array([0.4, -0.2, 1.1])
    moved = P.apply("swap_hands", clips @ R.T + t, 0.0, 0)
    assert np.allclose(moved, s @ R.T + t, atol=1e-5)


def _planar_hand(pip_bend_deg_per_finger):
    """A right hand laid out in the z = 0 plane: wrist at the origin, each finger's MCP at (x_f, 0.09), straight
    fingers along its metacarpal, bent toward -z at the PIP by the given angle; bone lengths differ per finger."""
    j = np.zeros((21, 3))
    xs = {"index": 0.03, "middle": 0.01, "ring": -0.01, "pinky": -0.03}
    lengths = {"index": (0.040, 0.025, 0.020), "middle": (0.045, 0.030, 0.022),
               "ring": (0.042, 0.028, 0.021), "pinky": (0.033, 0.020, 0.018)}
    for f, x0 in xs.items():
        mcp, pip, dip, tip = sk.CHAINS[f][1:]
        j[mcp] = (x0, 0.09, 0.0)
        u = j[mcp] / np.linalg.norm(j[mcp])
        a = np.radians(pip_bend_deg_per_finger.get(f, 0.0))
        bent = np.cos(a) * u + np.sin(a) * np.array([0.0, 0.0, -1.0])
        j[pip] = j[mcp] + lengths[f][0] * u
        j[dip] = j[pip] + lengths[f][1] * bent
        j[tip] = j[dip] + lengths[f][2] * bent
    for k, jj in enumerate(sk.CHAINS["thumb"][1:]):
        j[jj] = (0.04 + 0.01 * k, 0.02 + 0.02 * k, -0.01)
    return j, xs, lengths


def test_swap_fingers_known_answer_on_a_planar_hand():
    right, xs, lengths = _planar_hand({"middle": 90.0, "pinky": 30.0})
    x = np.stack([right * np.array([-1.0, 1, 1]) - (0.3, 0, 0), right])[None, None].astype(np.float64)
    y = P.apply("swap_fingers", x, 0.0, 0)[0, 0].astype(np.float64)
    for h in range(2):
        palm = [0, 13, 14, 15, 16, *sorted(sk.MCPS.values())]
        assert np.allclose(y[h, palm], x[0, 0, h, palm], atol=1e-7)  # the palm and thumb do not move
    r = y[1]
    # Index now bends 90 degrees at its PIP (middle's), turned onto index's metacarpal, with index's own lengths:
    # in the plane of the palm, index's metacarpal is middle's turned about z by the angle between them.
    mcp, pip, dip, tip = sk.CHAINS["index"][1:]
    u = r[mcp] / np.linalg.norm(r[mcp])
    want_pip = r[mcp] + lengths["index"][0] * u
    want_dip = want_pip + lengths["index"][1] * np.array([0.0, 0.0, -1.0])
    assert np.allclose(r[pip], want_pip, atol=1e-6) and np.allclose(r[dip], want_dip, atol=1e-6)
    assert np.allclose(r[tip], want_dip + lengths["index"][2] * np.array([0.0, 0.0, -1.0]), atol=1e-6)
    # Middle is straight now, along its own metacarpal, with its own lengths: its tip lies on that line.
    m = sk.CHAINS["middle"]
    along = r[m[1]] / np.linalg.norm(r[m[1]])
    assert np.allclose(r[m[4]], r[m[1]] + sum(lengths["middle"]) * along, atol=1e-6)
    # Ring takes pinky's 30 degrees and pinky ring's straight finger.
    ring, pinky = sk.CHAINS["ring"], sk.CHAINS["pinky"]
    cos = np.dot(*(np.diff(r[[ring[1], ring[2], ring[3]]], axis=0) / np.array(lengths["ring"][:2])[:, None]))
    assert math.degrees(math.acos(np.clip(cos, -1, 1))) == pytest.approx(30.0, abs=1e-4)
    assert np.allclose(np.cross(r[pinky[4]] - r[pinky[1]], r[pinky[1]]), 0, atol=1e-7)


def _interior_angles(x, chain):
    """The angle (degrees) at each of the chain's MCP, PIP and DIP between the bones in and out of it."""
    a = x[..., list(chain), :]
    d = np.diff(a, axis=-2)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(d[..., :-1, :] * d[..., 1:, :], -1), -1, 1)))


def test_swap_fingers_exchanges_the_fingers_shapes_and_keeps_the_bones(clips):
    s = P.apply("swap_fingers", clips, 0.0, 0)
    assert np.allclose(sk.bone_lengths(s), sk.bone_lengths(clips), atol=1e-6)
    assert np.array_equal(_handedness(s), _handedness(clips))
    for a, b in P.FINGER_SWAPS:
        assert np.allclose(_interior_angles(s, sk.CHAINS[a]), _interior_angles(clips, sk.CHAINS[b]), atol=0.05)
        assert np.allclose(_interior_angles(s, sk.CHAINS[b]), _interior_angles(clips, sk.CHAINS[a]), atol=0.05)
    assert P.mean_shift_mm(clips, s) > 1.0  # it moves the fingers
    assert np.allclose(P.apply("swap_fingers", s, 0.0, 0), clips, atol=1e-6)  # an involution


def test_still_fingers_holds_one_hand_rigid_and_leaves_the_other(clips):
    from handx_jax.representation.geometry import local_positions

    s = P.apply("still_fingers", clips, 0.0, 0)
    local = local_positions(s.astype(np.float64))
    still = np.all(np.isclose(local, local[:, :1], atol=1e-5), axis=(1, 3, 4))  # (N, 2): which hand is rigid
    assert np.all(still.sum(1) >= 1)
    for n in range(len(clips)):
        h = int(np.flatnonzero(still[n])[0])
        assert np.array_equal(s[n, :, 1 - h], clips[n, :, 1 - h])  # the other hand untouched
        assert np.allclose(s[n, :, h, 0], clips[n, :, h, 0], atol=1e-7)  # the wrist path kept
        assert np.allclose(sk.bone_lengths(s[n, :, h]), sk.bone_lengths(clips[n, :1, h]), atol=1e-6)
    assert set(np.flatnonzero(still[:, 0] & ~still[:, 1])) and set(np.flatnonzero(still[:, 1] & ~still[:, 0]))
    assert np.allclose(P.apply("still_fingers", s, 0.0, 0), s, atol=1e-6)  # holding still again changes nothing


def test_still_fingers_known_answer_on_a_turning_hand():
    """Both hands turn about z by a known angle and slide while their middle fingers curl: held still, a hand is
    its frame-0 shape turned by that angle and placed on its wrist path."""
    T = 5
    theta = np.radians(np.linspace(0, 40, T))
    x = np.zeros((6, T, 2, 21, 3))
    for t in range(T):
        right, _, _ = _planar_hand({"middle": 20.0 * t})
        c, s_ = np.cos(theta[t]), np.sin(theta[t])
        rz = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
        for h, hand in enumerate((right * np.array([-1.0, 1, 1]), right)):
            x[:, t, h] = hand @ rz.T + (0.01 * t, 0.3 * h, 0.0)
    y = P.apply("still_fingers", x, 0.0, 0).astype(np.float64)
    moved = [[not np.allclose(y[n, :, h], x[n, :, h], atol=1e-6) for h in range(2)] for n in range(6)]
    assert all(sum(m) == 1 for m in moved) and {m.index(True) for m in moved} == {0, 1}
    for n in range(6):
        h = moved[n].index(True)
        for t in range(T):
            c, s_ = np.cos(theta[t]), np.sin(theta[t])
            rz = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
            want = (x[n, 0, h] - x[n, 0, h, 0]) @ rz.T + x[n, t, h, 0]
            assert np.allclose(y[n, t, h], want, atol=1e-6)


def test_the_captions_of_a_tiny_v5_build_change_under_each_edit(tmp_path):
    from handx_jax import standard
    from handx_jax.annotation.caption import TemplateCaptioner
    from handx_jax.annotation.events import annotation_config
    from handx_jax.dataset.build import corpus_seed, reading_of
    from handx_jax.dataset.format import Dataset
    from handx_jax.validity import stability as S

    data = standard.build_standard_corpus(tmp_path / "v5", 60, workers=1, progress=False,
                                          recipe=standard.corpus_recipe("v5"))
    ds = Dataset.open(data)
    x = np.asarray(ds.motion[:], np.float32)
    reading, wording = reading_of(ds)
    assert reading == "surface"
    ann = S.Annotator(x, list(ds.ids), corpus_seed(ds), annotation_config(reading), TemplateCaptioner(wording))
    clean = [c[0] for c in ann.clean_captions]
    assert clean == [tuple(t[f][0] for f in ("left", "right", "interaction")) for t in ds.texts]
    changed = {}
    for kind in NEW_KINDS:
        assert not P.KINDS[kind].preserving
        _, caps = ann.records_and_captions(P.apply(kind, x, 0.0, 0))
        pert = [c[0] for c in caps]
        changed[kind] = np.mean([a != b for a, b in zip(clean, pert)])
        if kind == "swap_hands":
            # The rule the hard negatives' mask reads: swapped, a clip reads (right, left, interaction) at level 0.
            assert pert == [(r, l, i) for l, r, i in clean]
            assert [P.reads_the_same(kind, *c, 0) for c in clean] == [a == b for a, b in zip(clean, pert)]
    # Every edit changes what level 0 says for most clips (a clip whose two hands, or whose swapped fingers, do
    # the same thing reads the same; the measured shares are in docs/results/validity/hard-negatives-small/).
    assert all(v >= 0.5 for v in changed.values()), changed


def test_infonce_takes_each_hard_negative_and_leaves_out_those_that_read_the_same():
    import jax.numpy as jnp

    from handx_jax.models.evaluator import infonce

    m1, t1 = jnp.array([[1.0, 0.0]]), jnp.array([[1.0, 0.0]])
    same_as_clip = jnp.array([[[1.0, 0.0], [1.0, 0.0]]])  # (B 1, K 2, D): two edits that embed as the clip
    # Three tied columns on the text -> motion side: ln 3, halved by the symmetric mean.
    assert float(infonce(m1, t1, 1.0, mu_m_hard_BxKxD=same_as_clip)) == pytest.approx(0.5 * math.log(3), rel=1e-5)
    masked = jnp.array([[True, False]])
    assert float(infonce(m1, t1, 1.0, mu_m_hard_BxKxD=same_as_clip, hard_same_BxK=masked)) == pytest.approx(
        0.5 * math.log(2), rel=1e-5)
    both = dict(mu_m_rev=m1, mu_m_hard_BxKxD=same_as_clip)  # with the reversal: four tied columns
    assert float(infonce(m1, t1, 1.0, **both)) == pytest.approx(0.5 * math.log(4), rel=1e-5)


def test_the_evaluator_loss_reads_the_batchs_hard_negatives():
    import jax

    from handx_jax.evaluation.model import _init_params
    from handx_jax.models.evaluator import PRESETS, Evaluator, evaluator_loss

    cfg = dataclasses.replace(PRESETS["tiny"], text_dim=8, frames=4, dropout=0.0,
                              hard_negatives=("swap_hands", "swap_fingers"))
    model, params = Evaluator(cfg), _init_params(cfg, 6, jax.random.PRNGKey(0))
    loss = jax.jit(lambda b: evaluator_loss(model, params, b, jax.random.PRNGKey(1), False)[0])
    rng = np.random.default_rng(0)
    batch = {"motion": rng.standard_normal((3, 4, 126)).astype(np.float32),
             "text": rng.standard_normal((3, 6, 8)).astype(np.float32), "text_mask": np.ones((3, 6), bool)}
    plain = float(loss(batch))
    copies = np.repeat(batch["motion"][:, None], 2, axis=1)  # each clip's two edits embed as the clip itself
    hard = {**batch, "motion_hard": copies, "hard_same_text": np.zeros((3, 2), bool)}
    masked = {**hard, "hard_same_text": np.ones((3, 2), bool)}  # both read as the clip: left out
    assert float(loss(hard)) > plain + 0.1 and float(loss(masked)) == pytest.approx(plain, rel=1e-6)


def test_training_batches_carry_the_edits_and_the_config_names_them(clips):
    from handx_jax.config import ConfigError
    from handx_jax.evaluation import make_evaluator_config
    from handx_jax.evaluation.features import TrainingData, motion_features
    from handx_jax.models.evaluator import PRESETS, EvaluatorConfig
    from handx_jax.representation import NormStats

    class _Texts:  # two clips whose two hands read the same, then ones that differ
        texts = [{"left": [t], "right": [t if i < 2 else "other"], "interaction": ["apart"]}
                 for i, t in enumerate("abcdefgh")]

    td = TrainingData.__new__(TrainingData)
    td.seed, td.ds, td.companion, td.motion_input = 3, _Texts(), None, "positions"
    td.stats, td.hard_negatives = NormStats(np.zeros(126), np.ones(126)), ("swap_hands", "swap_fingers")
    idx = np.arange(8)
    feats, same = td._hard(clips, idx, idx, np.zeros(8, np.int64), None)
    assert feats.shape == (8, 2) + motion_features(clips, td.stats).shape[1:]
    for k, kind in enumerate(td.hard_negatives):
        assert np.allclose(feats[:, k], motion_features(P.apply(kind, clips, 0.0, 0), td.stats), atol=1e-5)
    assert same.tolist() == [[True, False]] * 2 + [[False, False]] * 6
    # The option: off by default (old recipes), named kinds only, a JSON list read back as the same config.
    assert PRESETS["small"].hard_negatives == ()
    cfg = make_evaluator_config("small", ["model.hard_negatives=swap_hands,swap_fingers"])
    assert cfg.model.hard_negatives == ("swap_hands", "swap_fingers")
    cfg.validate()
    back = EvaluatorConfig(**{**dataclasses.asdict(cfg.model), "hard_negatives": ["swap_hands", "swap_fingers"]})
    assert back == cfg.model
    for bad, why in (("wobble", "unknown wobble"), ("reverse", "unknown reverse"), ("swap_hands,swap_hands", "twice")):
        with pytest.raises(ConfigError, match=why):
            make_evaluator_config("small", [f"model.hard_negatives={bad}"]).validate()


def test_the_card_shows_the_caption_reader_beside_the_evaluator_where_the_report_has_it():
    from handx_jax import standard
    from handx_jax.standard.card import card_markdown, validity_summary

    card = standard.read_card()
    case = {"kind": "swap_hands", "label": "left and right hands swapped (mirrored)", "preserving": False,
            "amplitude_mm": 0.0, "mean_shift_mm": 86.6, "captions_unchanged": [0.333] * 5, "events_unchanged": 0.57,
            "top3_ratio": 0.61, "eval_fid": 10.3}
    report = {"test_clips": 96, "block": 32, "annotation": "surface", "ground_truth": {"rprec_top3": 0.98}}
    old = card_markdown({**card, "validity": validity_summary({**report, "cases": [case]})})
    assert "caption reader" not in old and "| left and right hands swapped (mirrored) | 86.6 | 0.61 | 10.30 | 0.33 |" in old
    new = card_markdown({**card, "validity": validity_summary({**report, "cases": [{**case, "caption_reader_ratio": 0.77}]})})
    assert "| caption reader × |" in new and "| 86.6 | 0.61 | 10.30 | 0.33 | 0.77 |" in new


def test_the_v8_build_script_names_a_corpus_version_and_hard_negatives_the_code_knows():
    import re
    from pathlib import Path

    from handx_jax import standard

    text = (Path(__file__).resolve().parents[1] / "scripts" / "build_standard_v8.sh").read_text()
    corpus = re.search(r"CORPUS=(\S+)", text).group(1)
    kinds = re.search(r"HARD_NEGATIVES=\$\{HARD_NEGATIVES:-([^}]+)\}", text).group(1).split(",")
    assert corpus in standard.CORPUS_VERSIONS and standard.corpus_recipe(corpus).annotation == "surface"
    assert kinds and all(k in P.HARD_NEGATIVE_KINDS for k in kinds)
    # the next version while v7 is packaged, this code's own once the lead names v8 the standard one
    assert int(re.search(r"STANDARD_VERSION=(\d+)", text).group(1)) in (standard.VERSION + 1, standard.VERSION)
