"""LeRobot's own ACT and diffusion policies in GaLR space, as a user runs them: two hands recorded with a
colour camera on the `opfa_sim` rig (`lerobot-record`), merged, turned into a latent dataset, trained with
`lerobot-train`, given joint-space processors, and run by `lerobot-eval` on each hand."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from subprocesses import run_command, run_lerobot_here

from lerobot_opfa import cli
from lerobot_opfa.envs.config import OpfaEnvConfig
from lerobot_opfa.experiments.failures import OUTCOMES, object_following

ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl"}
HANDS = ("umi", "inspire")
DEPTH = "observation.images.front_depth"


def lerobot(script: str, *flags: str) -> subprocess.CompletedProcess:
    return run_command([sys.executable, "-m", f"lerobot.scripts.{script}", *flags], env=ENV, timeout=600)


def opfa(*argv: str) -> None:
    """A `lerobot-opfa` command in this process (the LeRobot CLIs above run as subprocesses)."""
    assert cli.main(list(argv)) == 0, argv


@pytest.fixture(scope="module")
def latent(tmp_path_factory) -> Path:
    """One recorded episode per hand, merged with the packaged GaLR, as a latent dataset without depth."""
    root = tmp_path_factory.mktemp("stock")
    for hand in HANDS:
        done = lerobot(
            "lerobot_record", "--robot.type=opfa_sim", f"--robot.hand={hand}", "--robot.task=press_button",
            "--robot.depth_cameras=front", "--robot.rgb_cameras=front", "--robot.episode_time_s=1.2",
            f"--robot.calibration_dir={root / 'calibration'}", "--teleop.type=opfa_expert",
            f"--dataset.repo_id=local/{hand}", f"--dataset.root={root / hand}", "--dataset.num_episodes=1",
            "--dataset.episode_time_s=1.2", "--dataset.reset_time_s=0", "--dataset.fps=20",
            "--dataset.single_task=press the button", "--dataset.push_to_hub=false", "--display_data=false",
            "--play_sounds=false",
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-3000:]
    inputs = [str(root / hand) for hand in HANDS]
    opfa("dataset", "merge", "--inputs", *inputs, "--output", str(root / "merged"), "--galr", "default")
    opfa("policy", "latent-dataset", "--input", str(root / "merged"), "--output", str(root / "latent"),
         "--drop", DEPTH)  # fmt: skip
    return root / "latent"


def test_the_latent_dataset_keeps_the_colour_camera_and_says_what_its_frames_are(latent):
    dataset = LeRobotDataset("local/latent", root=latent)
    features = dataset.meta.features
    assert DEPTH not in features and features["observation.images.front_rgb"]["shape"][-1] == 3
    assert features["observation.state"]["names"][6:8] == ["z0", "z1"]
    frame = dataset[3]
    assert frame["observation.images.front_rgb"].std() > 0.05
    assert frame["observation.state"].abs().max() <= 1.0 + 1e-5  # normalised as opfa normalises
    assert json.loads((latent / "meta" / "opfa.json").read_text())["embodiments"] == list(HANDS)


STOCK = {
    "act": ["--policy.chunk_size=4", "--policy.n_action_steps=4", "--policy.dim_model=32",
            "--policy.dim_feedforward=64", "--policy.n_heads=2", "--policy.n_encoder_layers=1",
            "--policy.n_decoder_layers=1", "--policy.use_vae=false"],
    "diffusion": ["--policy.down_dims=[16,32]", "--policy.horizon=8", "--policy.n_action_steps=4",
                  "--policy.n_groups=4", "--policy.diffusion_step_embed_dim=16",
                  "--policy.crop_shape=[84,84]", "--policy.noise_scheduler_type=DDIM",
                  "--policy.num_inference_steps=4"],
}  # fmt: skip


@pytest.fixture(scope="module", params=sorted(STOCK))
def trained(request, latent, tmp_path_factory) -> tuple[str, Path]:
    """A stock policy trained 2 steps on the latent dataset: its type and checkpoint folder."""
    policy, out = request.param, tmp_path_factory.mktemp(f"train_{request.param}") / "train"
    done = lerobot(
        "lerobot_train", f"--policy.type={policy}", "--policy.device=cpu", "--policy.push_to_hub=false",
        "--policy.pretrained_backbone_weights=null", *STOCK[policy], "--dataset.repo_id=local/latent",
        f"--dataset.root={latent}", "--steps=2", "--batch_size=2", "--save_freq=2", "--num_workers=0",
        f"--output_dir={out}", "--wandb.enable=false",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return policy, out / "checkpoints" / "last" / "pretrained_model"


def test_a_stock_policy_trains_in_galr_space_and_lerobot_eval_runs_it_on_each_hand(
    latent, trained, tmp_path, capsys, monkeypatch
):
    policy, checkpoint = trained
    opfa("policy", "convert-io", "--policy", str(checkpoint), "--output", str(tmp_path / "joints"))
    assert "reads its action width (70: body + z)" in capsys.readouterr().out  # body 6 + z 64
    steps = json.loads((tmp_path / "joints" / "policy_postprocessor.json").read_text())["steps"]
    assert [s["registry_name"] for s in steps][-3:-1] == ["opfa_unnormalize", "opfa_decode_joints"]
    for hand in HANDS:
        done = lerobot(
            "lerobot_eval", f"--policy.path={tmp_path / 'joints'}", "--policy.device=cpu", "--env.type=opfa",
            "--env.task=press_button", f"--env.hand={hand}", "--env.obs_type=rgb", "--env.episode_length=4",
            "--eval.n_episodes=1", "--eval.batch_size=1", f"--output_dir={tmp_path / 'eval' / hand}",
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-3000:]
        info = json.loads((tmp_path / "eval" / hand / "eval_info.json").read_text())
        assert info["overall"]["n_episodes"] == 1
    wrong = [f"--policy.path={tmp_path / 'joints'}", "--env.type=opfa", "--env.policy_action_width=69"]
    with pytest.raises(SystemExit):
        run_lerobot_here("lerobot_eval", wrong, monkeypatch)
    refused = capsys.readouterr().err.strip().splitlines()[-1]
    assert (
        refused.startswith("error: `env.policy_action_width`: 69, but the policy at") and "70 wide" in refused
    )
    env = OpfaEnvConfig(
        task="press_button", hand="umi", obs_type="rgb", episode_length=4, policy_action_width=70
    )
    following = object_following(tmp_path / "joints", env, episodes=2, seed=0)  # the stock policy's class
    assert following["following_episodes"] == 2 and math.isfinite(following["follows_object"]), following
    assert sorted(following["outcomes"]) == sorted(OUTCOMES) and sum(following["outcomes"].values()) == 2
    interleaved_actions(tmp_path / "joints", policy, latent.parent)


def interleaved_actions(checkpoint: Path, policy_type: str, recorded: Path) -> None:
    """Two pipelines of one converted checkpoint in one process, called in turn: each gives its own hand's
    action entries (6 + 1 for umi, 6 + 6 for Inspire)."""
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    import lerobot_policy_opfa  # noqa: F401  (the plugin: registers the steps, as LeRobot's CLIs load it)

    policy = get_policy_class(policy_type).from_pretrained(checkpoint).eval()
    frames = {hand: LeRobotDataset(f"local/{hand}", root=recorded / hand)[5] for hand in HANDS}
    pipelines = {h: make_pre_post_processors(policy.config, pretrained_path=str(checkpoint)) for h in HANDS}
    for hand in (*HANDS, *HANDS):
        pre, post = pipelines[hand]
        observation = {k: frames[hand][k] for k in ("observation.state", "observation.images.front_rgb")}
        policy.reset()
        with torch.no_grad():
            action = post(policy.select_action(pre({**observation, "robot_type": hand})))
        assert action.shape == (1, len(frames[hand]["action"])), hand


def test_a_policy_with_its_own_relative_action_step_is_refused_in_one_line(trained, tmp_path, capsys):
    """pi0, pi05, pi0_fast and groot put a relative-action step before their normaliser, as here; LeRobot
    would pair opfa's decode step with it once reloaded."""
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.processor.relative_action_processor import (
        AbsoluteActionsProcessorStep,
        RelativeActionsProcessorStep,
    )

    import lerobot_policy_opfa  # noqa: F401  (registers the steps, as LeRobot's CLIs load it)
    from lerobot_opfa.policy.deploy import checkpoint_config

    policy, checkpoint = trained
    pi0_style = tmp_path / "pi0_style"
    shutil.copytree(checkpoint, pi0_style)
    pre, post = make_pre_post_processors(checkpoint_config(checkpoint), pretrained_path=str(checkpoint))
    relative = RelativeActionsProcessorStep(enabled=False)
    pre.steps.insert([type(s).__name__ for s in pre.steps].index("NormalizerProcessorStep"), relative)
    post.steps.insert(1, AbsoluteActionsProcessorStep(enabled=False, relative_step=relative))
    pre.save_pretrained(pi0_style)
    post.save_pretrained(pi0_style)
    assert (
        cli.main(["policy", "convert-io", "--policy", str(pi0_style), "--output", str(tmp_path / "o")]) != 0
    )
    err = capsys.readouterr().err.strip()
    assert f"{policy}'s preprocessor has its own relative-action step" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_convert_io_refuses_a_latent_dataset_the_policy_was_not_trained_on(latent, trained, tmp_path, capsys):
    """Another latent dataset of the same width (body 6 + z 64: umi's demos alone) has other statistics."""
    _, checkpoint = trained
    other = tmp_path / "latent_umi"
    opfa(
        "policy",
        "latent-dataset",
        "--input",
        str(latent.parent / "umi"),
        "--output",
        str(other),
        "--drop",
        DEPTH,
    )
    capsys.readouterr()
    convert = ["policy", "convert-io", "--policy", str(checkpoint), "--dataset", str(other)]
    assert cli.main([*convert, "--output", str(tmp_path / "o")]) != 0
    err = capsys.readouterr().err.strip()
    assert f"{checkpoint} was not trained on {other}" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "o").exists()
