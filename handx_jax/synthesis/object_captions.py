"""Captions of a hand–object clip in the project's three-text form (left, right, interaction), two levels.

Level 0 says what each hand does to which part ("The right hand opens the lid of the box while the left hand
holds its base"); level 1 adds where it takes the part (its grasp template), how far the angle goes, and how
far the object is lifted, carried and turned. The words come from the clip's program, which the synthesizer
carries out exactly (the grasp holds the part, the part follows the program), so they are true of the motion.
Word choices draw on a per-clip seed (build.caption_seed), as the hand corpus's template captioner does.
"""

from __future__ import annotations

import math

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.objects import TOP

OBJECT_WORDS = {"box": "box", "laptop": "laptop", "scissors": "scissors", "cabinet": "cabinet", "bottle": "bottle"}
PART_WORDS = {"box": ("lid", "base"), "laptop": ("screen", "base"), "scissors": ("upper blade", "lower handle"),
              "cabinet": ("door", "body"), "bottle": ("flip cap", "body")}
_TAKE = ("takes", "grips", "grasps")
_LET_GO = ("lets go", "releases it", "lets it go")


def _side(h: int) -> str:
    return sk.HAND_NAMES[h]


def _hand_text(pr: dict, h: int, angle_deg: tuple[float, float], rng: np.random.Generator) -> tuple[str, str]:
    cat = pr["category"]
    obj, (top, bottom) = OBJECT_WORDS[cat], PART_WORDS[cat]
    hand = pr["hands"][h]
    part = top if hand["part"] == TOP else bottom
    take, let_go = rng.choice(_TAKE), rng.choice(_LET_GO)
    where = hand["template"]
    if pr["program"] == "grab":
        m = pr["motion"]
        short = f"The {_side(h)} hand lifts the {obj} by its {part}."
        way = "to the right" if m["carry_m"] > 0 else "to the left"
        carry = f", carries it {abs(m['carry_m']) * 100:.0f} cm {way}" if abs(m["carry_m"]) >= 0.03 else ""
        turn = (f", turns it {abs(m['turn_deg']):.0f} degrees {'to the left' if m['turn_deg'] > 0 else 'to the right'}"
                if abs(m["turn_deg"]) >= 10 else "")
        return short, (f"The {_side(h)} hand {take} the {where}, lifts the {obj} about {m['lift_m'] * 100:.0f} cm"
                       f"{carry}{turn} and puts it down, then {let_go}.")
    lo, hi = angle_deg
    if hand["part"] == TOP:
        kind = pr["use"]
        if kind == "open":
            short = f"The {_side(h)} hand opens the {top} of the {obj}."
            detail = f"opens the {top} to about {hi:.0f} degrees"
        elif kind == "close":
            short = f"The {_side(h)} hand closes the {top} of the {obj}."
            detail = f"closes the {top} from about {hi:.0f} degrees"
        else:
            short = f"The {_side(h)} hand snips the {obj} open and shut."
            detail = f"opens and shuts the {obj} up to about {hi:.0f} degrees"
        return short, f"The {_side(h)} hand {take} the {where} and {detail}, then {let_go}."
    short = f"The {_side(h)} hand holds the {bottom} of the {obj} still."
    return short, f"The {_side(h)} hand {take} the {where} and holds it still while the {top} moves, then {let_go}."


def caption_clip(pr: dict, angle_T: np.ndarray, seed: int) -> dict:
    """{"left": [l0, l1], "right": [...], "interaction": [...]} for one clip's program and angle trajectory (rad)."""
    rng = np.random.default_rng(seed)
    cat = pr["category"]
    obj, (top, bottom) = OBJECT_WORDS[cat], PART_WORDS[cat]
    deg = (math.degrees(float(np.min(angle_T))), math.degrees(float(np.max(angle_T))))
    texts = {name: list(_hand_text(pr, h, deg, rng)) for h, name in enumerate(("left", "right"))}
    parts = [hd["part"] for hd in pr["hands"]]
    if pr["program"] == "grab":
        m = pr["motion"]
        if pr["layout"] == "pair":
            i0 = f"Both hands lift the {obj} together by its {PART_WORDS[cat][parts[0] != TOP]}."
        else:
            i0 = f"Both hands lift the {obj} together, one by its {top} and one by its {bottom}."
        way = "to the right" if m["carry_m"] > 0 else "to the left"
        i1 = (f"The two hands take the {obj} from both sides, lift it about {m['lift_m'] * 100:.0f} cm"
              + (f", carry it {abs(m['carry_m']) * 100:.0f} cm {way}" if abs(m["carry_m"]) >= 0.03 else "")
              + " and set it down again before letting go.")
    else:
        th = parts.index(TOP)
        bh = 1 - th
        # "snips the scissors open and shut", not "snips open and shut the scissors": the particle after the object.
        act = {"open": f"opens the {top} of the {obj}", "close": f"closes the {top} of the {obj}",
               "snip": f"snips the {obj} open and shut"}[pr["use"]]
        i0 = f"The {_side(th)} hand {act} while the {_side(bh)} hand holds its {bottom}."
        i1 = (f"The {_side(bh)} hand steadies the {bottom} of the {obj} while the {_side(th)} hand {act}"
              f" between about {deg[0]:.0f} and {deg[1]:.0f} degrees; then both hands let go.")
    texts["interaction"] = [i0, i1]
    return texts
