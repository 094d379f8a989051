"""Every way a spec can be wrong gives an error that names the file and the field."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from lerobot_opfa.hands import HandModel, HandSpec, HandSpecError


def _edit(folder: Path, change) -> Path:
    spec_path = folder / "spec.yaml"
    raw = yaml.safe_load(spec_path.read_text())
    change(raw)
    spec_path.write_text(yaml.safe_dump(raw))
    return spec_path


def _raises(spec_path: Path, field: str, words: str) -> None:
    with pytest.raises(HandSpecError) as info:
        HandModel.from_spec(spec_path)
    message = str(info.value)
    assert str(spec_path.resolve()) in message
    assert f"field '{field}'" in message
    assert words in message


def test_valid_spec_loads(umi_copy):
    spec = HandSpec.load(umi_copy / "spec.yaml")
    assert spec.actuated_joints == ["left_jaw_joint"]
    assert list(spec.couplings) == ["right_jaw_joint"]


def test_unknown_joint(umi_copy):
    path = _edit(umi_copy, lambda r: r["joints"].update(wrist_joint="index_mcp_flex"))
    _raises(path, "joints", "unknown joint(s) ['wrist_joint']")


def test_unknown_link(umi_copy):
    path = _edit(umi_copy, lambda r: r["links"].update(ghost=[2, 1]))
    _raises(path, "links", "unknown link(s) ['ghost']")


def test_joint_missing_from_mapping(umi_copy):
    path = _edit(umi_copy, lambda r: r.pop("couplings"))
    _raises(path, "joints", "['right_jaw_joint'] are neither actuated")


def test_link_with_geometry_unlabelled(umi_copy):
    path = _edit(umi_copy, lambda r: r["links"].pop("right_jaw"))
    _raises(path, "links", "['right_jaw'] carry geometry")


def test_universal_name_not_in_table(umi_copy):
    path = _edit(umi_copy, lambda r: r["joints"].update(left_jaw_joint="jaw_width"))
    _raises(path, "joints.left_jaw_joint", "'jaw_width' is not in the universal joint table")


def test_universal_name_used_twice(umi_copy):
    def change(raw):
        raw.pop("couplings")
        raw["joints"]["right_jaw_joint"] = "gripper_aperture"

    _raises(_edit(umi_copy, change), "joints", "used by more than one joint")


def test_coupling_cycle(umi_copy):
    def change(raw):
        raw["joints"] = {"left_jaw_joint": "gripper_aperture"}
        raw["couplings"] = {
            "right_jaw_joint": {"source": "extra_a"},
            "extra_a": {"source": "extra_b"},
            "extra_b": {"source": "right_jaw_joint"},
        }

    _raises(_edit(umi_copy, change), "couplings", "coupling cycle: ")


def test_model_file_missing(umi_copy):
    (umi_copy / "umi.urdf").unlink()
    _raises(umi_copy / "spec.yaml", "model", "not found")


def test_model_file_does_not_parse(umi_copy):
    (umi_copy / "umi.urdf").write_text("<robot name='broken'><link name='base'></robot")
    _raises(umi_copy / "spec.yaml", "model", "does not parse as URDF")


def test_model_of_unknown_format(umi_copy):
    path = _edit(umi_copy, lambda r: r.update(model="umi.obj"))
    _raises(path, "model", "neither URDF")


def test_pose_outside_limits(umi_copy):
    path = _edit(umi_copy, lambda r: r["poses"]["open"].update(left_jaw_joint=0.5))
    _raises(path, "poses.open.left_jaw_joint", "outside the model's limits")


def test_missing_pose(umi_copy):
    path = _edit(umi_copy, lambda r: r["poses"].pop("grasp"))
    _raises(path, "poses", "pose 'grasp' missing")


def test_bad_link_label(umi_copy):
    path = _edit(umi_copy, lambda r: r["links"].update(base=[7, 0]))
    _raises(path, "links.base", "expected [finger 0-5, segment >= 0]")


def test_unknown_top_level_field(umi_copy):
    path = _edit(umi_copy, lambda r: r.update(jionts={}))
    _raises(path, "jionts", "unknown field")
