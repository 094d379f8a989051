"""`lerobot-opfa hands ...` as a user runs it: a real subprocess of the installed console script."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import BUILTIN_HANDS


def _cli(*args: str) -> subprocess.CompletedProcess:
    exe = shutil.which("lerobot-opfa") or shutil.which(
        "lerobot-opfa", path=str(__import__("pathlib").Path(sys.executable).parent)
    )
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=300)


def test_hands_list_json():
    result = _cli("hands", "list", "--json")
    assert result.returncode == 0, result.stderr
    rows = {row["name"]: row for row in json.loads(result.stdout)}
    assert sorted(rows) == BUILTIN_HANDS
    assert rows["umi"]["dof"] == 1 and rows["umi"]["joints"] == 2
    assert rows["umi"]["fingers"] == ["palm", "thumb", "index"]


def test_hands_cloud_npz(tmp_path, user_allegro_spec):
    out = tmp_path / "cloud.npz"
    result = _cli(
        "hands",
        "cloud",
        str(user_allegro_spec),
        "--n-points",
        "300",
        "--batch",
        "5",
        "--seed",
        "3",
        "--out",
        str(out),
    )
    assert result.returncode == 0, result.stderr
    data = np.load(out)
    assert data["points"].shape == (5, 300, 3) and data["points"].dtype == np.float32
    assert data["labels"].shape == (5, 300, 2) and np.issubdtype(data["labels"].dtype, np.integer)
    assert data["joints"].shape == (5, 16) and data["joints"].dtype == np.float32


@pytest.mark.parametrize("joints", ["open", "random"])
def test_hands_show_png(tmp_path, joints):
    out = tmp_path / "hand.png"
    result = _cli("hands", "show", "umi", "--out", str(out), "--joints", joints)
    assert result.returncode == 0, result.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unknown_hand_lists_builtins():
    result = _cli("hands", "cloud", "no_such_hand", "--out", "x.npz")
    assert result.returncode == 2
    assert "unknown hand 'no_such_hand'" in result.stderr and "umi" in result.stderr
