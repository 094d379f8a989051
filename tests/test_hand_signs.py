"""`hands check` tells a wrong joint sign from a turned frame, and a right hand from its mirror, by geometry
that does not depend on the spec's signs (the fingers' roots and tips, the side their ranges curl to, the
thumb's side). The built-in hands and the vendor models as they ship pass with no warning; one finger's
signs flipped, every sign flipped, the hand turned half a turn with every sign flipped (what a palm
measured from the flexions called a frame to rotate) and a mirrored model are refused, naming the fix;
`--suggest` prints the base and signs that undo it."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import BUILTIN_HANDS, example_robot_data_allegro, orca_arm_urdf

from lerobot_opfa.cli import main
from lerobot_opfa.hands import frame, load_hand, load_spec
from lerobot_opfa.hands.registry import builtin_hands
from lerobot_opfa.hands.spec import SIDES
from lerobot_opfa.hands.validate import frame_report

HANDS = [name for name in BUILTIN_HANDS if load_spec(name).kind == "hand"]
VENDORS = [
    *(
        "user_allegro_spec",
        "user_shadow_spec",
        "cad_like_allegro_spec",
        "user_fourier_spec",
        "user_orca_spec",
    ),
]


@pytest.fixture(params=HANDS + VENDORS)
def spec(request, tmp_path) -> Path:
    """A correct spec: a built-in's, copied to be edited (renamed: an edited built-in is a hand of its
    own), or a vendor model's as the tests' data gives it, without its finger labels: a vendor's spec names
    its joints and, where the model holds more than the hand, what is not the hand (`null`)."""
    if request.param in VENDORS:
        return _unlabelled(request.getfixturevalue(request.param))
    source = builtin_hands()[request.param]
    raw = yaml.safe_load(source.read_text())
    raw.update(name=f"my_{raw['name']}", model=str(source.parent / raw["model"]))
    return _write(tmp_path / request.param / "spec.yaml", raw)


def _unlabelled(labelled: Path) -> Path:
    """The vendor spec without its finger labels, keeping `null` (not the hand)."""
    raw = yaml.safe_load(labelled.read_text())
    raw["links"] = {link: label for link, label in raw.pop("links", {}).items() if label is None}
    return _write(labelled, {k: v for k, v in raw.items() if v or k != "links"})


def _write(path: Path, raw: dict) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def _edited(spec: Path, change) -> Path:
    raw = yaml.safe_load(spec.read_text())
    change(raw)
    return _write(spec.parent / "edited" / "spec.yaml", raw)


def _flip(raw: dict, joints) -> None:
    for joint in joints:
        entry = raw["joints"][joint]
        universal, sign = (
            (entry["universal"], entry.get("sign", 1)) if isinstance(entry, dict) else (entry, 1)
        )
        raw["joints"][joint] = universal if sign == -1 else {"universal": universal, "sign": -1}


def _flexions(spec: Path, finger: str = "") -> list[str]:
    """The spec's flexion joints (of one finger when given), as `hands check` names them."""
    joints = load_spec(spec).joints
    return [j for j, u in joints.items() if u.endswith("_flex") and u.startswith(finger)]


def _signs(spec: Path, joints: list[str]) -> dict[str, float]:
    signs = load_spec(spec).signs
    return {joint: signs.get(joint, 1.0) for joint in joints}


def _turned_half(raw: dict) -> None:
    """The hand frame turned half a turn about z (the fix a palm measured from the flexions asked for)."""
    base = raw.setdefault("base", {})
    turned = frame.rpy_matrix(base.get("rpy", [0, 0, 0])) @ frame.rpy_matrix((0.0, 0.0, math.pi))
    base["rpy"] = list(frame.matrix_rpy(turned))


def _flipped_joints(problems: list[str]) -> set[str]:
    (problem,) = problems
    return set(re.findall(r"'([^']+)'", problem))


def test_a_correct_spec_passes_with_no_warning(spec):
    hand = load_hand(spec)
    lines, warnings, problems = frame_report(hand)
    assert warnings == [] and problems == [], (lines, warnings, problems)
    measured = frame.measure(hand)
    assert measured.side == "right"
    # The built-ins' and vendors' documented frames lie within 9 deg of what is measured (tolerance: 30).
    assert np.degrees(np.arccos(measured.fingers_point[2])) < 9
    assert np.degrees(np.arccos(measured.palm_faces[1])) < 7
    # every flexion, thumbs included, clearly the right way (the check's threshold is 0.3; the lowest, 0.70,
    # is the thumb of dexi-rs' Fourier hand, whose flexion at rest curls it across the palm)
    assert min(measured.flexion.values()) > 0.65
    assert set(measured.flexion) == set(_flexions(spec))


@pytest.mark.parametrize("name", [name for name in BUILTIN_HANDS if name not in HANDS])
def test_a_gripper_is_checked_for_where_its_fingers_point_only(name):
    """A gripper's jaws close sideways: no palm, side or flexion to judge."""
    hand = load_hand(name)
    assert frame_report(hand)[1:] == ([], [])
    measured = frame.measure(hand)
    assert measured.palm_faces is None and measured.side is None and measured.flexion == {}
    assert np.degrees(np.arccos(measured.fingers_point[2])) < 9


def test_ranges_that_do_not_tell_the_palm_leave_the_signs_unchecked_with_a_warning(tmp_path):
    source = builtin_hands()["leap"]
    raw = yaml.safe_load(source.read_text())
    tree = ET.parse(source.parent / raw["model"])
    for joint in tree.iter("joint"):
        if raw["joints"].get(joint.get("name"), "").endswith("_flex"):
            joint.find("limit").set("lower", "-1.0")
            joint.find("limit").set("upper", "1.0")
    tree.write(tmp_path / "leap.urdf")
    raw.update(name="even_leap", model=str(tmp_path / "leap.urdf"), poses={"open": {}, "grasp": {}})
    lines, warnings, problems = frame_report(load_hand(_write(tmp_path / "spec.yaml", raw)))
    assert problems == []
    assert warnings == [
        "the flexion joints' ranges reach as far both ways from 0, so the palm's side and the signs of the "
        "fingers' flexions are not checked: look at the `--png` picture"
    ]


def test_one_fingers_signs_flipped_are_refused_naming_them(spec):
    index = [j for j, u in load_spec(spec).joints.items() if u.startswith("index_")]
    edited = _edited(spec, lambda raw: _flip(raw, index))
    lines, warnings, problems = frame_report(load_hand(edited))
    assert warnings == []
    assert _flipped_joints(problems) == set(_flexions(spec, "index_"))
    assert "curl their finger away from the palm" in problems[0]
    had_sign = _signs(spec, _flexions(spec, "index_"))[_flexions(spec, "index_")[0]] == -1
    fix = "add `sign: -1` to joint(s)" if had_sign else "remove `sign: -1` from joint(s)"
    assert fix in problems[0]  # what undoes the edit (dexi-rs' Fourier index had `sign: -1`)


def test_every_sign_flipped_is_a_sign_problem_not_a_frame_to_rotate(spec):
    edited = _edited(spec, lambda raw: _flip(raw, list(raw["joints"])))
    lines, warnings, problems = frame_report(load_hand(edited))
    assert warnings == [], warnings  # the palm is where it was: nothing to rotate
    assert _flipped_joints(problems) == set(_flexions(spec))


def test_turned_with_every_sign_flipped_is_refused_and_suggest_undoes_both(spec, capsys):
    """The old check's trap: told to rotate a hand whose fingers all flex negative, the user got a hand with
    the thumb on the wrong side and every flexion inverted, which then passed."""
    edited = _edited(spec, lambda raw: (_turned_half(raw), _flip(raw, list(raw["joints"]))))
    assert main(["hands", "check", str(edited), "--suggest"]) == 1
    out = capsys.readouterr().out
    assert re.search(
        r"WARNING: the palm faces 1[78]\d deg away from \+y: put the model in the documented", out
    )
    assert "PROBLEM: " in out and "flexion joint(s) curl their finger away from the palm" in out

    suggested = yaml.safe_load(out.split("# measured by `hands check --suggest`")[1].split("\n", 1)[1])
    fixed = _edited(edited, lambda raw: raw.update(suggested))
    assert main(["hands", "check", str(fixed)]) == 0
    out = capsys.readouterr().out
    assert "WARNING" not in out and "PROBLEM" not in out, out
    assert _signs(fixed, _flexions(spec)) == _signs(spec, _flexions(spec))
    rpy = lambda s: frame.rpy_matrix(load_spec(s).base.rpy)  # noqa: E731
    assert np.allclose(rpy(fixed), rpy(spec), atol=1e-9)


def test_a_vendor_model_whose_fingers_flex_negative_needs_signs_not_a_turn(tmp_path, capsys):
    """The issue's LEAP: every flexion joint of the vendor's file turns the other way (axis and range
    negated); a spec without signs is told which joints need `sign: -1`, and the frame is left alone."""
    source = builtin_hands()["leap"]
    raw = yaml.safe_load(source.read_text())
    flexions = [joint for joint, universal in raw["joints"].items() if universal.endswith("_flex")]
    tree = ET.parse(source.parent / raw["model"])
    for joint in tree.iter("joint"):
        if joint.get("name") in flexions:
            axis, limit = joint.find("axis"), joint.find("limit")
            axis.set("xyz", " ".join(str(-float(v)) for v in axis.get("xyz").split()))
            lower, upper = float(limit.get("lower")), float(limit.get("upper"))
            limit.set("lower", str(-upper))
            limit.set("upper", str(-lower))
    tree.write(tmp_path / "leap.urdf")
    for pose in raw["poses"].values():
        pose.update({joint: -value for joint, value in pose.items() if joint in flexions})
    raw.update(name="vendor_leap", model=str(tmp_path / "leap.urdf"))
    spec = _write(tmp_path / "spec.yaml", raw)
    assert main(["hands", "check", str(spec), "--suggest"]) == 1
    out = capsys.readouterr().out
    assert "WARNING" not in out and "rotate" not in out
    listed = ", ".join(f"'{joint}'" for joint in flexions)
    assert f"against the universal sense: add `sign: -1` to joint(s) {listed} in `joints`" in out
    suggested = yaml.safe_load(out.split("# measured by `hands check --suggest`")[1].split("\n", 1)[1])
    assert "base" in suggested and suggested["base"]["rpy"] == [0.0, 0.0, 0.0]
    assert _signs(_edited(spec, lambda raw: raw.update(suggested)), flexions) == dict.fromkeys(flexions, -1.0)


def _mirrored_urdf(source: Path, target: Path) -> Path:
    """The model reflected through its x = 0 plane: a left hand from a right one (primitive shapes, which a
    reflection of their pose maps onto themselves)."""
    tree = ET.parse(source)
    for origin in tree.iter("origin"):
        x, y, z = (float(v) for v in origin.get("xyz", "0 0 0").split())
        roll, pitch, yaw = (float(v) for v in origin.get("rpy", "0 0 0").split())
        origin.set("xyz", f"{-x} {y} {z}")
        origin.set("rpy", f"{roll} {-pitch} {-yaw}")
    for joint in tree.iter("joint"):
        axis = joint.find("axis")
        if axis is not None:  # a rotation axis is reflected and turned (a pseudo-vector)
            x, y, z = (float(v) for v in axis.get("xyz").split())
            axis.set("xyz", f"{x} {-y} {-z}")
    tree.write(target)
    return target


@pytest.mark.parametrize("name", HANDS)
def test_a_mirrored_builtin_is_refused_naming_its_side(name, tmp_path):
    source = builtin_hands()[name]
    raw = yaml.safe_load(source.read_text())
    model = _mirrored_urdf(source.parent / raw["model"], tmp_path / "mirrored.urdf")
    raw.update(name=f"my_{name}", model=str(model))
    spec = _write(tmp_path / "spec.yaml", raw)
    lines, warnings, problems = frame_report(load_hand(spec))
    told_by = frame.measure(load_hand(name)).side_told_by  # the index where the thumb is centred (Dex3)
    assert warnings == []
    assert problems == [
        f"the model is a left hand (the {told_by} on +x, the palm on +y, the fingers on +z), the spec a "
        "right one: use the vendor's right-hand model, or declare `side: left`"
    ]
    raw["side"] = "left"
    assert frame_report(load_hand(_write(spec, raw)))[1:] == ([], [])


def test_the_vendors_left_hand_under_a_right_hand_spec_is_refused(user_allegro_spec, capsys):
    """example-robot-data ships the Allegro's mirror image too, with the same joint and link names."""
    left = str(example_robot_data_allegro()).replace("allegro_right_hand", "allegro_left_hand")
    spec = _edited(user_allegro_spec, lambda raw: raw.update(model=left))
    assert main(["hands", "check", str(spec), "--suggest"]) == 1
    out = capsys.readouterr().out
    assert "PROBLEM: the model is a left hand" in out and "declare `side: left`" in out
    assert "\nside: left\n" in out and "WARNING" not in out
    assert main(["hands", "check", str(_edited(spec, lambda raw: raw.update(side="left")))]) == 0
    assert "PROBLEM" not in capsys.readouterr().out


def test_the_fourier_left_hand_under_its_right_hand_spec_is_refused_and_passes_as_a_left_hand(
    user_fourier_spec, capsys
):
    """dexi-rs ships the Fourier hand's left model beside the right one, its names prefixed `L_`."""
    text = re.sub(r"\bR_", "L_", user_fourier_spec.read_text().replace("_right_hand_", "_left_hand_"))
    _refused_as_right_and_passes_as_left(user_fourier_spec.with_name("left.yaml"), text, capsys)


def test_the_orca_left_hand_under_its_right_hand_spec_is_refused_and_passes_as_a_left_hand(
    user_orca_spec, capsys
):
    """orca_arm's robot carries a left ORCA hand too: the right spec's joints and root renamed to the left
    hand's (the export names them differently, so by their place in the file) is the mirror image."""
    joints = [j for j in ET.parse(orca_arm_urdf()).getroot().iter("joint") if j.get("type") == "revolute"]
    right, left = ([j for j in joints if j.get("name").startswith(f"orcahand_{side}_")] for side in SIDES)
    names = {}
    for ours, theirs in zip(right, left, strict=True):
        names[ours.get("name")] = theirs.get("name")
        names[ours.find("child").get("link")] = theirs.find("child").get("link")
    text = re.sub(
        r"orcahand_right_[\w-]+", lambda m: names.get(m.group(0), m.group(0)), user_orca_spec.read_text()
    )
    _refused_as_right_and_passes_as_left(user_orca_spec.with_name("left.yaml"), text, capsys)


def _refused_as_right_and_passes_as_left(spec: Path, text: str, capsys) -> None:
    """A vendor's left-hand model under its right hand's spec (`text`, written to `spec`) is refused naming
    the side, and passes once the spec declares `side: left`."""
    spec.write_text(text)
    assert main(["hands", "check", str(spec)]) == 1
    out = capsys.readouterr().out
    assert "PROBLEM: the model is a left hand" in out and "declare `side: left`" in out, out
    assert main(["hands", "check", str(_edited(spec, lambda raw: raw.update(side="left")))]) == 0
    assert "PROBLEM" not in capsys.readouterr().out


@pytest.mark.parametrize("vendor", ["user_orca_spec", "user_allegro_spec"])
def test_two_fingers_named_as_each_other_are_refused(vendor, request):
    """The ORCA export names the middle and ring fingers' parts alike (`M-AP`, `M-PP`): a spec giving the
    middle finger's joints the ring's universal names, and the ring's the middle's, labels the links by them
    and would otherwise pass (also on a hand of three fingers: no little finger to order them by)."""
    spec = _unlabelled(request.getfixturevalue(vendor))

    def swap(universal: str) -> str:
        finger, rest = universal.split("_", 1)
        return "_".join([{"middle": "ring", "ring": "middle"}.get(finger, finger), rest])

    def swap_all(raw: dict) -> None:
        for joint, entry in raw["joints"].items():
            if isinstance(entry, dict):
                entry["universal"] = swap(entry["universal"])
            else:
                raw["joints"][joint] = swap(entry)

    swapped = _edited(spec, swap_all)
    problems = frame_report(load_hand(swapped))[2]
    assert any("the fingertips lie across the palm as index, ring, middle" in p for p in problems), problems
    assert frame_report(load_hand(spec))[2] == []


def test_a_side_that_is_neither_is_an_error(spec):
    with pytest.raises(ValueError, match=r"field 'side': 'up' is not one of \['right', 'left'\]"):
        load_spec(_edited(spec, lambda raw: raw.update(side="up")))


def test_a_hand_with_no_finger_link_is_one_line_naming_the_field(tmp_path, capsys):
    """Every link labelled palm: nothing says where the hand points, and the check says so."""
    source = builtin_hands()["inspire"]
    raw = yaml.safe_load(source.read_text())
    links = {link: [0, 0] for link in load_hand("inspire").link_names}
    raw.update(name="no_fingers", model=str(source.parent / raw["model"]), links=links)
    spec = _write(tmp_path / "no_fingers" / "spec.yaml", raw)
    assert main(["hands", "check", str(spec)]) != 0
    (last,) = capsys.readouterr().err.strip().splitlines()[-1:]
    assert f"{spec}: field 'links': no link is labelled as a finger" in last
