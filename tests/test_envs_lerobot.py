"""The benchmark through LeRobot, as a user runs it: the demos CLI writes a dataset that LeRobot loads,
`lerobot-eval` runs the registered `opfa` env with a (tiny, untrained) stock policy checkpoint (a real
subprocess of the installed console script), and `sim show` draws a scene. The `lerobot-opfa` commands run
in-process through `cli.main` to spare the tests a second LeRobot import."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest
from subprocesses import run_command

from lerobot_opfa.cli import main
from lerobot_opfa.hands.registry import load_hand

N_POINTS = 64
SUBPROCESS_ENV = {**os.environ, "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1"}


def _run(exe: str, *args: str) -> subprocess.CompletedProcess:
    path = shutil.which(exe, path=str(Path(sys.executable).parent)) or shutil.which(exe)
    return run_command([path, *args], timeout=600, env=SUBPROCESS_ENV)


@pytest.fixture(scope="module")
def demo_dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("demos") / "press_umi"
    code = main([
        "sim", "demos", "--task", "press_button", "--hand", "umi", "--episodes", "2",
        "--regions", "near_left,far_right", "--seed", "5", "--output-dir", str(root),
        "--n-points", str(N_POINTS), "--repo-id", "local/press_umi",
    ])  # fmt: skip
    assert code == 0
    return root


def test_demos_dataset_loads(demo_dataset):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset("local/press_umi", root=demo_dataset)
    hand = load_hand("umi")
    assert dataset.num_episodes == 2
    names = ["wrist_x", "wrist_y", "wrist_z", "wrist_yaw", "wrist_pitch", "wrist_roll", *hand.joint_names]
    assert dataset.features["observation.state"]["names"] == names
    assert dataset.features["action"]["names"] == names
    frame = dataset[0]
    assert frame["observation.state"].shape == frame["action"].shape == (len(names),)
    assert frame["observation.pointcloud"].shape == (3 * N_POINTS,)
    assert frame["observation.environment_state"].shape == (11,)
    assert frame["task"] == "press the button"
    meta = json.loads((demo_dataset / "meta" / "opfa_demos.json").read_text())
    assert [e["region"] for e in meta["episodes"]] == ["near_left", "far_right"]


def test_lerobot_eval_runs_the_registered_env(demo_dataset, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    meta = LeRobotDatasetMetadata("local/press_umi", root=demo_dataset)
    config = ACTConfig(
        device="cpu", chunk_size=4, n_action_steps=4, dim_model=16, n_heads=2, dim_feedforward=32,
        n_encoder_layers=1, n_decoder_layers=1, use_vae=False, push_to_hub=False,
    )  # fmt: skip
    policy = make_policy(config, ds_meta=meta)
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=meta.stats)
    checkpoint = tmp_path / "pretrained_model"
    for part in (policy, preprocessor, postprocessor):
        part.save_pretrained(checkpoint)

    out = tmp_path / "eval"
    result = _run(
        "lerobot-eval", f"--policy.path={checkpoint}", "--env.type=opfa", "--env.task=press_button",
        "--env.hand=umi", "--env.obs_type=pointcloud_state", f"--env.n_points={N_POINTS}",
        "--env.episode_length=6", "--eval.n_episodes=1", "--eval.batch_size=1", "--policy.device=cpu",
        f"--output_dir={out}",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1
    assert "pc_success" in info["overall"]


def test_sim_show_png_and_video(tmp_path, capsys):
    png, mp4 = tmp_path / "scene.png", tmp_path / "expert.mp4"
    code = main(
        ["sim", "show", "--task", "press_button", "--hand", "umi", "--out", str(png), "--video", str(mp4)]
    )
    assert code == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert mp4.stat().st_size > 1000 and "expert succeeded" in capsys.readouterr().out


def test_sim_show_says_why_the_expert_failed(tmp_path, capsys, monkeypatch):
    from lerobot_opfa.envs.experts import ArmExpert

    def stay_home(expert):
        expert.t += 1
        return np.concatenate([expert.env.home, expert.open])

    monkeypatch.setattr(ArmExpert, "act", stay_home)
    png, mp4 = tmp_path / "scene.png", tmp_path / "expert.mp4"
    argv = ["sim", "show", "--task", "press_button", "--hand", "umi", "--out", str(png), "--video", str(mp4)]
    assert main(argv) == 0
    assert "expert failed: reach: the button never moved" in capsys.readouterr().out


def test_cli_bad_names_are_clear_errors(tmp_path, capsys):
    for flag, value, message in [
        (
            "--task",
            "juggle",
            "unknown task 'juggle'; valid tasks: lift, lift_box, pick_place, press_button, pull_drawer",
        ),
        ("--hand", "hook", "unknown hand 'hook': not a built-in (ability, allegro"),
        ("--hand", "inspire+xhand", "lift takes one hand, got two ('inspire+xhand'); the two-hand tasks are"),
        ("--regions", "moon", "unknown region(s) ['moon']; valid regions: all, near_right"),
    ]:
        args = {"--task": "lift", "--hand": "umi", "--regions": "all", flag: value}
        code = main(["sim", "demos", *[x for kv in args.items() for x in kv], "--episodes", "1",
                     "--output-dir", str(tmp_path / "x")])  # fmt: skip
        assert code == 2
        assert message in capsys.readouterr().err
