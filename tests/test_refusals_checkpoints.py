"""Checkpoints and command lines refuse a user's mistake in one line before any work: a checkpoint killed
while saving, a mistyped hand in `lerobot-eval` and `lerobot-rollout`, a damaged or older checkpoint, a
folder that cannot be written; and a checkpoint trained on a user's hand carries that hand with it."""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import pytest
from subprocesses import run_command, run_lerobot_here

from lerobot_opfa import cli
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset
from lerobot_opfa.experiments.scales import get_scale

ENV = {
    **os.environ,
    "HF_HUB_OFFLINE": "1",
    "HF_DATASETS_OFFLINE": "1",
    "MUJOCO_GL": "egl",
    "OMP_NUM_THREADS": "1",
}
TINY = [
    "--policy.type=opfa",
    "--policy.action_space=raw",
    "--policy.device=cpu",
    "--policy.push_to_hub=false",
    *get_scale("toy").policy_args,  # the experiments' tiny policy
    "--batch_size=4",
    "--log_freq=1",
    "--wandb.enable=false",
]


def _run(exe: str, *args: str, timeout: float = 300):
    return run_command([str(Path(sys.executable).parent / exe), *args], env=ENV, timeout=timeout)


def _refused(result) -> str:
    """The one line a refused command ends with (after LeRobot's log lines, never a traceback)."""
    assert result.returncode != 0, result.stdout[-2000:]
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    return result.stderr.strip().splitlines()[-1]


def _refused_here(capsys, *argv: str) -> str:
    """The one line `lerobot-opfa` (run in this process: these refusals come before any work) fails with."""
    assert cli.main(list(argv)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    return write_synthetic_dataset(tmp_path_factory.mktemp("refusals") / "demos", "umi", n_points=32)


@pytest.fixture(scope="module")
def trained(demos, tmp_path_factory) -> Path:
    """A 2-step run of `lerobot-opfa train`: its folder, with checkpoint 000002 and `last`."""
    run = tmp_path_factory.mktemp("refusals") / "run"
    result = _run(
        "lerobot-opfa",
        "train",
        *TINY,
        "--dataset.repo_id=local/demos",
        f"--dataset.root={demos}",
        "--steps=2",
        "--save_freq=2",
        f"--output_dir={run}",
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return run


@pytest.fixture
def read_only(tmp_path) -> Path:
    """A folder this process cannot write in: /sys for root (whom permissions do not stop)."""
    if os.geteuid() == 0:
        return Path("/sys")
    folder = tmp_path / "read_only"
    folder.mkdir(mode=0o555)
    return folder


# --- a checkpoint killed while saving --------------------------------------------------------------------
def _killed_run(trained: Path, target: Path, keep_complete: bool) -> Path:
    """A run killed while saving checkpoint 000004: the folder without one of its files, `last` not
    pointing at it (at 000002 if `keep_complete`, else nowhere: it was the run's first checkpoint)."""
    checkpoints = target / "checkpoints"
    checkpoints.mkdir(parents=True)
    shutil.copytree(trained / "checkpoints" / "000002", checkpoints / "000004")
    (checkpoints / "000004" / "training_state" / "optimizer_state.safetensors").unlink()
    if keep_complete:
        shutil.copytree(trained / "checkpoints" / "000002", checkpoints / "000002")
        (checkpoints / "last").symlink_to("000002")
    for config in checkpoints.glob("*/pretrained_model/train_config.json"):
        config.write_text(json.dumps(json.loads(config.read_text()) | {"output_dir": str(target)}))
    return checkpoints


def test_a_first_checkpoint_killed_while_saving_is_named_by_a_fresh_run_and_a_resume(
    demos, trained, tmp_path, capsys
):
    checkpoints = _killed_run(trained, tmp_path / "run", keep_complete=False)
    data = ["--dataset.repo_id=local/demos", f"--dataset.root={demos}"]
    fresh = _refused_here(capsys, "train", *TINY, *data, "--steps=6", f"--output_dir={tmp_path / 'run'}")
    assert "checkpoint 000004 is incomplete (the run was killed while saving it)" in fresh, fresh
    assert f"no checkpoint is complete: delete {tmp_path / 'run'} and train again" in fresh, fresh
    for name in ("last", "000004"):
        config = checkpoints / name / "pretrained_model" / "train_config.json"
        resumed = _refused_here(capsys, "train", "--resume=true", f"--config_path={config}")
        assert resumed.startswith(f"error: --config_path {config}: checkpoint 000004 is incomplete"), resumed
        assert "delete" in resumed and "train again" in resumed, resumed


def test_a_later_checkpoint_killed_while_saving_says_what_to_delete_and_resume_from(
    trained, tmp_path, capsys
):
    checkpoints = _killed_run(trained, tmp_path / "run", keep_complete=True)
    config = checkpoints / "000004" / "pretrained_model" / "train_config.json"
    resumed = _refused_here(capsys, "train", "--resume=true", f"--config_path={config}")
    good = checkpoints / "000002" / "pretrained_model" / "train_config.json"
    assert f"delete {checkpoints / '000004'} and resume from checkpoint 000002" in resumed, resumed
    assert resumed.endswith(f"--resume=true --config_path={good}"), resumed


# --- a mistyped hand in LeRobot's own commands -----------------------------------------------------------
def _lerobot_refused(script: str, argv: list[str], capsys, monkeypatch) -> list[str]:
    """The lines LeRobot's entry point `script` (run in this process: its flags are refused while they are
    parsed, before any work) ends with."""
    with pytest.raises(SystemExit) as exit_info:
        run_lerobot_here(script, argv, monkeypatch)
    err = capsys.readouterr().err
    assert exit_info.value.code not in (0, None) and "Traceback" not in err, err
    return err.strip().splitlines()


def test_a_mistyped_hand_in_lerobot_eval_is_one_line_naming_the_flag_and_the_closest_hand(
    trained, capsys, monkeypatch
):
    policy = trained / "checkpoints" / "last" / "pretrained_model"
    argv = [f"--policy.path={policy}", "--env.type=opfa", "--env.hand=inspyre"]
    line = _lerobot_refused("lerobot_eval", argv, capsys, monkeypatch)[-1]
    assert line.startswith("error: `env.hand`: unknown hand 'inspyre' (did you mean 'inspire'?)"), line


def test_ee_delta_control_for_a_joints_checkpoint_in_lerobot_eval_names_the_flag(
    trained, capsys, monkeypatch
):
    policy = trained / "checkpoints" / "last" / "pretrained_model"
    argv = [f"--policy.path={policy}", "--env.type=opfa", "--env.hand=umi", "--env.control=ee_delta"]
    line = _lerobot_refused("lerobot_eval", argv, capsys, monkeypatch)[-1]
    assert line.startswith("error: `env.control`: ee_delta, but the policy at") and "at joints" in line, line


def test_a_mistyped_hand_in_lerobot_rollout_is_refused_cause_first(trained, tmp_path, capsys, monkeypatch):
    policy = trained / "checkpoints" / "last" / "pretrained_model"
    argv = ["--robot.type=opfa_sim", "--robot.hand=inspyre", f"--robot.calibration_dir={tmp_path}",
            f"--policy.path={policy}", "--duration=1"]  # fmt: skip
    line = _lerobot_refused("lerobot_rollout", argv, capsys, monkeypatch)[-1]
    assert line.lstrip().startswith("RobotConfig: `hand`: unknown hand 'inspyre' (did you mean 'inspire'?)")
    assert len(line) < 250, line


# --- damaged and older checkpoints -----------------------------------------------------------------------
def test_a_truncated_model_file_through_lerobot_rollout_names_the_file(trained, tmp_path):
    policy = tmp_path / "policy"
    shutil.copytree(trained / "checkpoints" / "last" / "pretrained_model", policy)
    weights = policy / "model.safetensors"
    with weights.open("r+b") as file:
        file.truncate(weights.stat().st_size // 2)
    result = _run(
        "lerobot-rollout",
        "--robot.type=opfa_sim",
        "--robot.hand=umi",
        "--robot.task=press_button",
        f"--robot.calibration_dir={tmp_path}",
        f"--policy.path={policy}",
        "--duration=1",
    )
    assert result.returncode != 0
    line = result.stderr.strip().splitlines()[-1]
    assert f"{weights} is damaged (cut short or not a safetensors file" in line, line
    assert "download the checkpoint again" in line
    assert line.startswith("error: ") and "Traceback" not in result.stderr, result.stderr[-3000:]


def test_an_rgb_checkpoint_from_before_image_goal_names_the_config_line_to_add(trained, tmp_path):
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.configs.types import FeatureType, PolicyFeature
    from safetensors.torch import load_file, save_file

    from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

    config = PreTrainedConfig.from_pretrained(trained / "checkpoints" / "last" / "pretrained_model")
    config.visual_inputs, config.image_feature_dim = "rgb", 8
    config.input_features["observation.images.front"] = PolicyFeature(FeatureType.VISUAL, (3, 48, 64))
    OpfaPolicy(config).save_pretrained(tmp_path)
    saved = json.loads((tmp_path / "config.json").read_text())
    del saved["image_goal"]  # written before the field existed, without the layer
    (tmp_path / "config.json").write_text(json.dumps(saved))
    weights = load_file(tmp_path / "model.safetensors")
    save_file(
        {k: v for k, v in weights.items() if not k.startswith("image_goal.")}, tmp_path / "model.safetensors"
    )
    with pytest.raises(ValueError) as refused:
        OpfaPolicy.from_pretrained(tmp_path)
    assert f'add the line "image_goal": false to {tmp_path / "config.json"}' in str(refused.value)
    (tmp_path / "config.json").write_text(json.dumps(saved | {"image_goal": False}))
    assert OpfaPolicy.from_pretrained(tmp_path).image_goal is None


# --- folders that cannot be written ----------------------------------------------------------------------
def test_sim_demos_into_a_read_only_folder_is_one_line_before_any_episode(read_only, capsys):
    argv = ["sim", "demos", "--task", "press_button", "--hand", "umi", "--episodes", "1", "--n-points", "16"]
    assert _refused_here(capsys, *argv, "--output-dir", str(read_only / "demos")) == (
        f"error: --output-dir {read_only / 'demos'}: cannot write in {read_only} (Permission denied); "
        "choose a folder you can write to"
    )


def test_train_into_a_read_only_folder_is_one_line_before_any_step(demos, read_only, capsys):
    data = ["--dataset.repo_id=local/demos", f"--dataset.root={demos}"]
    line = _refused_here(capsys, "train", *TINY, *data, "--steps=2", f"--output_dir={read_only / 'run'}")
    assert line == (
        f"error: --output_dir {read_only / 'run'}: cannot write in {read_only} (Permission denied); "
        "choose a folder you can write to"
    )  # the only line: nothing was read or trained


# --- a checkpoint trained on a user's hand carries it ----------------------------------------------------
def test_a_policy_trained_on_a_user_hand_acts_after_the_checkpoint_moved_and_the_spec_is_gone(
    user_shadow_spec, tmp_path, monkeypatch
):
    """The hand's spec, MJCF files and meshes travel in the processors' state files; loaded, they are
    unpacked into the Hugging Face cache, and the GaLR's registry and the joint maps point there."""
    import torch
    from huggingface_hub import constants
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_opfa.galr.model import Galr, GalrConfig, hand_record
    from lerobot_opfa.hands import load_hand
    from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

    spec = user_shadow_spec
    name = load_hand(spec).name
    demos, merged = tmp_path / "demos", tmp_path / "merged"
    assert cli.main(["sim", "demos", "--task", "press_button", "--hand", str(spec), "--episodes", "2",
                     "--n-points", "16", "--output-dir", str(demos)]) == 0  # fmt: skip
    tiny = dict(latent_dim=4, encoder="pointnet", n_points=64, n_level1=32, n_superpoints=24,
                widths=(8, 16, 16), decoder_hidden=16)  # fmt: skip
    torch.manual_seed(0)
    Galr(GalrConfig(**tiny, hands=[hand_record(load_hand(spec))])).save_pretrained(tmp_path / "galr")
    assert cli.main(["dataset", "merge", "--inputs", str(demos), "--output", str(merged),
                     "--galr", str(tmp_path / "galr")]) == 0  # fmt: skip
    run = tmp_path / "run"
    flags = [f.replace("action_space=raw", "action_space=galr") for f in TINY]
    data = ["--dataset.repo_id=local/merged", f"--dataset.root={merged}"]
    result = _run("lerobot-opfa", "train", *flags, *data, "--steps=2", "--save_freq=2", f"--output_dir={run}")
    assert result.returncode == 0, result.stderr[-3000:]

    moved = tmp_path / "elsewhere"
    shutil.move(run / "checkpoints" / "000002" / "pretrained_model", moved)
    for folder in (run, spec.parent, tmp_path / "assets", tmp_path / "galr"):
        shutil.rmtree(folder)
    monkeypatch.setattr(constants, "HF_HOME", str(tmp_path / "hf_home"))
    policy = OpfaPolicy.from_pretrained(moved).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(moved))
    frame = LeRobotDataset("local/demos", root=demos)[0]
    observation = {k: frame[k] for k in ("observation.state", "observation.pointcloud")} | {
        "task": frame["task"]
    }
    with torch.no_grad():
        action = post(policy.select_action(pre(observation)))
    assert action.shape == (1, frame["action"].shape[0]) and torch.isfinite(action).all()
    unpacked = list((tmp_path / "hf_home" / "lerobot_opfa" / "hands").glob("*/spec.yaml"))
    assert len(unpacked) == 1 and list(unpacked[0].parent.glob("model/stls/hand/*.stl"))
    # lerobot-eval finds the hand by its name in the checkpoint it evaluates
    run_lerobot_here("lerobot_eval", [
        f"--policy.path={moved}", "--env.type=opfa", "--env.task=press_button", f"--env.hand={name}",
        "--env.n_points=16", "--env.episode_length=2", "--eval.n_episodes=1", "--eval.batch_size=1",
        f"--output_dir={tmp_path / 'eval'}",
    ], monkeypatch)  # fmt: skip
    assert json.loads((tmp_path / "eval" / "eval_info.json").read_text())["overall"]["n_episodes"] == 1


def test_packaged_galr_checkpoints_find_their_builtin_hands_by_name_not_by_the_recorded_paths():
    """The packaged checkpoints record the spec paths of the machine that trained them; built-in hands are
    found by name, so those paths never need to exist."""
    import torch

    from lerobot_opfa.galr import checkpoints
    from lerobot_opfa.galr.frozen import encode_joints, galr_hand_refs, known_hand_refs
    from lerobot_opfa.hands import load_hand

    for name in checkpoints.PACKAGED:
        galr = checkpoints.load(name)
        for record in galr.config.hands:
            record["spec"] = f"/nowhere/{record['name']}/spec.yaml"
        assert galr_hand_refs(galr) == galr.config.hand_names
        assert not any(ref.startswith("/nowhere") for ref in known_hand_refs(galr))
        z = encode_joints(galr, "inspire", load_hand("inspire").pose("open")[None])
        assert z.shape == (1, galr.config.latent_dim) and torch.isfinite(z).all()


def test_a_missing_spec_path_is_named_as_missing_and_a_mistyped_name_gets_the_closest():
    from lerobot_opfa.hands.registry import resolve_spec_path

    with pytest.raises(ValueError, match=r"^hand spec /nowhere/spec.yaml not found \(the built-in hands: "):
        resolve_spec_path("/nowhere/spec.yaml")
    with pytest.raises(
        ValueError, match=r"^unknown hand 'inspyre' \(did you mean 'inspire'\?\): not a built-in"
    ):
        resolve_spec_path("inspyre")


@pytest.mark.parametrize(
    "removed", ["model.safetensors", "policy_postprocessor_step_1_opfa_unnormalize.safetensors"]
)
def test_a_checkpoint_copied_in_part_names_the_missing_file_through_lerobot_eval(trained, tmp_path, removed):
    policy = tmp_path / "policy"
    shutil.copytree(trained / "checkpoints" / "last" / "pretrained_model", policy)
    (policy / removed).unlink()
    result = _run(
        "lerobot-eval", f"--policy.path={policy}", "--env.type=opfa", "--env.task=press_button",
        "--env.hand=umi", "--env.n_points=32", "--eval.n_episodes=1", "--eval.batch_size=1",
        f"--output_dir={tmp_path / 'eval'}",
    )  # fmt: skip
    line = _refused(result)
    assert line.startswith("error: ") and f"{policy} is an incomplete checkpoint: {removed} missing" in line
