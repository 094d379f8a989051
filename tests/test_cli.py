"""The `lerobot-opfa` command line as a user meets it: the hands commands as a real subprocess of the
installed console script, named checkpoints, one-line errors for mistakes, summaries of what was written,
and start-up without the heavy libraries."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest
from conftest import BUILTIN_HANDS
from subprocesses import run_command

from lerobot_opfa import cli
from lerobot_opfa.envs import demos as demos_module
from lerobot_opfa.galr import checkpoints
from lerobot_opfa.hands.registry import load_hand


def _cli(*args: str) -> subprocess.CompletedProcess:
    exe = shutil.which("lerobot-opfa") or shutil.which(
        "lerobot-opfa", path=str(__import__("pathlib").Path(sys.executable).parent)
    )
    return run_command([exe, *args], timeout=300)


def _cli_here(capsys, *args: str) -> subprocess.CompletedProcess:
    """`lerobot-opfa` run in this process (`test_hands_list_json` runs the installed command)."""
    code = cli.main(list(args))
    out = capsys.readouterr()
    return subprocess.CompletedProcess(["lerobot-opfa", *args], code, out.out, out.err)


def test_hands_list_json():
    result = _cli("hands", "list", "--json")
    assert result.returncode == 0, result.stderr
    rows = {row["name"]: row for row in json.loads(result.stdout)}
    assert sorted(rows) == BUILTIN_HANDS
    assert rows["umi"]["dof"] == 1 and rows["umi"]["joints"] == 2
    assert rows["umi"]["fingers"] == ["palm", "thumb", "index"]


def test_hands_cloud_npz(tmp_path, user_allegro_spec, capsys):
    out = tmp_path / "cloud.npz"
    result = _cli_here(
        capsys,
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
def test_hands_show_png(tmp_path, joints, capsys):
    out = tmp_path / "hand.png"
    result = _cli_here(capsys, "hands", "show", "umi", "--out", str(out), "--joints", joints)
    assert result.returncode == 0, result.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unknown_hand_lists_builtins(capsys):
    result = _cli_here(capsys, "hands", "cloud", "no_such_hand", "--out", "x.npz")
    assert result.returncode == 2
    assert "unknown hand 'no_such_hand'" in result.stderr and "umi" in result.stderr


def one_error_line(capsys, argv: list[str]) -> str:
    """Runs the CLI, expecting a user mistake: exit code 2 and exactly one line on stderr."""
    assert cli.main(argv) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, lines
    return lines[0]


def test_packaged_checkpoints_are_listed_and_load_by_name(capsys):
    assert cli.main(["galr", "list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in checkpoints.PACKAGED)
    assert "hands: ability, allegro" in out and "dex3" not in out, out  # the paper's 11, without the Dex3
    assert "lerobot-opfa galr pretrain --init NAME --hands +HAND" in out
    assert checkpoints.load("default").config.hand_names  # a real checkpoint, by name


def test_galr_eval_by_name(tmp_path, capsys):
    report = tmp_path / "eval.json"
    argv = [
        "galr",
        "eval",
        "--checkpoint",
        "default",
        "--hands",
        "umi",
        "--states",
        "4",
        "--json",
        str(report),
    ]
    assert cli.main(argv) == 0
    assert json.loads(report.read_text())["mean"]["joint_rmse_deg"] >= 0


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (lambda p: p.mkdir() or p, "is not a GaLR checkpoint folder (it has no config.json"),
        (lambda p: p / "missing", "not found: not a packaged name (default, long), not a folder"),
    ],
    ids=["folder-without-checkpoint", "missing-folder"],
)
def test_a_checkpoint_that_is_not_there_is_one_line(tmp_path, capsys, make, expected):
    folder = make(tmp_path / "ckpt")
    line = one_error_line(
        capsys, ["galr", "eval", "--checkpoint", str(folder), "--json", str(tmp_path / "x")]
    )
    assert expected in line


def test_embed_names_the_shape_and_joint_order_it_needs(tmp_path, capsys):
    np.save(tmp_path / "q.npy", np.zeros((2, 5)))
    argv = ["galr", "embed", "--checkpoint", "default", "--hand", "umi", "--joints", str(tmp_path / "q.npy")]
    line = one_error_line(capsys, [*argv, "--out", str(tmp_path / "z.npy")])
    assert "need shape (B, 1)" in line


def record(tmp_path, *extra: str) -> list[str]:
    return ["sim", "demos", "--task", "press_button", "--hand", "umi", "--episodes", "1", "--n-points", "32",
            "--output-dir", str(tmp_path / "demos"), *extra]  # fmt: skip


def test_sim_demos_refuses_an_existing_folder_unless_told(tmp_path, capsys):
    assert cli.main(record(tmp_path, "--depth-cameras", "front,left")) == 0
    assert "wrote" in capsys.readouterr().out
    meta = json.loads((tmp_path / "demos" / "meta" / demos_module.META_FILE).read_text())
    assert meta["depth_cameras"] == ["front", "left"]  # what the env rendered with
    assert "pass --overwrite" in one_error_line(capsys, record(tmp_path))
    assert cli.main(record(tmp_path, "--overwrite", "--pointcloud-source", "geometry")) == 0


def test_sim_demos_without_a_success_fails_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(demos_module, "expert_episode", lambda env, seed, region: ([], False))
    line = one_error_line(capsys, record(tmp_path, "--pointcloud-source", "geometry"))
    assert (
        "no expert episode of press_button with 'umi' succeeded in 3 attempts" in line and "sim show" in line
    )
    assert not (tmp_path / "demos").exists() and list(tmp_path.iterdir()) == []


def test_merge_of_a_missing_folder_is_one_line_and_a_merge_says_what_it_wrote(tmp_path, capsys):
    assert cli.main(record(tmp_path, "--pointcloud-source", "geometry")) == 0
    missing = tmp_path / "not_recorded"
    argv = [
        "dataset",
        "merge",
        "--inputs",
        str(tmp_path / "demos"),
        str(missing),
        "--output",
        str(tmp_path / "m"),
    ]
    assert (
        one_error_line(capsys, argv) == f"error: {missing}: not a LeRobotDataset folder (no meta/info.json)"
    )
    assert (
        cli.main(["dataset", "merge", "--inputs", str(tmp_path / "demos"), "--output", str(tmp_path / "m")])
        == 0
    )
    assert re.search(r"wrote .*/m: 1 episodes, \d+ frames of umi$", capsys.readouterr().out.strip())


def test_light_commands_do_not_import_torch_or_lerobot():
    code = (
        "import sys; from lerobot_opfa.cli import main; main(['hands', 'list']); main(['galr', 'list']); "
        "heavy = [m for m in ('torch', 'lerobot', 'mujoco', 'gymnasium') if m in sys.modules]; "
        "assert not heavy, heavy"
    )
    result = run_command([sys.executable, "-c", code], timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]


def test_wheel_ships_checkpoints_and_hand_models_without_training_logs(tmp_path):
    import zipfile
    from pathlib import Path

    root = Path(__file__).parents[1]
    command = [
        sys.executable,
        "-m",
        "pip",
        "wheel",
        "--no-deps",
        "--no-build-isolation",
        "-q",
        "-w",
        str(tmp_path),
        str(root),
    ]
    result = run_command(command, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    (wheel,) = tmp_path.glob("lerobot_policy_opfa-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for name in checkpoints.PACKAGED.values():
        for file in checkpoints.CHECKPOINT_FILES:
            assert f"lerobot_opfa/checkpoints/{name[0]}/{file}" in names
    assert not [n for n in names if n.endswith("metrics.jsonl")]
    assert "lerobot_opfa/hand_models/leap/spec.yaml" in names and "lerobot_policy_opfa/__init__.py" in names


def test_demo_progress_bar_counts_what_it_says(tmp_path, monkeypatch):
    """`make demo`'s bar advances once per evaluated hand and says so (the work before it is not counted)."""
    import argparse

    from lerobot_opfa import demo
    from lerobot_opfa.experiments import jobs

    bars = []

    class Bar:
        def __init__(self, total, desc):
            self.total, self.desc, self.n = total, desc, 0
            bars.append(self)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def update(self, n=1):
            self.n += n

    class Workspace:
        def __init__(self, root, scale, galr):
            self.root = root

        def evaluate(self, evaluation):
            return {"condition": evaluation.training.condition, "hand": evaluation.hand,
                    "task": evaluation.task, "regions": list(evaluation.regions), "training": "t",
                    "successes": [True, False]}  # fmt: skip

    monkeypatch.setattr(demo, "tqdm", Bar)
    monkeypatch.setattr(jobs, "Workspace", Workspace)
    args = argparse.Namespace(task="press_button", hands="umi,inspire,xhand", region="mid_center",
                              galr="long", output_dir=tmp_path)  # fmt: skip
    demo.policy_table(args)
    (bar,) = bars
    assert bar.total == bar.n == 6 and "evaluated" in bar.desc, "three hands, OPFA and its control"
    success = json.loads((tmp_path / "success.json").read_text())
    assert success["opfa"]["xhand"] == success["untrained"]["xhand"] == {"successes": 1, "episodes": 2}


def test_hands_list_shows_each_hands_joints_with_units_and_limits(capsys):
    table = _cli_here(capsys, "hands", "list", "--joints")
    assert table.returncode == 0, table.stderr
    assert "umi: joint" in table.stdout and "thumb_bend" in table.stdout
    listed = _cli_here(capsys, "hands", "list", "--joints", "--json")
    rows = {row["name"]: row for row in json.loads(listed.stdout)}
    (jaw,) = rows["umi"]["joint_limits"]
    assert jaw["unit"] == "m" and 0 <= jaw["lower"] < jaw["upper"] < 0.1, jaw
    inspire = {j["joint"]: j for j in rows["inspire"]["joint_limits"]}
    assert len(inspire) == rows["inspire"]["dof"] and all(j["unit"] == "rad" for j in inspire.values())
    model = load_hand("inspire")
    assert inspire["thumb_bend"]["upper"] == pytest.approx(
        model.upper[model.joint_names.index("thumb_bend")].item()
    )
