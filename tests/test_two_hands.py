"""Two hands per frame, as published bimanual datasets lay them out (written with LeRobot's own writer): a
Unitree G1 with Dex3 hands (radians, the left hand's joints mirrored, each hand's fingers in another order), a
G1 with Inspire hands (0-1 units, 1 = open) with its arms first or with each arm beside its hand,
LeRobot's two-arm rig (`bi_so_follower` naming) with a gripper on each arm, and a rig with different hands
on its two sides. One joint map with a slot per hand reads each; the policy holds one hand part per slot
(a latent each for `galr`), and the checkpoint gives back the robot's entries in its order and units."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from lerobot.processor import TransitionKey
from lerobot.processor.converters import batch_to_transition
from lerobot.utils.constants import ACTION, OBS_STATE
from subprocesses import run_lerobot_here
from test_map_hint import DEX3, G1_ARM, G1_INSPIRE, SO101, hint, proposed_maps
from test_policy import batch_of, make_policy, save_galr

from lerobot_opfa import cli
from lerobot_opfa.datasets.io import read_columns
from lerobot_opfa.datasets.joint_map import JointMap, JointMapError
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset
from lerobot_opfa.features import OBS_EMBODIMENT, OBS_POINTCLOUD
from lerobot_opfa.hands import load_hand
from lerobot_opfa.policy.joint_steps import OpfaEncodeJointsStep
from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

N_POINTS = 32
INSPIRE_OF = {  # the G1 SDK's Inspire motor -> the spec's joint
    "Pinky": "little_mcp_flex", "Ring": "ring_mcp_flex", "Middle": "middle_mcp_flex",
    "Index": "index_mcp_flex", "ThumbBend": "thumb_bend", "ThumbRotation": "thumb_yaw",
}  # fmt: skip
SIDES = ("left", "right")
G1_MERGED = ("g1_inspire_arms_first", "g1_xhand", "g1_dex3")
"""G1s whose arms are the same and whose hands differ: one merge."""


def g1_inspire_slot(side: str) -> dict:
    """One G1 Inspire hand's slot: 0 (closed) .. 1 (open) per motor, joint = upper * (1 - entry)."""
    hand = load_hand("inspire")
    upper = dict(zip(hand.joint_names, hand.upper.tolist(), strict=True))
    joints = {
        f"k{side.title()}Hand{motor}": {"joint": joint, "scale": -upper[joint], "offset": upper[joint]}
        for motor, joint in INSPIRE_OF.items()
    }
    return {"side": side, "hand": "inspire", "joints": joints}


def g1_dex3_slot(side: str) -> dict:
    """One G1 Dex3 hand's slot, in radians as its SDK reports them: Unitree's left hand is the right one
    mirrored, each joint negated but the thumb's rotation, so its entries map onto the right-hand model with
    scale -1."""
    joints = {}
    for motor in DEX3:
        joint = f"{motor[:-1].lower()}_{motor[-1]}"  # Thumb0 -> thumb_0
        mirrored = side == "left" and motor != "Thumb0"
        joints[f"k{side.title()}Hand{motor}"] = {"joint": joint, "scale": -1.0} if mirrored else joint
    return {"side": side, "hand": "dex3", "joints": joints}


def named_slot(side: str, hand: str, prefix: str) -> dict:
    """A slot whose entries are `<prefix><joint>` in the spec's units."""
    return {"side": side, "hand": hand, "joints": {f"{prefix}{j}": j for j in load_hand(hand).joint_names}}


ROBOTS = {
    # name: (hands per side, state/action entries, the map's slots)
    "g1_inspire_arms_first": (
        ("inspire", "inspire"),
        [*(f"k{s}{j}" for s in ("Left", "Right") for j in G1_ARM),
         *(f"k{s}Hand{j}" for s in ("Left", "Right") for j in G1_INSPIRE)],
        [g1_inspire_slot(side) for side in SIDES],
    ),
    "g1_inspire_side_by_side": (
        ("inspire", "inspire"),
        [*(f"kLeft{j}" for j in G1_ARM), *(f"kLeftHand{j}" for j in G1_INSPIRE),
         *(f"kRight{j}" for j in G1_ARM), *(f"kRightHand{j}" for j in G1_INSPIRE)],
        [g1_inspire_slot(side) for side in SIDES],
    ),
    "g1_dex3": (  # the published order: each hand's fingers listed differently (left middle first)
        ("dex3", "dex3"),
        [*(f"k{s}{j}" for s in ("Left", "Right") for j in G1_ARM), *(f"kLeftHand{j}" for j in DEX3),
         *(f"kRightHand{j}" for j in (*DEX3[:3], *DEX3[5:], *DEX3[3:5]))],
        [g1_dex3_slot(side) for side in SIDES],
    ),
    "g1_xhand": (  # the same G1 arms, XHand hands (entries named after the spec's joints)
        ("xhand", "xhand"),
        [*(f"k{s}{j}" for s in ("Left", "Right") for j in G1_ARM),
         *(f"k{s}Hand_{j}" for s in ("Left", "Right") for j in load_hand("xhand").joint_names)],
        [named_slot(side, "xhand", f"k{side.title()}Hand_") for side in SIDES],
    ),
    "bi_so_follower": (  # SO-101 arms, each gripper 0 (closed) .. 100 (open) as the 2F-85's knuckle
        ("robotiq_2f85", "robotiq_2f85"),
        [f"{s}_{j}.pos" for s in SIDES for j in SO101],
        [{"side": s, "hand": "robotiq_2f85",
          "joints": {f"{s}_gripper.pos": {"joint": "left_knuckle", "scale": -0.008, "offset": 0.8}}}
         for s in SIDES],
    ),
    "inspire_xhand": (  # different hands on the two arms
        ("inspire", "xhand"),
        [*(f"left_arm_{i}" for i in range(6)), *(f"left_{j}" for j in load_hand("inspire").joint_names),
         *(f"right_arm_{i}" for i in range(6)), *(f"right_{j}" for j in load_hand("xhand").joint_names)],
        [named_slot("left", "inspire", "left_"), named_slot("right", "xhand", "right_")],
    ),
}  # fmt: skip


def write_robot(root: Path, sources: dict[str, Path], name: str) -> Path:
    """The robot `name` of `ROBOTS` with each side's hand moving as a synthetic dataset of that hand, its
    body entries a ramp, written with LeRobot's writer in the robot's entries and units."""
    hands, names, slots = ROBOTS[name]
    joint_map = JointMap.from_dict({"slots": slots})
    frames = {
        s: read_columns(sources[h], [OBS_STATE, ACTION, OBS_POINTCLOUD])
        for s, h in zip(SIDES, hands, strict=True)
    }
    features = {
        key: {"dtype": "float32", "shape": (len(names),), "names": names} for key in (OBS_STATE, ACTION)
    } | {OBS_POINTCLOUD: {"dtype": "float32", "shape": (3 * N_POINTS,), "names": None}}
    dataset = LeRobotDataset.create(
        f"local/{name}", 10, features=features, root=root / name, robot_type=name, use_videos=False
    )
    n = min(len(f[OBS_STATE]) for f in frames.values())
    values = {}
    for key in (OBS_STATE, ACTION):
        out = np.zeros((n, len(names)), np.float32)
        body = [i for i, entry in enumerate(names) if entry not in joint_map.key_joints(key)]
        out[:, body] = np.linspace(-0.5, 0.5, n)[:, None] + 0.01 * np.arange(len(body))
        for side, slot in zip(SIDES, joint_map.slots, strict=True):
            q = frames[side][key][:n, 6:]
            q = q[::-1] if side == "right" and hands[0] == hands[1] else q  # the two hands apart
            order = load_hand(slot.hand).joint_names
            for entry, mapped in slot.joints.items():
                joint = q[:, order.index(mapped.joint)]
                out[:, names.index(entry)] = (joint - mapped.offset) / mapped.scale
        values[key] = out
    for row in range(n):
        dataset.add_frame({
            OBS_STATE: values[OBS_STATE][row], ACTION: values[ACTION][row],
            OBS_POINTCLOUD: frames["left"][OBS_POINTCLOUD][row], "task": "lift the tray",
        })  # fmt: skip
        if row in (n // 2 - 1, n - 1):
            dataset.save_episode()
    dataset.finalize()
    (root / f"{name}.yaml").write_text(yaml.safe_dump({"slots": slots}, sort_keys=False))
    return root / name


@pytest.fixture(scope="module")
def robots(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("two_hands")
    hands = ["inspire", "robotiq_2f85", "xhand", "dex3"]
    save_galr(root / "galr", hands)
    sources = {}
    for seed, hand in enumerate(hands):
        sources[hand] = write_synthetic_dataset(
            root / f"{hand}_sim", hand, episodes=2, frames=16, n_points=N_POINTS, seed=seed
        )
    for name in ROBOTS:
        write_robot(root, sources, name)
    for name in ROBOTS:  # each alone, as a merge of one input
        alone = ["dataset", "merge", "--inputs", str(root / name), "--output", str(root / f"{name}_merged"),
                 "--galr", str(root / "galr"), "--joint-maps", str(root / f"{name}.yaml")]  # fmt: skip
        assert cli.main(alone) == 0
    names = G1_MERGED
    merge = ["dataset", "merge", "--inputs", *(str(root / n) for n in names), "--output",
             str(root / "g1_merged"), "--galr", str(root / "galr"), "--joint-maps",
             *(f"{root / n}={root / f'{n}.yaml'}" for n in names)]  # fmt: skip
    assert cli.main(merge) == 0
    return root


def bound_map(robots: Path, name: str) -> JointMap:
    meta = LeRobotDatasetMetadata(f"local/{name}", root=robots / name)
    return JointMap.load(robots / f"{name}.yaml").bind(
        meta.features[OBS_STATE]["names"], meta.features[ACTION]["names"]
    )


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_a_two_handed_map_splits_the_body_and_each_hand_and_joins_them_back(robots, name):
    joint_map = bound_map(robots, name)
    hands, names, _ = ROBOTS[name]
    action = torch.tensor(read_columns(robots / name, [ACTION])[ACTION], dtype=torch.float64)
    body, qs = joint_map.split(action, ACTION)
    assert [q.shape[-1] for q in qs] == [load_hand(h).dof for h in hands]
    for hand, q in zip(hands, qs, strict=True):
        model = load_hand(hand)
        assert ((q >= model.lower - 1e-4) & (q <= model.upper + 1e-4)).all(), "each hand in its spec's units"
    assert body.shape[-1] == len(names) - sum(q.shape[-1] for q in qs)
    assert torch.allclose(joint_map.join(body, qs), action)


def test_a_map_that_gives_one_entry_to_both_hands_or_leaves_a_side_unsaid_is_refused(robots):
    _, names, slots = ROBOTS["g1_inspire_arms_first"]
    twice = [slots[0], {**slots[1], "joints": slots[0]["joints"]}]
    with pytest.raises(JointMapError, match=r"entries \['kLeftHandIndex', .*\] are given to two hand slots"):
        JointMap.from_dict({"slots": twice}, "twice.yaml").bind(names, names)
    unsaid = [{k: v for k, v in slot.items() if k != "side"} for slot in slots]
    with pytest.raises(JointMapError, match=r"unsaid.yaml: each slot of a two-handed robot names its side"):
        JointMap.from_dict({"slots": unsaid}, "unsaid.yaml")


def test_a_slot_whose_entries_name_the_other_side_is_refused(robots):
    """A G1's Inspire slots with their sides swapped: every joint 0.5 rad off, were it read."""
    _, names, slots = ROBOTS["g1_inspire_arms_first"]
    swapped = [{**slots[0], "side": slots[1]["side"]}, {**slots[1], "side": slots[0]["side"]}]
    with pytest.raises(
        JointMapError, match=r"swapped.yaml \(right hand\): entry 'kLeftHand\w+' names the left"
    ):
        JointMap.from_dict({"slots": swapped}, "swapped.yaml").bind(names, names)


def test_hand_fields_beside_slots_are_told_to_go_into_a_slot(robots):
    _, _, slots = ROBOTS["g1_inspire_arms_first"]
    beside = {"slots": slots, "hand": "inspire", "joints": slots[0]["joints"]}
    with pytest.raises(
        JointMapError, match=r"beside.yaml: hand, joints beside `slots`: a map with slots gives"
    ):
        JointMap.from_dict(beside, "beside.yaml")
    with pytest.raises(
        JointMapError, match=r"unknown field\(s\) \['robot'\] \(valid here: action_names, drop"
    ):
        JointMap.from_dict({"slots": slots, "robot": "g1"}, "typo.yaml")


def test_a_mistyped_entry_in_a_map_given_to_a_merge_is_named_with_the_closest_entry(robots, tmp_path, capsys):
    name = "g1_inspire_arms_first"
    typo = tmp_path / "typo.yaml"
    typo.write_text((robots / f"{name}.yaml").read_text().replace("kLeftHandIndex:", "kLeftHandIndx:"))
    merge = ["dataset", "merge", "--inputs", str(robots / name), "--output", str(tmp_path / "out")]
    assert cli.main([*merge, "--joint-maps", str(typo)]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert (
        f"joint map {typo} would fit it, but for entry 'kLeftHandIndx' (did you mean 'kLeftHandIndex'?)"
        in error
    )


def _round_trip(pre, post, frames, rows) -> tuple[torch.Tensor, torch.Tensor, dict]:
    transition = batch_to_transition(batch_of(frames, rows))
    original = transition[TransitionKey.ACTION].clone()
    for step in pre.steps:
        transition = step(transition)
    encoded = dict(transition[TransitionKey.OBSERVATION])
    back = {TransitionKey.ACTION: transition[TransitionKey.ACTION], TransitionKey.OBSERVATION: {}}
    for step in post.steps:
        back = step(back)
    return original, back[TransitionKey.ACTION], encoded


@pytest.mark.parametrize("merged", [False, True], ids=["as_recorded", "merged"])
@pytest.mark.parametrize("space", ["raw", "per_embodiment", "galr"])
@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_a_two_handed_robots_actions_come_back_in_its_entries_order_and_units(robots, name, space, merged):
    """As recorded (through its map) or merged alone (the merge records the map), each layout trains in
    each space and its actions come back in the robot's entries."""
    hands, names, _ = ROBOTS[name]
    through = {} if merged else {"joint_map": str(robots / f"{name}.yaml")}
    dataset = f"{name}_merged" if merged else name
    policy, pre, post, frames = make_policy(robots, dataset, action_space=space, **through)
    encoder = next(step for step in pre.steps if isinstance(step, OpfaEncodeJointsStep))
    assert [encoder.embodiments[e] for e in encoder.robots[0]] == list(hands)
    rows = [0, 5, 9]
    _, back, encoded = _round_trip(pre, post, frames, rows)
    delta = {ACTION: frames.delta_timestamps[ACTION]}
    recorded = LeRobotDataset(f"local/{name}", root=robots / name, delta_timestamps=delta)
    original = batch_of(recorded, rows)[ACTION]  # a merge keeps its input's frames in order
    assert back.shape == original.shape and back.shape[-1] == len(names)
    joint_map = encoder.trained_map(tuple(encoder.robots[0]))
    body = joint_map.body_names(ACTION)
    columns = [names.index(b) for b in body]
    assert torch.allclose(back[..., columns], original[..., columns], atol=1e-4), "the body as recorded"
    if space != "galr":  # exact; an untrained tiny GaLR decodes its latents only roughly
        assert torch.allclose(back, original, atol=1e-3 * original.abs().max())
    ids = encoded[OBS_EMBODIMENT]
    assert ids.shape == (3, 2), "one embodiment id per hand slot"
    assert policy.config.action_width == len(body) + sum(encoder.slot_widths)


def test_both_hands_of_a_g1_go_through_the_latent_each_in_its_own_slot(robots):
    """The state after the encode step is the body, then the left hand's z, then the right hand's: each the
    GaLR latent of that hand's joints alone."""
    name = "g1_inspire_arms_first"
    _, pre, _, frames = make_policy(
        robots, name, action_space="galr", joint_map=str(robots / f"{name}.yaml"), decoded_state=False
    )
    encoder = next(step for step in pre.steps if isinstance(step, OpfaEncodeJointsStep))
    batch = batch_of(frames, [3, 12])
    transition = batch_to_transition(batch)
    for step in pre.steps:
        transition = step(transition)
        if step is encoder:
            break
    state = transition[TransitionKey.OBSERVATION][OBS_STATE][:, -1]
    body, (left, right) = encoder.trained_map((0, 0)).split(batch[OBS_STATE][:, -1], OBS_STATE)
    latent = encoder.latent_dim
    assert state.shape[-1] == body.shape[-1] + 2 * latent
    assert torch.allclose(state[:, : body.shape[-1]], body)
    for slot, q in enumerate((left, right)):
        z = state[:, body.shape[-1] + slot * latent : body.shape[-1] + (slot + 1) * latent]
        assert torch.allclose(z, encoder.encode(0, q), atol=1e-5), f"slot {slot}: its own hand's latent"
    assert not torch.allclose(encoder.encode(0, left), encoder.encode(0, right)), "the two hands differ here"


def _train_flags(robots: Path, dataset: str, space: str, out: Path) -> list[str]:
    joint_map = [] if dataset == "g1_merged" else [f"--policy.joint_map={robots / f'{dataset}.yaml'}"]
    return [
        "--policy.type=opfa", f"--policy.action_space={space}", f"--policy.galr_path={robots / 'galr'}",
        *joint_map, f"--dataset.repo_id=local/{dataset}", f"--dataset.root={robots / dataset}",
        "--policy.device=cpu", "--policy.push_to_hub=false", "--policy.down_dims=[16,32]",
        "--policy.horizon=8", "--policy.n_action_steps=4", "--policy.pointcloud_widths=[16,32]",
        "--policy.pointcloud_feature_dim=16", "--policy.n_groups=4", "--steps=2", "--batch_size=4",
        "--save_freq=2", "--log_freq=1", "--num_workers=0", f"--output_dir={out}", "--wandb.enable=false",
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("dataset", "space", "trainer"),
    [("g1_inspire_arms_first", "raw", "lerobot-train"), ("g1_inspire_arms_first", "galr", "lerobot-train"),
     ("g1_merged", "galr", "lerobot-opfa train")],
)  # fmt: skip
def test_a_trained_g1_checkpoint_alone_turns_its_frames_into_its_26_entries(
    robots, tmp_path, dataset, space, trainer, monkeypatch
):
    """`lerobot-train --policy.joint_map` on the G1 layout as published (no renaming), or `lerobot-opfa train`
    on the merge of three G1s; the checkpoint alone turns a frame of the Inspire G1 into its 26 entries, the
    hands' in 0..1."""
    out, name = tmp_path / "train", "g1_inspire_arms_first"
    flags = _train_flags(robots, dataset, space, out)
    if trainer == "lerobot-train":
        run_lerobot_here("lerobot_train", flags, monkeypatch)
    else:
        assert cli.main(["train", *flags]) == 0
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"
    policy = OpfaPolicy.from_pretrained(checkpoint)
    robots_trained = [[0, 0]] if dataset == name else [[0, 0], [1, 1], [2, 2]]
    assert policy.config.robots == robots_trained
    overrides = {} if dataset == name else {"opfa_encode_joints": {"hand": "inspire+inspire"}}
    pre, post = make_pre_post_processors(
        policy.config, pretrained_path=str(checkpoint), preprocessor_overrides=overrides
    )
    frame = LeRobotDataset(f"local/{name}", root=robots / name)[3]
    observation = {OBS_STATE: frame[OBS_STATE], OBS_POINTCLOUD: frame[OBS_POINTCLOUD]}
    with torch.no_grad():
        action = post(policy.select_action(pre(observation)))
    assert action.shape == (1, 26)
    hands = action[0, 14:]
    assert ((hands > -0.05) & (hands < 1.05)).all(), f"the hands' entries in 0..1: {hands}"


def test_g1s_with_different_hands_merge_and_co_train_and_each_gets_its_own_entries_back(robots):
    """G1s with Inspire, XHand and Dex3 hands share their arms: one merge (each slot's universal
    joints and cached z, one id per slot; the `robots` fixture), one policy, and each robot's frames come
    back in its entries."""
    names = G1_MERGED
    features = LeRobotDatasetMetadata("local/g1_merged", root=robots / "g1_merged").features
    assert features[OBS_EMBODIMENT]["shape"] == (2,)
    assert features[OBS_EMBODIMENT]["names"] == ["inspire", "xhand", "dex3"]
    assert {"left.index_mcp_flex", "right.z0"} <= set(features[OBS_STATE]["names"])
    ids = torch.tensor(read_columns(robots / "g1_merged", [OBS_EMBODIMENT])[OBS_EMBODIMENT])
    for space in ("per_embodiment", "galr"):
        policy, pre, post, frames = make_policy(robots, "g1_merged", action_space=space)
        assert policy.config.robots == [[0, 0], [1, 1], [2, 2]]
        now = policy.config.n_obs_steps - 1  # the chunk's step of the frame itself
        for robot, name in enumerate(names):
            mine = torch.nonzero((ids == robot).all(1))[:, 0]
            rows = mine[[2, 5, 12]].tolist()
            original = torch.tensor(read_columns(robots / name, [ACTION])[ACTION])
            _, back, encoded = _round_trip(pre, post, frames, rows)
            assert torch.equal(encoded[OBS_EMBODIMENT], torch.tensor([[robot, robot]] * 3))
            expected = original[[r - int(mine[0]) for r in rows]]
            assert back.shape[-1] == expected.shape[-1], f"{name}: its own entries"
            if space == "per_embodiment":
                assert torch.allclose(back[:, now], expected, atol=1e-4), f"{name}: its entries, order, units"
        loss, _ = policy.forward(pre(batch_of(frames, [2, 5, 40, 45, 70, 75])))
        assert loss.isfinite()


def test_a_latent_dataset_of_g1s_with_different_hands_holds_the_arms_then_a_latent_per_side(robots, tmp_path):
    """The stock-policy path (`policy latent-dataset`) on the merge of three two-handed G1s: body, then a
    latent per slot, named by side."""
    out = tmp_path / "latent"
    latent = ["policy", "latent-dataset", "--input", str(robots / "g1_merged"), "--output", str(out),
              "--galr", str(robots / "galr")]  # fmt: skip
    assert cli.main(latent) == 0
    names = LeRobotDatasetMetadata("local/latent", root=out).features[OBS_STATE]["names"]
    body = [f"k{s}{j}" for s in ("Left", "Right") for j in G1_ARM]
    latent_dim = len([n for n in names if n.startswith("left.z")])
    assert latent_dim > 0 and names == [*body, *(f"{s}.z{i}" for s in SIDES for i in range(latent_dim))]


def test_a_g1_with_dex3_hands_is_recorded_in_the_vendors_senses_and_the_hint_proposes_its_map(robots):
    """Unitree reports the left Dex3's fingers in -1.57..0 and the right's in 0..1.57. The closest-hand hint
    on the recorded dataset proposes a Dex3 on each side, with scale -1 for each left entry whose recorded
    range fits the right-hand model only negated, and none on the right."""
    name = "g1_dex3"
    _, names, slots = ROBOTS[name]
    action = read_columns(robots / name, [ACTION])[ACTION]
    for side, sense in (("Left", -1.0), ("Right", 1.0)):
        for finger in ("Index", "Middle"):
            entries = action[:, [names.index(f"k{side}Hand{finger}{i}") for i in (0, 1)]]
            assert (sense * entries >= -1e-6).all() and (sense * entries).max() > 0.1, (side, finger)
    meta = LeRobotDatasetMetadata(f"local/{name}", root=robots / name)
    maps = proposed_maps(hint(meta.features, meta.robot_type, robots / name))
    assert {side: proposed["hand"] for side, proposed in maps.items() if side != "map"} == {
        "left": "dex3", "right": "dex3"
    }  # fmt: skip
    assert all(isinstance(joint, str) for joint in maps["right"]["joints"].values()), "the right as recorded"
    recorded = torch.tensor(action, dtype=torch.float64)
    proposed = JointMap.from_dict(maps["map"]).bind(names, names).split(recorded, ACTION)
    written = bound_map(robots, name).split(recorded, ACTION)
    assert torch.equal(proposed[0], written[0])
    for q_proposed, q_written in zip(proposed[1], written[1], strict=True):
        assert torch.allclose(q_proposed, q_written), "the proposal reads each hand as the written map does"


def test_the_hint_on_a_g1_with_inspire_hands_proposes_motor_units_and_flags_their_sense(robots):
    """Unitree's converters record the G1's Inspire motors in 0..1 with 1 = open: the ranges say 0..1 motor
    units (or radians), never which end is open. The hint scales each entry onto its joint's range and says
    on the line the other sense, which the written map uses."""
    name = "g1_inspire_arms_first"
    meta = LeRobotDatasetMetadata(f"local/{name}", root=robots / name)
    message = hint(meta.features, meta.robot_type, robots / name)
    assert "lines marked 'check': the recorded ranges cannot decide their sense or units" in message
    model, maps = load_hand("inspire"), proposed_maps(message)
    for side in SIDES:
        for mapped in maps[side]["joints"].values():
            i = model.joint_names.index(mapped["joint"])
            lower, upper = float(model.lower[i]), float(model.upper[i])
            assert mapped["scale"] == pytest.approx(upper - lower) and mapped["offset"] == pytest.approx(
                lower
            )
    (index,) = [line for line in message.splitlines() if line.strip().startswith("kLeftHandIndex:")]
    upper = float(model.upper[model.joint_names.index("index_mcp_flex")])
    assert "# check: a 0..1 motor command" in index and f"scale: {-upper:.6g}, offset: {upper:.6g}" in index
    written = g1_inspire_slot("left")["joints"]["kLeftHandIndex"]
    assert (written["scale"], written["offset"]) == pytest.approx((-upper, upper))  # the flagged sense


def test_a_merge_with_a_galr_that_lacks_the_robots_hand_says_how_to_add_it(robots, tmp_path, capsys):
    """The packaged GaLRs hold the paper's 11 hands, not the Dex3: a G1 + Dex3 merge names the command that
    adds it, in one line."""
    galr = save_galr(tmp_path / "galr", ["inspire"])
    merge = ["dataset", "merge", "--inputs", str(robots / "g1_dex3"), "--output", str(tmp_path / "out"),
             "--galr", str(galr), "--joint-maps", str(robots / "g1_dex3.yaml")]  # fmt: skip
    assert cli.main(merge) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert error.startswith("error: hand(s) ['dex3'] are not in the GaLR registry of ")
    assert error.endswith(f"add them with `lerobot-opfa galr pretrain --init {galr} --hands +dex3`")
    assert not (tmp_path / "out").exists(), "nothing written"


def test_a_right_first_slot_map_reads_the_simulators_frames_as_its_recorded_robots():
    """Slots are matched by side: a map that lists the right hand first reads the two-armed simulator's
    frames (left arm first) as the frames of the robot it was recorded on, entry for entry."""
    from lerobot_opfa.datasets.joint_map import arm_entries
    from lerobot_opfa.hands.registry import load_spec

    arms = {"left": load_spec("inspire"), "right": load_spec("xhand")}
    names = arm_entries(arms, [f"body_{i}" for i in range(6)])  # the simulator's layout, left first
    right_first = JointMap.named_after_arms({"right": arms["right"], "left": arms["left"]}, names, names)
    assert [slot.side for slot in right_first.slots] == ["right", "left"]
    step = OpfaEncodeJointsStep(
        action_space="raw", embodiments=["inspire", "xhand"], hand_refs=["inspire", "xhand"], wrist_dim=12,
        joint_maps=[right_first.to_dict()], robots=[[1, 0]],
    )  # fmt: skip

    def within_limits(hand: str) -> torch.Tensor:
        model = load_hand(hand)
        return model.lower + torch.rand(3, model.dof) * (model.upper - model.lower)

    state = torch.cat(
        [torch.rand(3, 6), within_limits("inspire"), torch.rand(3, 6), within_limits("xhand")], 1
    )
    recorded = step(batch_to_transition({OBS_STATE: state}))[TransitionKey.OBSERVATION]
    simulated = step(batch_to_transition({OBS_STATE: state, "robot_type": "inspire+xhand"}))
    simulated = simulated[TransitionKey.OBSERVATION]
    assert recorded[OBS_EMBODIMENT].tolist() == simulated[OBS_EMBODIMENT].tolist() == [[1, 0]] * 3
    assert torch.equal(recorded[OBS_STATE], simulated[OBS_STATE])
    assert step.robot_name((1, 0)) == "inspire+xhand"  # named left first, whatever the slots' order
