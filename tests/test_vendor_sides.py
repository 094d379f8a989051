"""Which hand a model is, judged from its geometry, matches the side its vendor labels, on the left/right
pairs example-robot-data ships: the Allegro hands, the G1's two Dex3 hands and Alex's two Psyonic hands (cut
out of their robots' URDFs as the vendors ship them). The Psyonic fingers rest curled: their distal joints
follow the proximal ones 0.72 rad further on (the URDF's mimic offset), and still the thumb says the side.
The Psyonic URDF's mimics name joints it does not have (`index_q1` for `Right_index_q1`): the spec's
couplings say how those joints move."""

from __future__ import annotations

import pytest
import yaml
from conftest import DATA, example_robot_data_allegro

from lerobot_opfa.hands.frame import measure
from lerobot_opfa.hands.registry import load_hand

ROBOTS = example_robot_data_allegro().parents[2]
PSYONIC_DISTAL = {"scale": 1.05851325, "offset": 0.72349796}
"""Alex's Psyonic URDF: each finger's distal joint = 1.0585 x its proximal + 0.7235 rad."""


def dex3(side: str) -> dict:
    joint = f"{side}_hand_{{}}_joint".format
    universal = ["thumb_cmc_roll", "thumb_mcp_flex", "thumb_ip_flex", "index_mcp_flex", "index_pip_flex",
                 "middle_mcp_flex", "middle_pip_flex"]  # fmt: skip
    names = ["thumb_0", "thumb_1", "thumb_2", "index_0", "index_1", "middle_0", "middle_1"]
    return {
        "model": str(ROBOTS / "g1_description" / "urdf" / "g1_29dof_with_hand_rev_1_0.urdf"),
        "root": f"{side}_hand_palm_link",
        "joints": {joint(n): u for n, u in zip(names, universal, strict=True)},
    }


def psyonic(side: str) -> dict:
    side = side.capitalize()
    fingers = {"index": "index", "middle": "middle", "ring": "ring", "pinky": "little"}
    return {
        "model": str(ROBOTS / "alex_description" / "urdf" / "alex_psyonic_hands.urdf"),
        "root": f"{side}_thumb_base",
        "joints": {f"{side}_thumb_q1": "thumb_cmc_abd", f"{side}_thumb_q2": "thumb_mcp_flex",
                   **{f"{side}_{f}_q1": f"{u}_mcp_flex" for f, u in fingers.items()}},
        "couplings": {f"{side}_{f}_q2": {"source": f"{side}_{f}_q1", **PSYONIC_DISTAL} for f in fingers},
    }  # fmt: skip


def allegro(side: str) -> dict:
    """tests/data/user_allegro's spec on the side's URDF (the two share joint and link names)."""
    raw = yaml.safe_load((DATA / "user_allegro" / "spec.yaml").read_text())
    model = str(example_robot_data_allegro()).replace("allegro_right_hand", f"allegro_{side}_hand")
    return {key: value for key, value in raw.items() if key in ("joints", "couplings", "base")} | {
        "model": model
    }


@pytest.mark.parametrize("side", ["left", "right"])
@pytest.mark.parametrize("vendor", [allegro, dex3, psyonic])
def test_a_vendors_left_and_right_hands_are_told_apart_by_their_geometry(vendor, side, tmp_path):
    spec = {"name": f"{vendor.__name__}_{side}", "kind": "hand",  # no `side`: the verdict is the geometry's
            "description": f"{vendor.__name__} {side} as its vendor ships it",
            **vendor(side), "poses": {"open": {}, "grasp": {}}}  # fmt: skip
    path = tmp_path / "spec.yaml"
    path.write_text(yaml.safe_dump(spec))
    assert measure(load_hand(path)).side == side
