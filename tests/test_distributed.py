"""Training on several processes: LeRobot's training loop (accelerate, the path to several GPUs or
machines) under torchrun, two CPU processes on gloo, trains the opfa policy as one process does with the
doubled batch: each rank takes its share of every batch, and the gradients are averaged."""

from __future__ import annotations

import os
import re
import statistics
import sys
from pathlib import Path

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from subprocesses import run_command

from lerobot_opfa.datasets.synthetic import write_synthetic_dataset
from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

BIN = Path(sys.executable).parent
ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
COMMANDS = {
    "lerobot-opfa train": [str(BIN / "lerobot-opfa"), "train"],
    "lerobot-train": [str(BIN / "lerobot-train")],
}
POLICY = ["--policy.type=opfa", "--policy.action_space=raw", "--policy.device=cpu", "--policy.horizon=8",
          "--policy.push_to_hub=false", "--policy.down_dims=[16,32]", "--policy.n_action_steps=4",
          "--policy.pointcloud_widths=[8,16]", "--policy.pointcloud_feature_dim=8"]  # fmt: skip
STEPS, BATCH = 12, 4
LOSS = re.compile(r"step:(\d+) .*? loss:([\d.]+)")


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("distributed") / "umi"
    write_synthetic_dataset(root, "umi", episodes=4, frames=24, n_points=32, seed=0)
    return root


def train(command: str, demos: Path, out: Path, processes: int) -> str:
    launch = [str(BIN / "torchrun"), "--standalone", f"--nproc_per_node={processes}"] if processes > 1 else []
    args = [*POLICY, "--dataset.repo_id=local/umi", f"--dataset.root={demos}", f"--steps={STEPS}",
            f"--batch_size={BATCH * 2 // processes}", "--log_freq=1", f"--save_freq={STEPS}",
            "--num_workers=0", f"--output_dir={out}", "--wandb.enable=false", "--seed=0"]  # fmt: skip
    done = run_command([*launch, *COMMANDS[command], *args], env=ENV, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout + done.stderr


@pytest.fixture(scope="module")
def one_process(demos, tmp_path_factory) -> str:
    """LeRobot's own loop on one process with the doubled batch: both commands' two-process runs must match
    it (`lerobot-opfa train` serves the same batches as `lerobot-train`: test_training_fast)."""
    return train("lerobot-train", demos, tmp_path_factory.mktemp("distributed") / "one", processes=1)


@pytest.mark.parametrize("command", list(COMMANDS))
def test_two_processes_train_as_one_with_the_doubled_batch_and_the_checkpoint_acts(
    demos, one_process, tmp_path, command
):
    two = train(command, demos, tmp_path / "two", processes=2)
    assert f"Effective batch size: {BATCH} x 2 = {2 * BATCH}" in two  # both ranks joined the process group
    one = one_process
    losses = [{int(s): float(v) for s, v in LOSS.findall(log)} for log in (two, one)]
    assert sorted(losses[0]) == sorted(losses[1]) == list(range(1, STEPS + 1))
    relative = [abs(losses[0][s] - losses[1][s]) / losses[1][s] for s in losses[1]]
    assert statistics.median(relative) < 0.05, losses  # the same batches, averaged gradients
    checkpoint = tmp_path / "two" / "checkpoints" / "last" / "pretrained_model"
    policy = OpfaPolicy.from_pretrained(checkpoint)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    frame = LeRobotDataset("local/umi", root=demos)[0]
    observation = {k: v[None] for k, v in frame.items() if k.startswith("observation.")}
    with torch.no_grad():
        action = post(policy.select_action(pre(observation)))
    assert action.shape == (1, frame["action"].shape[-1]) and action.isfinite().all()
