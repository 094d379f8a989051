"""A user's hand as its vendor ships it: frames, signs and extra joints fixed in the spec alone, and every
command from `hands check` to `lerobot-eval` working from the dataset's record of the spec. The hands are
third-party models with meshes from PyPI packages: gymnasium-robotics' Shadow (MJCF) and
example-robot-data's Allegro (URDF)."""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np
import pytest
import torch
import yaml
from subprocesses import run_command, run_lerobot_here

from lerobot_opfa.cli import main
from lerobot_opfa.datasets.layout import read_layout
from lerobot_opfa.galr.model import Galr, GalrConfig, hand_record
from lerobot_opfa.hands import HandModel, HandSpecError, load_hand
from lerobot_opfa.hands.mujoco_model import hand_mjspec
from lerobot_opfa.hands.registry import hand_models_dir
from lerobot_opfa.hands.universal import UNIVERSAL_INDEX

ENV = {**os.environ, "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
TINY_GALR = dict(latent_dim=8, encoder="pointnet", n_points=64, n_level1=32, n_superpoints=24,
                 widths=(16, 32, 32), decoder_hidden=32)  # fmt: skip
TINY_POLICY = [
    "--policy.device=cpu", "--policy.push_to_hub=false", "--policy.down_dims=[16,32]", "--policy.horizon=8",
    "--policy.n_action_steps=4", "--policy.pointcloud_widths=[16,32]", "--policy.pointcloud_feature_dim=16",
    "--policy.n_groups=4", "--steps=2", "--batch_size=4", "--save_freq=2", "--log_freq=1", "--num_workers=0",
    "--wandb.enable=false",
]  # fmt: skip


def _edit(spec: Path, change) -> Path:
    raw = yaml.safe_load(spec.read_text())
    change(raw)
    spec.write_text(yaml.safe_dump(raw))
    return spec


def _check(spec: Path, capsys) -> tuple[int, str]:
    code = main(["hands", "check", str(spec)])
    return code, capsys.readouterr().out


# --- frames, signs, extra joints --------------------------------------------------------------------
def test_base_puts_a_vendor_model_in_the_hand_frame(user_shadow_spec, capsys):
    """The Shadow ships 1.3 m from the origin, fingers along -y: `hands check` says so, and the spec's `base`
    fixes it with FK and MuJoCo still in agreement."""
    code, out = _check(user_shadow_spec, capsys)
    assert code == 0 and "WARNING" not in out, out
    hand = load_hand(user_shadow_spec)
    cloud = hand.point_cloud(hand.pose("open")[None], 256).points[0]
    assert cloud[:, 2].min() > -0.03 and cloud[:, 2].max() > 0.15  # from the wrist forwards along +z
    _edit(user_shadow_spec, lambda raw: raw.pop("base"))
    code, out = _check(user_shadow_spec, capsys)
    assert code == 0 and "FK vs MuJoCo" in out
    assert "the fingers point 89 deg away from +z" in out
    assert "the palm faces" in out and "1.24 m from the origin" in out


def test_fixed_wrist_joints_hold_in_simulation(user_shadow_spec):
    hand = load_hand(user_shadow_spec)
    model = hand_mjspec(hand).compile()
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("grasp").id)
    data.ctrl[:] = hand.pose("grasp").double().numpy()
    mujoco.mj_step(model, data, 500)
    for joint in ("robot0:WRJ0", "robot0:WRJ1"):
        assert abs(data.qpos[model.jnt_qposadr[model.joint(joint).id]]) < 1e-3
    _edit(user_shadow_spec, lambda raw: raw.pop("fixed"))
    with pytest.raises(
        HandSpecError, match=r"\['robot0:WRJ1', 'robot0:WRJ0'\] are neither .* nor held \('fixed'"
    ):
        HandModel.from_spec(user_shadow_spec)


def test_links_behind_held_joints_stay_put_and_only_they_can_be_the_base(user_shadow_spec):
    """The palm sits behind the wrist joints the spec holds: it is static, so its points are posed once."""
    hand = load_hand(user_shadow_spec)
    assert {"robot0:palm", "robot0:forearm"} <= hand.static_links
    assert "robot0:ffdistal" not in hand.static_links
    cloud = hand.point_cloud(hand.sample_joints(4, torch.Generator().manual_seed(0)), 256).points
    on_palm = hand.surface_samples(256).link_index == hand.link_names.index("robot0:palm")
    assert torch.equal(cloud[:, on_palm], cloud[:1, on_palm].expand(4, -1, -1))
    assert not torch.allclose(cloud[0, ~on_palm], cloud[1, ~on_palm])
    _edit(user_shadow_spec, lambda raw: raw["base"].update(link="robot0:ffdistal"))
    with pytest.raises(HandSpecError, match=r"'robot0:ffdistal' moves with the actuated joints"):
        HandModel.from_spec(user_shadow_spec)


def test_fixed_value_outside_the_joint_limits_is_an_error(user_shadow_spec):
    _edit(user_shadow_spec, lambda raw: raw["fixed"].update({"robot0:WRJ1": 2.0}))
    with pytest.raises(HandSpecError, match=r"field 'fixed.robot0:WRJ1': 2.0 is outside its limits"):
        HandModel.from_spec(user_shadow_spec)


def test_sign_flips_a_joint_into_the_universal_sense(user_shadow_spec):
    hand = load_hand(user_shadow_spec)
    q = hand.pose("grasp")[None]
    universal = hand.to_universal(q)
    thumb_ip = hand.joint_names.index("robot0:THJ0")
    assert q[0, thumb_ip] < 0 and universal[0, UNIVERSAL_INDEX["thumb_ip_flex"]] == -q[0, thumb_ip]
    assert torch.equal(hand.from_universal(universal), q)


def test_check_refuses_a_finger_that_flexes_away_from_the_palm(tmp_path, capsys):
    spec = tmp_path / "inspire" / "spec.yaml"
    shutil.copytree(hand_models_dir() / "inspire", spec.parent)
    code, out = _check(spec, capsys)
    assert "WARNING" not in out
    _edit(spec, lambda raw: raw.update(name="my_inspire"))  # an edited built-in is a hand of its own
    _edit(spec, lambda raw: raw["joints"].update(index_mcp_flex={"universal": "index_mcp_flex", "sign": -1}))
    code, out = _check(spec, capsys)
    assert code == 1 and "WARNING" not in out
    assert "PROBLEM: 1 flexion joint(s) curl their finger away from the palm" in out
    assert "remove `sign: -1` from joint(s) 'index_mcp_flex' in `joints`" in out


def test_links_labelled_null_are_simulated_but_not_in_the_cloud(user_shadow_spec):
    hand = load_hand(user_shadow_spec)
    assert "robot0:forearm" not in hand.link_names and "robot0:palm" in hand.link_names
    assert hand_mjspec(hand).compile().body("robot0:forearm").id > 0


# --- every command ---------------------------------------------------------------------------------
@pytest.fixture(params=["mjcf", "urdf"])
def user_spec(request, user_shadow_spec, user_allegro_spec) -> Path:
    return user_shadow_spec if request.param == "mjcf" else user_allegro_spec


def _lerobot(exe: str, *args: str) -> None:
    result = run_command([str(Path(sys.executable).parent / exe), *args], env=ENV, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]


def test_user_hand_through_every_command(user_spec, tmp_path, capsys, request, monkeypatch):
    """check, cloud, demos, a GaLR that learns the hand (`--init`), merge, lerobot-train (a subprocess) and
    lerobot-eval (its entry point, here), with nothing but the spec's path given once, to `sim demos`. The
    URDF hand trains in GaLR space, the MJCF hand on raw joints (and in GaLR space in
    test_refusals_checkpoints' moved-checkpoint test)."""
    hand = load_hand(user_spec)
    code, out = _check(user_spec, capsys)
    assert code == 0 and "WARNING" not in out, out
    assert main(["hands", "cloud", str(user_spec), "--n-points", "64", "--out", str(tmp_path / "c.npz")]) == 0
    assert np.load(tmp_path / "c.npz")["joints"].shape[-1] == hand.dof

    demos = tmp_path / "demos"
    code = main(["sim", "demos", "--task", "press_button", "--hand", str(user_spec), "--episodes", "2",
                 "--n-points", "32", "--output-dir", str(demos)])  # fmt: skip
    assert code == 0
    record = json.loads((demos / "meta" / "opfa.json").read_text())
    assert record["hands"] == {hand.name: {"spec": str(user_spec.resolve()), "sha256": hand.spec.sha256}}

    torch.manual_seed(0)
    Galr(GalrConfig(**TINY_GALR, hands=[hand_record(load_hand("umi"))])).save_pretrained(tmp_path / "galr0")
    code = main(["galr", "pretrain", "--init", str(tmp_path / "galr0"), "--hands", f"+{user_spec}",
                 "--steps", "2", "--batch-size", "8", "--validate-every", "2", "--save-every", "2",
                 "--output-dir", str(tmp_path / "galr")])  # fmt: skip
    assert code == 0
    assert Galr.from_pretrained(tmp_path / "galr").config.hand_names == ["umi", hand.name]
    merged = tmp_path / "merged"
    code = main(
        [
            "dataset",
            "merge",
            "--inputs",
            str(demos),
            "--output",
            str(merged),
            "--galr",
            str(tmp_path / "galr"),
        ]
    )
    assert code == 0

    model = request.node.callspec.params["user_spec"]
    space, dataset = {"mjcf": ("raw", demos), "urdf": ("galr", merged)}[model]
    out = tmp_path / f"train_{space}"
    _lerobot("lerobot-train", "--policy.type=opfa", f"--policy.action_space={space}",
             f"--dataset.repo_id=local/{dataset.name}", f"--dataset.root={dataset}", *TINY_POLICY,
             f"--output_dir={out}")  # fmt: skip
    run_lerobot_here("lerobot_eval", [
        f"--policy.path={out / 'checkpoints' / 'last' / 'pretrained_model'}", "--policy.device=cpu",
        "--env.type=opfa", f"--env.hand={user_spec}", "--env.task=press_button", "--env.n_points=32",
        "--env.episode_length=4", "--eval.n_episodes=1", "--eval.batch_size=1",
        f"--output_dir={tmp_path / f'eval_{space}'}",
    ], monkeypatch)  # fmt: skip
    info = json.loads((tmp_path / f"eval_{space}" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1


def test_a_dataset_whose_hand_changed_is_an_error(user_shadow_spec, tmp_path):
    demos = tmp_path / "demos"
    code = main(["sim", "demos", "--task", "press_button", "--hand", str(user_shadow_spec), "--episodes", "1",
                 "--n-points", "16", "--output-dir", str(demos)])  # fmt: skip
    assert code == 0
    info = json.loads((demos / "meta" / "info.json").read_text())
    layout = read_layout(info["features"], info["robot_type"], demos)
    assert layout.hand_refs == [str(user_shadow_spec.resolve())]
    _edit(user_shadow_spec, lambda raw: raw["fixed"].update({"robot0:WRJ1": 0.1}))
    with pytest.raises(ValueError, match="changed since the dataset was recorded; record the demos again"):
        read_layout(info["features"], info["robot_type"], demos)


def test_per_embodiment_trains_and_acts_on_a_user_hand_without_a_galr(user_shadow_spec, tmp_path):
    from lerobot.configs.types import FeatureType
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.utils.feature_utils import dataset_to_policy_features

    from lerobot_opfa.policy.configuration_opfa import OpfaConfig
    from lerobot_opfa.policy.modeling_opfa import OpfaPolicy
    from lerobot_opfa.policy.processor_opfa import make_opfa_pre_post_processors

    demos, merged = tmp_path / "demos", tmp_path / "merged"
    code = main(["sim", "demos", "--task", "press_button", "--hand", str(user_shadow_spec), "--episodes", "1",
                 "--n-points", "16", "--output-dir", str(demos)])  # fmt: skip
    assert code == 0 and main(["dataset", "merge", "--inputs", str(demos), "--output", str(merged)]) == 0
    meta = LeRobotDatasetMetadata("local/merged", root=merged)
    config = OpfaConfig(device="cpu", action_space="per_embodiment", down_dims=(16, 32), horizon=8,
                        n_action_steps=4, pointcloud_widths=(16, 32), pointcloud_feature_dim=16,
                        diffusion_step_embed_dim=16, n_groups=4)  # fmt: skip
    features = dataset_to_policy_features(meta.features)
    config.output_features = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config.input_features = {k: f for k, f in features.items() if k not in config.output_features}
    policy = OpfaPolicy(config, dataset_meta=meta)
    pre, post = make_opfa_pre_post_processors(config, dataset_meta=meta)
    assert policy.config.galr_path is None and policy.config.embodiment_joints == [
        load_hand(user_shadow_spec).universal_names
    ]
    dataset = LeRobotDataset(
        "local/merged", root=merged, delta_timestamps=resolve_delta_timestamps(config, meta)
    )
    batch = torch.utils.data.default_collate([dataset[i] for i in range(2)])
    loss, _ = policy.forward(pre(batch))
    assert torch.isfinite(loss)
    frame = LeRobotDataset("local/demos", root=demos)[0]
    observation = {
        k: frame[k] for k in ("observation.state", "observation.pointcloud", "observation.environment_state")
    }
    with torch.no_grad():
        action = post(policy.select_action(pre({**observation, "task": frame["task"]})))
    assert action.shape == (1, frame["action"].shape[0])


def test_a_user_hand_named_like_a_builtin_is_the_users(tmp_path):
    """A copy of a built-in spec elsewhere (edited, say) is a user hand: recorded, and read back as itself."""
    spec = tmp_path / "my_inspire" / "spec.yaml"
    shutil.copytree(hand_models_dir() / "inspire", spec.parent)
    demos = tmp_path / "demos"
    code = main(["sim", "demos", "--task", "press_button", "--hand", str(spec), "--episodes", "1",
                 "--n-points", "16", "--output-dir", str(demos)])  # fmt: skip
    assert code == 0
    assert json.loads((demos / "meta" / "opfa.json").read_text())["hands"]["inspire"]["spec"] == str(spec)
    info = json.loads((demos / "meta" / "info.json").read_text())
    assert read_layout(info["features"], info["robot_type"], demos).hand_refs == [str(spec)]
