"""The YAML files users write (joint maps, calibrations, specs) are read by one loader: a key given twice
and a tab are one-line errors naming the file and the line."""

from __future__ import annotations

import pytest

from lerobot_opfa.datasets.joint_map import JointMap, JointMapError
from lerobot_opfa.hands.spec import HandSpec, HandSpecError
from lerobot_opfa.pointclouds import DepthRig, DepthRigError


@pytest.mark.parametrize(
    ("load", "error"),
    [(JointMap.load, JointMapError), (DepthRig.load, DepthRigError), (HandSpec.load, HandSpecError)],
)
def test_a_key_given_twice_is_refused_naming_both_lines(tmp_path, load, error):
    path = tmp_path / "file.yaml"
    path.write_text(
        "hand: inspire\njoints:\n  index.pos: index_mcp\n  index.pos: {joint: index_mcp, scale: 0.5}\n"
    )
    with pytest.raises(error, match=r"line 4.*'index.pos' given twice \(lines 3 and 4\)") as info:
        load(path)
    assert "\n" not in str(info.value) and str(path.name) in str(info.value)


def test_a_tab_is_named_with_its_line(tmp_path):
    path = tmp_path / "map.yaml"
    path.write_text("hand: inspire\njoints:\n\tindex.pos: index_mcp\n")
    with pytest.raises(
        JointMapError, match=r"map.yaml: line 3, column 1: a tab character; YAML indents with spaces"
    ):
        JointMap.load(path)
