"""Links labelled from the kinematic tree: a spec that names its joints (and, where the tree cannot tell, each
finger's root) needs no `links` table; a `links` entry overrides the tree's label."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml
from conftest import DATA, example_robot_data_allegro

from lerobot_opfa.cli import main
from lerobot_opfa.hands import HandModel, HandSpecError, load_hand

TIPS = ("link_3.0_tip", "link_7.0_tip", "link_11.0_tip", "link_15.0_tip")


def _allegro(tmp_path: Path, **fields) -> Path:
    """tests/data/user_allegro/spec.yaml without its `links` table, with `fields` set instead."""
    raw = yaml.safe_load((DATA / "user_allegro" / "spec.yaml").read_text())
    raw["model"] = str(example_robot_data_allegro())
    raw.pop("links")
    raw.update(fields)
    spec = tmp_path / "allegro" / "spec.yaml"
    spec.parent.mkdir(exist_ok=True)
    spec.write_text(yaml.safe_dump(raw))
    return spec


def _explicit_allegro_links() -> dict[str, tuple[int, int]]:
    raw = yaml.safe_load((DATA / "user_allegro" / "spec.yaml").read_text())
    return {link: tuple(label) for link, label in raw["links"].items()}


def test_the_tree_labels_a_vendor_urdf_as_its_explicit_table_does(tmp_path, capsys, user_allegro_spec):
    """The one difference: the explicit table gives each fingertip, fixed to its distal link, a segment of its
    own; in the tree no joint moves it against the distal link, so it is the distal link's segment."""
    spec = _allegro(tmp_path)
    expected = _explicit_allegro_links()
    for tip in TIPS:
        expected[tip] = expected[tip.removesuffix("_tip")]
    hand = load_hand(spec)
    assert hand.inferred_links == expected and hand.spec.links == expected
    assert hand.fingertip_links == load_hand(user_allegro_spec).fingertip_links  # each finger's `_tip` link
    assert main(["hands", "check", str(spec)]) == 0
    out = capsys.readouterr().out
    assert "WARNING" not in out, out
    assert "labels from the kinematic tree, 21 links" in out
    assert "palm: v0 palm_link\n" in out
    assert "index: v0 link_0.0; v1 link_1.0; v2 link_2.0; v3 link_3.0, link_3.0_tip\n" in out
    assert "thumb: v0 link_12.0; v1 link_13.0; v2 link_14.0; v3 link_15.0, link_15.0_tip\n" in out

    roots = {"index": "joint_0.0", "middle": "link_4.0", "ring": "joint_8.0", "thumb": "link_12.0"}
    assert HandModel.from_spec(_allegro(tmp_path, fingers=roots)).spec.links == expected  # as the tree says


def test_links_override_the_tree(tmp_path):
    spec = _allegro(tmp_path, links={"link_3.0_tip": [2, 4], "link_15.0_tip": None, "link_0.0": [0, 0]})
    hand = HandModel.from_spec(spec)
    assert hand.spec.links["link_3.0_tip"] == (2, 4) and hand.spec.links["link_0.0"] == (0, 0)
    assert "link_3.0_tip" not in hand.inferred_links and "link_0.0" not in hand.inferred_links
    assert "link_15.0_tip" not in hand.link_names and "link_15.0_tip" not in hand.spec.links
    assert hand.spec.links["link_1.0"] == (2, 1)  # below the override, still counted from the finger's root


def test_builtin_hands_keep_their_tables():
    assert load_hand("allegro").inferred_links == {} and load_hand("umi").inferred_links == {}


def _umi(umi_copy: Path, **fields) -> Path:
    spec = umi_copy / "spec.yaml"
    raw = yaml.safe_load(spec.read_text())
    raw.pop("links", None)
    raw.update(fields)
    spec.write_text(yaml.safe_dump(raw))
    return spec


def test_a_gripper_needs_its_finger_roots(umi_copy):
    """A gripper's joints are the palm's in the universal table: the tree cannot tell which jaw is which."""
    spec = _umi(umi_copy)
    with pytest.raises(HandSpecError) as info:
        HandModel.from_spec(spec)
    message = str(info.value)
    assert message.startswith(f"{spec.resolve()}: field 'links': link(s) ['left_jaw', 'right_jaw'] carry")
    assert "joint(s) ['left_jaw_joint', 'right_jaw_joint'] move them" in message and "`fingers`" in message
    assert "\n" not in message

    spec = _umi(umi_copy, fingers={"thumb": "left_jaw_joint", "index": "right_jaw"})
    assert HandModel.from_spec(spec).spec.links == {"base": (0, 0), "left_jaw": (1, 0), "right_jaw": (2, 0)}


@pytest.mark.parametrize(
    ("fingers", "field", "words"),
    [
        ({"palm": "base"}, "fingers.palm", "not a finger; expected one of ['thumb', 'index'"),
        ({"index": "left_jaw_joint", "thumb": "left_jaw_joint"}, "fingers.thumb", "already another finger"),
        ({"thumb": "ghost"}, "fingers.thumb", "'ghost' is neither a movable joint nor a link of the model"),
    ],
)
def test_bad_finger_roots(umi_copy, fingers, field, words):
    spec = _umi(umi_copy, fingers=fingers)
    with pytest.raises(HandSpecError, match=f"field '{re.escape(field)}': .*{re.escape(words)}"):
        HandModel.from_spec(spec)


def test_a_root_above_another_fingers_joints(tmp_path):
    spec = _allegro(tmp_path, fingers={"index": "palm_link"})
    with pytest.raises(HandSpecError, match=r"'fingers': joint\(s\) 'joint_4.0' \(middle\) below the index"):
        HandModel.from_spec(spec)


def test_an_mjcf_hand_is_labelled_too(user_shadow_spec):
    """gymnasium-robotics' Shadow with `links` down to its null entries: each link in the finger its explicit
    table says, but the little finger's metacarpal, which LFJ4 (little_cmc_flex) moves and the table keeps in
    the palm. Segments differ: the tree counts every moving joint, the table counts phalanges (a knuckle's
    abduction joint starts none)."""
    raw = yaml.safe_load(user_shadow_spec.read_text())
    explicit = {link: label for link, label in raw["links"].items() if label is not None}
    raw["links"] = {link: None for link, label in raw["links"].items() if label is None}
    user_shadow_spec.write_text(yaml.safe_dump(raw))
    hand = HandModel.from_spec(user_shadow_spec)
    fingers = {link: u for link, (u, _) in hand.inferred_links.items()}
    assert fingers == {link: u for link, (u, _) in explicit.items()} | {"robot0:lfmetacarpal": 5}
    assert hand.inferred_links["robot0:ffdistal"] == (2, 3) and explicit["robot0:ffdistal"] == [2, 2]
