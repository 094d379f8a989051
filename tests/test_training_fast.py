"""`lerobot-opfa train`, LeRobot's training on the dataset held in memory: items equal to LeRobotDataset's
for every index and key (windows, `*_is_pad`), and the command as a user runs it: checkpoints, logged steps,
the same losses as `lerobot-train`, resume, and clear errors for datasets it cannot hold."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from subprocesses import run_command

from lerobot_opfa import cli
from lerobot_opfa.datasets.in_memory import InMemoryDataset
from lerobot_opfa.datasets.merge import merge_datasets
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset
from lerobot_opfa.policy.configuration_opfa import OpfaConfig

ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "MUJOCO_GL": "egl",
       "OMP_NUM_THREADS": "1"}  # fmt: skip
TINY = [
    "--policy.type=opfa", "--policy.action_space=raw", "--policy.device=cpu", "--policy.push_to_hub=false",
    "--policy.down_dims=[16,32]", "--policy.horizon=8", "--policy.n_action_steps=4",
    "--policy.pointcloud_widths=[16,32]", "--policy.pointcloud_feature_dim=16", "--policy.n_groups=4",
    "--policy.diffusion_step_embed_dim=16", "--batch_size=4", "--log_freq=1", "--wandb.enable=false",
]  # fmt: skip


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    """Three scripted demos recorded by the simulator (episodes of different lengths)."""
    root = tmp_path_factory.mktemp("fast") / "demos"
    code = cli.main([
        "sim", "demos", "--task", "press_button", "--hand", "umi", "--episodes", "3",
        "--regions", "mid_center", "--output-dir", str(root), "--n-points", "32", "--repo-id", "local/demos",
    ])  # fmt: skip
    assert code == 0
    return root


@pytest.fixture(scope="module")
def merged(tmp_path_factory) -> Path:
    """Two hands merged: int (`observation.embodiment`) and bool (joint mask) columns, 9- and 12-frame
    episodes."""
    root = tmp_path_factory.mktemp("fast")
    write_synthetic_dataset(root / "umi", "umi", episodes=2, frames=12, n_points=16, seed=0)
    write_synthetic_dataset(root / "inspire", "inspire", episodes=2, frames=9, n_points=16, seed=1)
    return merge_datasets([root / "umi", root / "inspire"], root / "merged", repo_id="local/merged")


def _assert_same_items(reference: LeRobotDataset, fast: InMemoryDataset) -> None:
    assert len(fast) == len(reference)
    for i in range(len(reference)):
        expected, got = reference[i], fast[i]
        assert list(got) == list(expected), i
        for key, value in expected.items():
            if isinstance(value, torch.Tensor):
                same = got[key].dtype == value.dtype and got[key].shape == value.shape
                assert same and torch.equal(got[key], value), (i, key)
            else:
                assert got[key] == value, (i, key)


@pytest.mark.parametrize("name", ["demos", "merged"])
@pytest.mark.parametrize("episodes", [None, [0, 2]])
def test_items_equal_lerobot_dataset(name, episodes, request):
    """Every item, every key, with the opfa policy's default windows (16 actions from 2 observations back:
    longer than these episodes, so both ends pad)."""
    root = request.getfixturevalue(name)
    meta = LeRobotDatasetMetadata(f"local/{name}", root=root)
    delta = resolve_delta_timestamps(OpfaConfig(device="cpu"), meta)
    reference = LeRobotDataset(f"local/{name}", root=root, delta_timestamps=delta, episodes=episodes)
    fast = InMemoryDataset(reference)
    assert any(item["action_is_pad"].any() for item in (reference[0], reference[len(reference) - 1]))
    _assert_same_items(reference, fast)
    batch = fast.__getitems__([len(fast) - 1, 0, 3])
    assert [b["index"].item() for b in batch] == [reference[i]["index"].item() for i in (len(fast) - 1, 0, 3)]
    assert (fast.num_frames, fast.num_episodes, fast.episodes) == (
        reference.num_frames,
        reference.num_episodes,
        reference.episodes,
    )
    assert fast.absolute_to_relative_idx == reference.absolute_to_relative_idx
    plain = InMemoryDataset(LeRobotDataset(f"local/{name}", root=root, episodes=episodes))
    _assert_same_items(LeRobotDataset(f"local/{name}", root=root, episodes=episodes), plain)


def test_image_features_are_served_as_lerobot_serves_them_and_text_features_refused(tmp_path):
    features = {
        "observation.image": {"dtype": "image", "shape": (4, 6, 3), "names": ["h", "w", "c"]},
        "action": {"dtype": "float32", "shape": (2,), "names": None},
    }
    dataset = LeRobotDataset.create("local/img", 10, features, root=tmp_path / "img", use_videos=False)
    rng = np.random.default_rng(0)
    for i in range(3):
        picture = rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)
        dataset.add_frame({"observation.image": picture, "action": np.full(2, i, np.float32), "task": "t"})
    dataset.save_episode()
    dataset.finalize()
    deltas = {"observation.image": [-0.1, 0.0]}
    source = LeRobotDataset("local/img", root=tmp_path / "img", delta_timestamps=deltas)
    held = InMemoryDataset(source)
    for index in range(3):
        expected, served = source[index], held[index]
        assert served["observation.image"].dtype == torch.float32
        assert torch.equal(served["observation.image"], expected["observation.image"])
        assert torch.equal(served["observation.image_is_pad"], expected["observation.image_is_pad"])
    text = {"observation.note": {"dtype": "string", "shape": (1,), "names": None}}
    dataset = LeRobotDataset.create("local/txt", 10, text, root=tmp_path / "txt", use_videos=False)
    dataset.add_frame({"observation.note": "a", "task": "t"})
    dataset.save_episode()
    dataset.finalize()
    with pytest.raises(
        ValueError, match="numeric, image and video features.*observation.note.*lerobot-train"
    ):
        InMemoryDataset(LeRobotDataset("local/txt", root=tmp_path / "txt"))


def _run(exe: str, *args: str) -> subprocess.CompletedProcess:
    command = [str(Path(sys.executable).parent / exe), *args]
    return run_command(command, env=ENV, timeout=600)


def _train(exe: str, *args: str) -> str:
    result = _run(exe, *args)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result.stdout + result.stderr


def _losses(log: str) -> dict[int, str]:
    return {int(step): loss for step, loss in re.findall(r"step:(\d+) .*?loss:(\S+)", log)}


def test_train_checkpoints_matches_lerobot_train_and_resumes(demos, tmp_path, capfd):
    """Three steps of `lerobot-opfa train` (a real subprocess): a checkpoint, the steps logged, the losses of
    `lerobot-train` with the same flags and seed (the same batches), then one more step resumed (in this
    process)."""
    data = ["--dataset.repo_id=local/demos", f"--dataset.root={demos}", "--seed=3", "--steps=3",
            "--save_freq=2"]  # fmt: skip
    fast = _train("lerobot-opfa", "train", *TINY, *data, f"--output_dir={tmp_path / 'fast'}")
    assert "Dataset held in memory" in fast
    checkpoints = tmp_path / "fast" / "checkpoints"
    assert sorted(p.name for p in checkpoints.iterdir()) == ["000002", "000003", "last"]
    assert (checkpoints / "last" / "pretrained_model" / "model.safetensors").is_file()
    config = json.loads((checkpoints / "last" / "pretrained_model" / "train_config.json").read_text())
    assert config["num_workers"] == 0
    stock = _train("lerobot-train", *TINY, *data, "--num_workers=0", f"--output_dir={tmp_path / 'stock'}")
    assert set(_losses(fast)) == {1, 2, 3} and _losses(fast) == _losses(stock)

    config_path = checkpoints / "last" / "pretrained_model" / "train_config.json"
    capfd.readouterr()
    assert cli.main(["train", f"--config_path={config_path}", "--resume=true", "--steps=4"]) == 0  # here
    resumed = "".join(capfd.readouterr())
    assert "Resuming data order" in resumed and set(_losses(resumed)) == {4}
    assert (checkpoints / "000004" / "pretrained_model" / "model.safetensors").is_file()


def test_cli_passes_only_train_arguments_through(demos, capsys):
    with pytest.raises(SystemExit):
        cli.main(["dataset", "synthetic", "--hand", "umi", "--output", "x", "--policy.type=opfa"])
    assert "unrecognized arguments: --policy.type=opfa" in capsys.readouterr().err
    data = ["--dataset.repo_id=local/demos", f"--dataset.root={demos}", "--dataset.streaming=true"]
    assert cli.main(["train", *TINY, *data, "--steps=1"]) == 2
    assert "error: the in-memory fast path reads whole datasets" in capsys.readouterr().err
