"""Datasets as a LeRobot robot records them: entries under the robot's names, in its order and units, an arm
before the hand, observation-only entries; joint maps applied on the way in and inverted on the way out."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from lerobot.processor import TransitionKey, create_transition
from lerobot.processor.converters import batch_to_transition
from lerobot.utils.constants import ACTION, OBS_STATE
from subprocesses import run_lerobot_here
from test_policy import batch_of, make_policy, save_galr

from lerobot_opfa.datasets.io import read_columns
from lerobot_opfa.datasets.joint_map import JointMap, JointMapError
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset
from lerobot_opfa.features import OBS_POINTCLOUD
from lerobot_opfa.hands import load_hand
from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

N_POINTS = 32
MOTIONS = (("mcp_side", "mcp_abd"), ("mcp_fwd", "mcp_flex"), ("pip", "pip_flex"), ("dip", "dip_flex"))
GHAND_FINGERS = {  # the LEAP plugin's entries, in its order (ring, middle, index, thumb) -> the spec's joints
    **{
        f"right_hand.{f}_{motion}.pos": f"{f}_{joint}"
        for f in ("ring", "middle", "index")
        for motion, joint in MOTIONS
    },
    "right_hand.thumb_cmc_rot.pos": "thumb_cmc_yaw",
    "right_hand.thumb_cmc_side.pos": "thumb_cmc_abd",
    "right_hand.thumb_mcp_fwd.pos": "thumb_mcp_flex",
    "right_hand.thumb_ip_flex.pos": "thumb_ip_flex",
}  # fmt: skip
ARM = [f"arm.joint_{i}.pos" for i in range(1, 8)]
INSPIRE = {  # RH56-style actuators, 0 (closed) .. 1000 (open)
    "hand.thumb_rotate": "thumb_yaw",
    "hand.little": "little_mcp_flex",
    "hand.ring": "ring_mcp_flex",
    "hand.middle": "middle_mcp_flex",
    "hand.index": "index_mcp_flex",
    "hand.thumb_bend": "thumb_bend",
}


def robot_dataset(source: Path, root: Path, robot_type: str, entries: dict[str, str], units, body: list[str],
                  state_only: list[str] = ()) -> Path:  # fmt: skip
    """A copy of a synthetic dataset of a hand as a robot records it, written with LeRobot's own writer:
    `body` entries (the wrist's values, padded with a ramp to their count), then the hand's joints under
    `entries` names in that order, in the robot's units (`units[joint] = (scale, offset)`: joint = scale *
    entry + offset), the `state_only` entries only in the state, and an RGB camera."""
    hand = load_hand(LeRobotDatasetMetadata("local/x", root=source).robot_type)
    frames = read_columns(source, [OBS_STATE, ACTION, OBS_POINTCLOUD, "episode_index"])
    names = [*body, *entries]
    state_names = names + list(state_only)
    image = {"dtype": "image", "shape": (32, 32, 3), "names": ["height", "width", "channels"]}
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (len(state_names),), "names": state_names},
        ACTION: {"dtype": "float32", "shape": (len(names),), "names": names},
        OBS_POINTCLOUD: {"dtype": "float32", "shape": (3 * N_POINTS,), "names": None},
        "observation.images.front": image,
    }
    dataset = LeRobotDataset.create(
        f"local/{root.name}", 10, features=features, root=root, robot_type=robot_type, use_videos=False
    )

    def to_robot(values: np.ndarray) -> np.ndarray:
        wrist = values[:, :6]
        padded = np.concatenate(
            [wrist, np.linspace(0, 1, len(values))[:, None].repeat(max(0, len(body) - 6), 1)], 1
        )
        columns = [padded[:, : len(body)]]
        for joint in entries.values():
            scale, offset = units.get(joint, (1.0, 0.0))
            columns.append(((values[:, 6 + hand.joint_names.index(joint)] - offset) / scale)[:, None])
        return np.concatenate(columns, 1).astype(np.float32)

    state, action = to_robot(frames[OBS_STATE]), to_robot(frames[ACTION])
    state = np.concatenate([state, np.full((len(state), len(state_only)), 0.25, np.float32)], 1)
    for episode in np.unique(frames["episode_index"]):
        for row in np.flatnonzero(frames["episode_index"] == episode):
            dataset.add_frame({
                OBS_STATE: state[row], ACTION: action[row], OBS_POINTCLOUD: frames[OBS_POINTCLOUD][row],
                "observation.images.front": picture(row), "task": "reach",
            })  # fmt: skip
        dataset.save_episode()
    dataset.finalize()
    return root


def picture(row: int) -> np.ndarray:
    """A dark 32x32 frame with a bright square that moves with the frame."""
    image = np.full((32, 32, 3), 20, np.uint8)
    image[row % 24 : row % 24 + 8, 4:12] = 230
    return image


def write_map(path: Path, hand: str, entries: dict[str, str], units=None, drop=()) -> Path:
    units = units or {}
    lines = [f"hand: {hand}", "joints:"]
    for entry, joint in entries.items():
        scale, offset = units.get(joint, (1.0, 0.0))
        lines.append(f"  {entry}: {{joint: {joint}, scale: {scale!r}, offset: {offset!r}}}")
    if drop:
        lines.append(f"drop: [{', '.join(drop)}]")
    path.write_text("\n".join(lines) + "\n")
    return path


def inspire_units() -> dict[str, tuple[float, float]]:
    """0..1000 (open .. closed reversed): joint = upper + entry * (lower - upper) / 1000."""
    hand = load_hand("inspire")
    return {
        j: (float(lo - hi) / 1000, float(hi))
        for j, lo, hi in zip(hand.joint_names, hand.lower.tolist(), hand.upper.tolist(), strict=True)
    }


@pytest.fixture(scope="module")
def rigs(tmp_path_factory) -> Path:
    """A tiny GaLR, a LEAP plugin's dataset (16 `right_hand.*.pos` entries, radians, no arm) and an arm with
    an Inspire hand (7 arm joints, then 0-1000 actuators, and a current only in the state)."""
    root = tmp_path_factory.mktemp("rigs")
    save_galr(root / "galr", ["umi", "inspire", "leap"])
    write_synthetic_dataset(root / "leap_sim", "leap", episodes=2, frames=12, n_points=N_POINTS, seed=3)
    write_synthetic_dataset(root / "inspire_sim", "inspire", episodes=2, frames=12, n_points=N_POINTS, seed=4)
    robot_dataset(root / "leap_sim", root / "ghand", "ghand", GHAND_FINGERS, {}, body=[])
    units = inspire_units()
    robot_dataset(
        root / "inspire_sim", root / "arm_inspire", "arm_inspire", INSPIRE, units, ARM, ["hand.current"]
    )
    write_map(root / "ghand_map.yaml", "leap", GHAND_FINGERS)
    write_map(root / "arm_inspire_map.yaml", "inspire", INSPIRE, units, drop=["hand.current"])
    return root


def test_map_errors_are_one_line_naming_the_map_and_the_entry(rigs, tmp_path):
    meta = LeRobotDatasetMetadata("local/arm_inspire", root=rigs / "arm_inspire")
    state, action = meta.features[OBS_STATE]["names"], meta.features[ACTION]["names"]
    good = JointMap.load(rigs / "arm_inspire_map.yaml")
    assert good.bind(state, action).body_names(ACTION) == ARM
    assert good.bind(state, action).body_names(OBS_STATE) == ARM  # hand.current dropped
    without_thumb = {k: v for k, v in INSPIRE.items() if k != "hand.thumb_rotate"}
    current = ["hand.current"]
    cases = [
        (
            "entry 'hand.thumb_rotat' is not in the dataset's observation.state \\(closest: 'hand.thumb_rot",
            dict(entries={**without_thumb, "hand.thumb_rotat": "thumb_yaw"}, drop=current),
        ),
        (
            "must name each joint of hand 'inspire' once .*missing \\['thumb_yaw'\\]",
            dict(entries=without_thumb, drop=current),
        ),
        (
            "unknown \\['thumb_roll'\\]",
            dict(entries={**INSPIRE, "hand.thumb_rotate": "thumb_roll"}, drop=current),
        ),
        (
            "drop lists 'arm.joint_1.pos', which is an action entry",
            dict(entries=INSPIRE, drop=[*current, "arm.joint_1.pos"]),
        ),
    ]
    for i, (message, case) in enumerate(cases):
        path = write_map(tmp_path / f"map{i}.yaml", "inspire", case["entries"], drop=case.get("drop", ()))
        with pytest.raises(JointMapError, match=message) as error:
            JointMap.load(path).bind(state, action)
        assert "\n" not in str(error.value) and str(path) in str(error.value)
    (tmp_path / "scale.yaml").write_text(
        "hand: inspire\njoints:\n  hand.index: {joint: index_mcp_flex, scale: 0}\n"
    )
    with pytest.raises(JointMapError, match="scale must be finite and non-zero"):
        JointMap.load(tmp_path / "scale.yaml")
    (tmp_path / "bad.yaml").write_text("hand: inspire\njoints: [\n")
    with pytest.raises(JointMapError, match="bad.yaml: line 3, column 1: not valid YAML"):
        JointMap.load(tmp_path / "bad.yaml")


def test_split_and_join_are_inverse_and_apply_the_units(rigs):
    meta = LeRobotDatasetMetadata("local/arm_inspire", root=rigs / "arm_inspire")
    joint_map = JointMap.load(rigs / "arm_inspire_map.yaml").bind(
        meta.features[OBS_STATE]["names"], meta.features[ACTION]["names"]
    )
    action = torch.rand(5, len(ARM) + len(INSPIRE), dtype=torch.float64) * 1000
    body, (q,) = joint_map.split(action, ACTION)
    hand, units = load_hand("inspire"), inspire_units()
    entry = {joint: action[:, len(ARM) + i] for i, joint in enumerate(INSPIRE.values())}
    expected = torch.stack([units[j][0] * entry[j] + units[j][1] for j in hand.joint_names], dim=1)
    assert torch.equal(body, action[:, : len(ARM)]) and torch.allclose(q, expected)
    assert torch.allclose(joint_map.join(body, [q]), action)
    state = torch.cat([action, torch.full((5, 1), 7.0, dtype=torch.float64)], dim=1)  # the current, dropped
    assert torch.allclose(joint_map.split(state, OBS_STATE)[1][0], q)


def test_a_scale_that_leaves_a_joint_under_a_tenth_of_its_range_is_a_warning_naming_it(rigs, caplog):
    """Values as recorded beyond the limits (0..1000) are not the refused case (entries already in the
    spec's units), but a scale that then uses a twentieth of the range is named."""
    meta = LeRobotDatasetMetadata("local/arm_inspire", root=rigs / "arm_inspire")
    names = meta.features[ACTION]["names"]
    raw = JointMap.load(rigs / "arm_inspire_map.yaml").to_dict()
    raw["joints"]["hand.index"]["scale"] /= 20  # 0..1000 now moves index_mcp_flex over 0.07 rad of 1.47
    joint_map = JointMap.from_dict(raw, "squeezed.yaml").bind(meta.features[OBS_STATE]["names"], names)
    hand = load_hand("inspire")
    frames = torch.tensor(read_columns(rigs / "arm_inspire", [ACTION])[ACTION])
    with caplog.at_level("WARNING", logger="lerobot_opfa.datasets.joint_map"):
        joint_map.check_spans(frames, ACTION, [(hand.lower, hand.upper)])
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and "entry 'hand.index'" in warned[0] and "'index_mcp_flex'" in warned[0]
    assert "under a tenth" in warned[0]


def _through_processors(pre, post, frames) -> tuple[torch.Tensor, torch.Tensor]:
    transition = batch_to_transition(batch_of(frames, list(range(0, len(frames), 5))))
    original = transition[TransitionKey.ACTION].clone()
    for step in pre.steps:
        transition = step(transition)
    back = create_transition(action=transition[TransitionKey.ACTION])
    for step in post.steps:
        back = step(back)
    return original, back[TransitionKey.ACTION]


@pytest.mark.parametrize("space", ["raw", "per_embodiment", "galr"])
@pytest.mark.parametrize("rig", ["ghand", "arm_inspire"])
def test_a_robots_actions_come_back_in_its_entries_order_and_units(rigs, rig, space):
    _, pre, post, frames = make_policy(rigs, rig, action_space=space, joint_map=str(rigs / f"{rig}_map.yaml"))
    original, back = _through_processors(pre, post, frames)
    assert back.shape == original.shape
    if space != "galr":  # exact; an untrained tiny GaLR decodes its latents only roughly
        assert torch.allclose(back, original, atol=1e-3 * original.abs().max())
    body = len(ARM) if rig == "arm_inspire" else 0
    assert torch.allclose(back[..., :body], original[..., :body], atol=1e-4), "the arm's joints as recorded"


def test_the_simulator_and_a_robot_with_permuted_scaled_entries_go_through_the_same_joint_map_code(rigs):
    """One policy, two robots of one hand: the arm's (its own order, 0-1000 units) and the simulator's
    (body entries, then the joints in spec order). Both are split on the way in and joined on the way out
    by a JointMap, each by its own, and each gets its own entries back."""
    from unittest import mock

    from lerobot_opfa.features import ROBOT_TYPE
    from lerobot_opfa.policy.joint_steps import OpfaEncodeJointsStep

    _, pre, post, frames = make_policy(
        rigs, "arm_inspire", action_space="raw", joint_map=str(rigs / "arm_inspire_map.yaml")
    )
    hand, units = load_hand("inspire"), inspire_units()
    arm_state = frames[3][OBS_STATE][-1]
    entries = dict(zip(frames.meta.features[OBS_STATE]["names"], arm_state.tolist(), strict=True))
    joints = [units[j][0] * entries[e] + units[j][1] for e, j in INSPIRE.items()]
    spec_order = [joints[list(INSPIRE.values()).index(j)] for j in hand.joint_names]
    sim_state = torch.tensor([entries[a] for a in ARM] + spec_order)
    used = []
    split, join = JointMap.split, JointMap.join

    def spy_split(self, x, key):
        used.append(("split", key, self))
        return split(self, x, key)

    def spy_join(self, body, q, arms=None):
        used.append(("join", ACTION, self))
        return join(self, body, q, arms)

    encoder = next(step for step in pre.steps if isinstance(step, OpfaEncodeJointsStep))

    with mock.patch.object(JointMap, "split", spy_split), mock.patch.object(JointMap, "join", spy_join):
        widths = {}
        for name, observation in (
            ("arm", {OBS_STATE: arm_state}),
            ("simulator", {OBS_STATE: sim_state, ROBOT_TYPE: "inspire"}),
        ):
            used.clear()
            batch = pre({**observation, OBS_POINTCLOUD: frames[3][OBS_POINTCLOUD][-1]})
            action = post(batch[OBS_STATE][:, None])  # the state as a one-step action: same entries
            widths[name] = action.shape[-1]
            assert [(op, key) for op, key, _ in used] == [("split", OBS_STATE), ("join", ACTION)], name
            expected = encoder.hands_map((0,)) if name == "simulator" else encoder.trained_map((0,))
            assert all(joint_map == expected for _, _, joint_map in used), name  # the decode step: a copy
    assert widths == {"arm": len(ARM) + len(INSPIRE), "simulator": len(ARM) + hand.dof}


def test_recorded_units_beyond_the_hands_limits_are_refused_before_training(rigs, tmp_path):
    wrong = write_map(
        tmp_path / "radians.yaml", "inspire", INSPIRE, drop=["hand.current"]
    )  # 0..1000 read as rad
    with pytest.raises(ValueError, match=r"through .*radians.yaml.*outside its limits .* frames \(worst"):
        make_policy(rigs, "arm_inspire", action_space="raw", joint_map=str(wrong))


def test_lerobot_train_on_a_robots_dataset_through_a_map_then_the_checkpoint_drives_that_robot(
    rigs, tmp_path, monkeypatch
):
    """`lerobot-train --policy.joint_map` (its entry point, here) on the arm + Inspire dataset as recorded (no
    renaming, no merge); the checkpoint alone (no map file) turns the robot's observations into actions in
    its entries."""
    out = tmp_path / "train"
    flags = [
        "--policy.type=opfa", "--policy.action_space=raw",
        f"--policy.joint_map={rigs / 'arm_inspire_map.yaml'}", "--dataset.repo_id=local/arm_inspire",
        f"--dataset.root={rigs / 'arm_inspire'}", "--policy.device=cpu", "--policy.push_to_hub=false",
        "--policy.down_dims=[16,32]", "--policy.horizon=8", "--policy.n_action_steps=4",
        "--policy.pointcloud_widths=[16,32]", "--policy.pointcloud_feature_dim=16", "--policy.n_groups=4",
        "--steps=2", "--batch_size=4", "--save_freq=2", "--log_freq=1", "--num_workers=0",
        f"--output_dir={out}", "--wandb.enable=false",
    ]  # fmt: skip
    run_lerobot_here("lerobot_train", flags, monkeypatch)
    (rigs / "arm_inspire_map.yaml").rename(tmp_path / "moved.yaml")  # deployment needs no map file
    try:
        checkpoint = out / "checkpoints" / "last" / "pretrained_model"
        policy = OpfaPolicy.from_pretrained(checkpoint)
        pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
        frames = LeRobotDataset("local/arm_inspire", root=rigs / "arm_inspire")
        frame = frames[3]
        observation = {OBS_STATE: frame[OBS_STATE], OBS_POINTCLOUD: frame[OBS_POINTCLOUD]}
        with torch.no_grad():
            action = post(policy.select_action(pre(observation)))
        assert action.shape == (1, len(ARM) + len(INSPIRE))
        assert ((action[0, len(ARM) :] > -50) & (action[0, len(ARM) :] < 1050)).all(), "0-1000 units out"
        with pytest.raises(
            ValueError,
            match="observation.state has 12 entries; the 'inspire' robot this policy was trained on has 14",
        ):
            pre({OBS_STATE: frame[OBS_STATE][:12], OBS_POINTCLOUD: frame[OBS_POINTCLOUD]})
    finally:
        (tmp_path / "moved.yaml").rename(rigs / "arm_inspire_map.yaml")


@pytest.mark.parametrize("visual_inputs", ["rgb", "pointcloud_rgb"])
def test_the_plugins_rgb_camera_alone_or_beside_the_cloud_trains_and_acts_through_the_map(
    rigs, visual_inputs
):
    policy, pre, post, frames = make_policy(
        rigs, "ghand", action_space="galr", joint_map=str(rigs / "ghand_map.yaml"),
        visual_inputs=visual_inputs, image_feature_dim=8,
    )  # fmt: skip
    assert policy.config.image_keys == ["observation.images.front"]
    assert (policy.point_encoder is not None) == (visual_inputs == "pointcloud_rgb")
    before = policy.image_encoder.backbone[0].weight.detach().clone()
    optimizer = torch.optim.Adam(policy.parameters(), lr=1e-2)
    loss, _ = policy.forward(pre(batch_of(frames, [0, 5, 9])))
    loss.backward()
    optimizer.step()
    assert torch.isfinite(loss) and not torch.equal(before, policy.image_encoder.backbone[0].weight)
    policy.eval()
    frame = frames[3]
    observation = {
        k: v[-1] for k, v in frame.items() if k in (OBS_STATE, OBS_POINTCLOUD, "observation.images.front")
    }
    with torch.no_grad():
        action = post(policy.select_action(pre(observation)))
    assert action.shape == (1, len(GHAND_FINGERS)) and torch.isfinite(action).all()


@pytest.mark.parametrize(
    ("rig", "goal", "entries"), [("ghand", 0, len(GHAND_FINGERS)), ("arm_inspire", 7, 13)]
)
def test_image_goal_trains_the_first_pictures_features_on_the_episodes_last_wrist_pose(
    rigs, rig, goal, entries
):
    """`goal`: the policy entries the goal predicts, the wrist's (the arm's 7 here), 0 for all of them where
    there is no wrist (the LEAP plugin records the hand alone)."""
    policy, pre, post, frames = make_policy(
        rigs, rig, action_space="galr", joint_map=str(rigs / f"{rig}_map.yaml"), visual_inputs="rgb",
        image_feature_dim=8, image_goal=True,
    )  # fmt: skip
    config = policy.config
    assert policy.image_goal.out_features == (goal or config.action_width)
    episode = frames.meta.episodes[0]
    first, last = episode["dataset_from_index"], episode["dataset_to_index"] - 1
    columns = frames.hf_dataset.with_format("torch")
    raw = batch_of(frames, [first + 4, last])
    assert raw["action"].shape[1] == config.horizon + 1 and raw[OBS_STATE].shape[1] == config.n_obs_steps + 1
    assert torch.equal(raw["action"][:, -1], columns["action"][[last, last]]), "the episode's last action"
    assert torch.equal(raw[OBS_STATE][:, 0], columns[OBS_STATE][[first, first]]), "its first frame"
    assert torch.equal(raw[OBS_STATE][0, -1], columns[OBS_STATE][first + 4]), "then the history"
    loss, info = policy.forward(pre(raw))
    loss.backward()
    assert loss.item() == pytest.approx(info["denoising_loss"] + info["image_goal_loss"], rel=1e-5)
    assert policy.image_goal.weight.grad.abs().sum() > 0
    assert policy.image_encoder.backbone[0].weight.grad.abs().sum() > 0
    policy.eval()
    observation = {k: v[-1] for k, v in frames[first].items() if k in (OBS_STATE, "observation.images.front")}
    with torch.no_grad():
        assert post(policy.select_action(pre(observation))).shape == (1, entries)
