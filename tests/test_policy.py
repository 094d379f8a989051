"""The `opfa` policy on tiny configs: merged datasets, processors, the three action spaces, save/load,
Hub round trip, clear errors, and `lerobot-train` / `lerobot-eval` as the user runs them."""

from __future__ import annotations

import copy
import json
import logging
import os
import shutil
import sys
from pathlib import Path
from unittest.mock import patch

import pytest
import torch
from lerobot.configs import NormalizationMode
from lerobot.configs.types import FeatureType
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from lerobot.processor import TransitionKey, create_transition
from lerobot.processor.converters import batch_to_transition, transition_to_batch
from lerobot.utils.constants import OBS_ENV_STATE, OBS_STATE
from lerobot.utils.feature_utils import dataset_to_policy_features
from safetensors.torch import load_file, save_file
from subprocesses import run_command, run_lerobot_here

from lerobot_opfa import cli
from lerobot_opfa.datasets import merge as merge_module
from lerobot_opfa.datasets.layout import JointNameError, read_layout
from lerobot_opfa.datasets.merge import merge_datasets
from lerobot_opfa.datasets.statistics import STATS_FILE
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset
from lerobot_opfa.features import OBS_EMBODIMENT, OBS_POINTCLOUD, ROBOT_TYPE
from lerobot_opfa.flags import FlagError
from lerobot_opfa.galr.model import Galr, GalrConfig, hand_record
from lerobot_opfa.hands import load_hand
from lerobot_opfa.hands.universal import UNIVERSAL_JOINT_NAMES
from lerobot_opfa.policy import processor_opfa as processor_module
from lerobot_opfa.policy.action_spaces import ACTION_SPACES
from lerobot_opfa.policy.configuration_opfa import OpfaConfig
from lerobot_opfa.policy.joint_steps import OpfaEncodeJointsStep
from lerobot_opfa.policy.modeling_opfa import OpfaPolicy
from lerobot_opfa.policy.normalization import OpfaNormalizeStep, OpfaUnnormalizeStep
from lerobot_opfa.policy.processor_opfa import make_opfa_pre_post_processors
from lerobot_opfa.policy.stock import latent_dataset

HANDS = ["umi", "inspire", "leap"]  # 1, 6 and 16 DoF
GALR = dict(latent_dim=8, encoder="pointnet", n_points=64, n_level1=32, n_superpoints=24, widths=(16, 32, 32),
            decoder_hidden=32)  # fmt: skip
POLICY = dict(device="cpu", down_dims=(16, 32), horizon=8, n_action_steps=4, pointcloud_widths=(16, 32),
              pointcloud_feature_dim=16, diffusion_step_embed_dim=16, n_groups=4)  # fmt: skip
ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "OMP_NUM_THREADS": "1"}


def save_galr(path: Path, hands: list[str]) -> Path:
    torch.manual_seed(0)
    Galr(GalrConfig(**GALR, hands=[hand_record(load_hand(h)) for h in hands])).save_pretrained(path)
    return path


@pytest.fixture(scope="session")
def data(tmp_path_factory) -> Path:
    """A tiny GaLR, one synthetic dataset per hand and their merge (built once per test session)."""
    root = tmp_path_factory.mktemp("opfa")
    save_galr(root / "galr", HANDS)
    for seed, hand in enumerate(HANDS):
        write_synthetic_dataset(root / hand, hand, episodes=2, frames=12, n_points=32, seed=seed)
    inputs = [str(root / h) for h in HANDS]
    merge = ["dataset", "merge", "--inputs", *inputs, "--output", str(root / "merged"), "--galr"]
    assert cli.main([*merge, str(root / "galr")]) == 0
    return root


def make_policy(root: Path, dataset: str, **overrides) -> tuple[OpfaPolicy, object, object, LeRobotDataset]:
    meta = LeRobotDatasetMetadata(f"local/{dataset}", root=root / dataset)
    config = OpfaConfig(**{**POLICY, "galr_path": str(root / "galr"), **overrides})
    features = dataset_to_policy_features(meta.features)
    config.output_features = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config.input_features = {k: f for k, f in features.items() if k not in config.output_features}
    torch.manual_seed(0)
    policy = OpfaPolicy(config, dataset_meta=meta)
    pre, post = make_opfa_pre_post_processors(config, dataset_meta=meta)
    dataset = LeRobotDataset(
        f"local/{dataset}", root=root / dataset, delta_timestamps=resolve_delta_timestamps(config, meta)
    )
    return policy, pre, post, dataset


def batch_of(dataset: LeRobotDataset, rows: list[int]) -> dict:
    return torch.utils.data.default_collate([dataset[i] for i in rows])


def native_observation(hand: str, cloud: torch.Tensor) -> dict:
    """What the simulator's observation looks like after LeRobot's `preprocess_observation` and the env's
    processor (its robot_type)."""
    state = torch.cat([torch.tensor([0.0, 0.0, 0.3, 0.0, 0.0, 0.0]), load_hand(hand).pose("open").float()])
    env_state = torch.tensor([0.05, -0.02, 0.04])
    return {
        "observation.state": state,
        OBS_POINTCLOUD: cloud,
        OBS_ENV_STATE: env_state,
        ROBOT_TYPE: hand,
        "task": "lift the object",
    }


def rollout(policy, pre, post, hand: str, cloud: torch.Tensor, steps: int = 5, seed: int = 0) -> torch.Tensor:
    policy.reset()
    torch.manual_seed(seed)
    with torch.no_grad():
        return torch.cat(
            [post(policy.select_action(pre(native_observation(hand, cloud)))) for _ in range(steps)]
        )


# --- model parts -----------------------------------------------------------------------------------
def test_ddim_with_an_exact_denoiser_returns_the_sample():
    from lerobot_opfa.policy.diffusion import Ddim

    ddim = Ddim(100, 10, "squaredcos_cap_v2", 1e-4, 0.02, "sample", clip=1.0)
    assert ddim.timesteps == list(range(90, -1, -10))
    x0 = torch.rand(2, 8, 5) * 2 - 1
    noisy = ddim.add_noise(x0, torch.randn_like(x0), torch.tensor([99, 99]))
    assert torch.allclose(ddim.sample(lambda x, t: x0, noisy), x0, atol=1e-5)


@pytest.mark.parametrize(
    ("inference", "schedule", "prediction"),
    [(10, "squaredcos_cap_v2", "sample"), (30, "squaredcos_cap_v2", "epsilon"), (7, "linear", "sample")],
)
def test_ddim_matches_diffusers(inference, schedule, prediction):
    from diffusers import DDIMScheduler

    from lerobot_opfa.policy.diffusion import Ddim

    ours = Ddim(100, inference, schedule, 1e-4, 0.02, prediction, clip=1.0)
    theirs = DDIMScheduler(num_train_timesteps=100, beta_schedule=schedule, beta_start=1e-4, beta_end=0.02,
                           prediction_type=prediction, clip_sample=True, clip_sample_range=1.0)  # fmt: skip
    theirs.set_timesteps(inference)
    assert ours.timesteps == theirs.timesteps.tolist()
    torch.manual_seed(0)
    outputs = [1.5 * torch.randn(2, 8, 3) for _ in ours.timesteps]  # some beyond the clip range
    x_ours = x_theirs = torch.randn(2, 8, 3)
    for i, t in enumerate(ours.timesteps):
        t_prev = ours.timesteps[i + 1] if i + 1 < len(ours.timesteps) else -1
        x_ours = ours.step(outputs[i], t, x_ours, t_prev)
        x_theirs = theirs.step(outputs[i], t, x_theirs, use_clipped_model_output=True).prev_sample
    assert torch.allclose(x_ours, x_theirs, atol=1e-5)


def tiny_unet(n_heads: int = 2):
    from lerobot_opfa.policy.diffusion import ConditionalUnet1d

    torch.manual_seed(0)
    unet = ConditionalUnet1d(
        5, 7, (16, 32), kernel=5, groups=4, step_embed_dim=16, use_scale=True, n_heads=n_heads
    )
    for p in unet.parameters():
        torch.nn.init.normal_(p, std=0.2)
    return unet


@pytest.mark.parametrize("n_heads", [1, 2])
def test_fast_sampling_matches_the_plain_unet_and_sampler(n_heads):
    from lerobot_opfa.policy.diffusion import Ddim
    from lerobot_opfa.policy.fast_sampling import FastSampler, denoise, films

    unet = tiny_unet(n_heads).eval()
    ddim = Ddim(100, 10, "squaredcos_cap_v2", 1e-4, 0.02, "sample", clip=1.0)
    x, cond = torch.randn(3, 8, 5), torch.randn(3, 7)
    head = torch.tensor([[0] * 5, [1] * 5, [1, 0, 1, 0, 0]]) % n_heads  # each entry's head
    t = torch.tensor([0, 42, 99])
    with torch.no_grad():
        assert torch.allclose(denoise(unet, x, films(unet, t, cond), head), unet(x, t, cond, head), atol=1e-5)
        expected, steps = x, ddim.timesteps
        for i, step in enumerate(steps):
            a, a_prev = ddim.alpha_bar[step], ddim.alpha_bar[steps[i + 1]] if i + 1 < len(steps) else 1.0
            x0 = unet(expected, torch.full((3,), step), cond, head).clamp(-1, 1)
            eps = (expected - a.sqrt() * x0) / (1 - a).sqrt()
            expected = a_prev**0.5 * x0 + (1 - a_prev) ** 0.5 * eps
        actions = ddim.sample(FastSampler(unet, float16_weights=False).denoiser(steps, cond, head), x)
    assert torch.allclose(actions, expected, atol=1e-5)


@pytest.mark.parametrize("float16", [False, True])
def test_fast_sampling_follows_optimiser_steps_and_loads(float16):
    """The frozen traces follow the weights after an optimiser step and after a load through a parent
    module (no hook: the traces are keyed by the weights' versions); with float16 weights the actions stay
    within 2e-3."""
    from lerobot_opfa.policy.diffusion import Ddim
    from lerobot_opfa.policy.fast_sampling import FastSampler

    unet = tiny_unet()
    sampler = FastSampler(unet, float16_weights=float16)
    if float16 and not sampler.float16:
        pytest.skip("torch has no fbgemm engine here")
    ddim = Ddim(100, 10, "squaredcos_cap_v2", 1e-4, 0.02, "sample", clip=1.0)
    x, cond = torch.randn(3, 8, 5), torch.randn(3, 7)
    head = torch.tensor([0, 1, 1])[:, None].expand(-1, 5)  # each entry's head
    atol = 2e-3 if float16 else 1e-5

    def both():
        steps = ddim.timesteps
        with torch.no_grad():
            plain = ddim.sample(lambda x, i: unet(x, torch.full((3,), steps[i]), cond, head), x)
            fast = ddim.sample(sampler.denoiser(steps, cond, head), x)
        return plain, fast

    unet.eval()
    plain, fast = both()
    assert sampler.traces and torch.allclose(fast, plain, atol=atol)
    assert bool((fast - plain).abs().max() > 1e-5) == float16  # the float16 path ran, only when asked for
    assert not any(hasattr(m, "float16_packed") for m in unet.modules())  # packed copies live in the trace
    optimiser = torch.optim.SGD(unet.parameters(), lr=1.0)
    unet(x, torch.tensor([0, 42, 99]), cond, head).square().mean().backward()
    optimiser.step()
    plain_after, fast_after = both()
    assert not torch.allclose(plain_after, plain, atol=1e-3)
    assert torch.allclose(fast_after, plain_after, atol=atol)
    parent = torch.nn.ModuleDict({"unet": unet})
    parent.load_state_dict({k: v * 0.5 for k, v in parent.state_dict().items()})
    plain_loaded, fast_loaded = both()
    assert torch.allclose(fast_loaded, plain_loaded, atol=atol)


@pytest.mark.parametrize(("space", "width"), [("raw", 6 + 2), ("per_embodiment", 6 + 28), ("galr", 6 + 8)])
def test_policy_width_comes_from_the_config_alone(space, width):
    """No hand is loaded: a user hand's checkpoint (its spec known by path only) still builds."""
    joints = [["index_mcp_flex", "thumb_mcp_flex"]]
    config = OpfaConfig(**POLICY, action_space=space, embodiments=["user_hand"], embodiment_joints=joints,
                        wrist_names=list("xyzabc"), latent_dim=8)  # fmt: skip
    assert config.state_width == config.action_width == width  # 28 universal joints
    config.action_body_names = ["dx", "dy", "dz"]  # an action of end-effector deltas
    assert (config.state_width, config.action_width) == (width, width - 3)


@pytest.mark.parametrize("space", sorted(ACTION_SPACES))
def test_each_action_space_maps_joints_in_and_out_with_a_mask_of_its_width(data, space):
    """Native joints and a merged dataset's universal joints reach the same policy-space rows, which map
    back to the joints (exactly without a GaLR); the loss mask marks the entries a hand has."""
    pair = ["inspire", "leap"]
    galr = Galr.from_pretrained(data / "galr")
    hands = OpfaEncodeJointsStep(action_space=space, embodiments=pair, hand_refs=pair, galr=galr)
    action_space = ACTION_SPACES[space]
    mask = action_space.hand_mask(hands.latent_dim, hands.embodiment_joints or [[], []])
    assert mask.shape == (2, action_space.hand_width(hands.latent_dim, hands.embodiment_joints))
    for index in range(1 if space == "raw" else 2):
        (width,) = action_space.slot_widths(hands.latent_dim, hands.embodiment_joints, [index])
        model = hands.model(index)
        q = model.sample_joints(4, generator=torch.Generator().manual_seed(index))
        rows = action_space.from_joints(hands, index, q)
        ids = torch.full((4,), index)
        assert torch.equal(rows, action_space.from_universal(hands, model.to_universal(q), ids))
        assert rows.shape == (4, width)
        if space != "galr":
            assert torch.equal(action_space.to_joints(hands, index, rows), q)
            assert mask[index, :width].sum() == (width if space == "raw" else model.dof)


# --- datasets ----------------------------------------------------------------------------------------
def test_merge_layout_mask_ids_and_cached_latents(data):
    merged = LeRobotDataset("local/merged", root=data / "merged")
    features = merged.meta.features
    assert features[OBS_EMBODIMENT]["names"] == HANDS
    assert features[OBS_POINTCLOUD]["shape"] == (96,)
    layout = read_layout(features, merged.meta.robot_type, data / "merged")
    assert layout.kind == "merged" and layout.latent_dim == 8 and layout.galr_fingerprint
    galr = Galr.from_pretrained(data / "galr").eval()
    frames = merged.hf_dataset.with_format("torch")[:]
    ids = frames[OBS_EMBODIMENT].flatten()
    assert ids.tolist() == [0] * 24 + [1] * 24 + [2] * 24
    for index, hand in enumerate(HANDS):
        model = load_hand(hand)
        rows = ids == index
        state = frames["observation.state"][rows]
        absent = torch.ones(28, dtype=torch.bool)
        absent[model.universal_index] = False
        assert (state[:, 6:34][:, absent] == 0).all()  # universal joints the hand lacks
        native = LeRobotDataset(f"local/{hand}", root=data / hand).hf_dataset.with_format("torch")[:]
        assert torch.allclose(state[:, 6 + model.universal_index], native["observation.state"][:, 6:])
        with torch.no_grad():
            z = galr.encode_joints(hand, native["action"][:, 6:])
        assert torch.allclose(frames["action"][rows][:, 6 + 28 :], z, atol=1e-5)


def test_interrupted_merge_leaves_nothing(data, monkeypatch, tmp_path):
    def fail(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(merge_module, "_append", fail)
    with pytest.raises(KeyboardInterrupt):
        merge_datasets([data / h for h in HANDS], tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def test_wrong_joint_names_list_missing_and_unknown(tmp_path):
    names = list(load_hand("inspire").joint_names)
    names[0] = "thumb_yaw_typo"
    write_synthetic_dataset(tmp_path / "bad", "inspire", episodes=1, frames=4, n_points=8, joint_names=names)
    meta = LeRobotDatasetMetadata("local/bad", root=tmp_path / "bad")
    with pytest.raises(JointNameError, match=r"missing \['thumb_yaw'\].*unknown.*'thumb_yaw_typo'"):
        read_layout(meta.features, meta.robot_type)


def test_hand_missing_from_the_galr_registry(data, tmp_path):
    save_galr(tmp_path / "galr", ["umi", "inspire"])
    config = OpfaConfig(**{**POLICY, "galr_path": str(tmp_path / "galr")})
    meta = LeRobotDatasetMetadata("local/leap", root=data / "leap")
    config.input_features = dataset_to_policy_features(meta.features)
    with pytest.raises(ValueError, match=r"'leap'.* not in the GaLR registry"):
        make_opfa_pre_post_processors(config, dataset_meta=meta)


# --- processors and model ------------------------------------------------------------------------------
def _before_normalization(pre, batch: dict) -> dict:
    transition = batch_to_transition(batch)
    for step in pre.steps:
        transition = step(transition)
        if isinstance(step, OpfaEncodeJointsStep):
            break
    return transition_to_batch(transition)


def test_cached_and_online_latents_agree(data):
    _, pre_merged, _, merged = make_policy(data, "merged")
    _, pre_native, _, native = make_policy(data, "leap")
    pipelines = (pre_merged, pre_native)
    encoders = [next(s for s in p.steps if isinstance(s, OpfaEncodeJointsStep)) for p in pipelines]
    assert encoders[0].use_cached_latents and not encoders[1].use_cached_latents
    from_cache = _before_normalization(pre_merged, batch_of(merged, [50, 60]))
    online = _before_normalization(pre_native, batch_of(native, [2, 12]))
    assert from_cache[OBS_EMBODIMENT].tolist() == [[2], [2]] and online[OBS_EMBODIMENT].tolist() == [[0], [0]]
    for key in ("observation.state", "action"):
        assert torch.allclose(from_cache[key], online[key], atol=1e-5)


@pytest.mark.parametrize("dataset", ["leap", "merged"])
@pytest.mark.parametrize("decoded_state", [True, False])
def test_a_galr_policy_trains_on_the_hand_states_its_decoded_actions_leave(data, dataset, decoded_state):
    """The cause of `galr`'s 34/50 against `raw`'s 46/50 on LEAP `pull_drawer` (docs/results.md): a deployed
    hand holds the decoded action, the GaLR round trip of the demonstrated pose, so a training frame's state
    must be that pose's, or the policy meets states at deployment that it never saw in training."""
    _, pre, _, frames = make_policy(data, dataset, decoded_state=decoded_state)
    encoder = next(s for s in pre.steps if isinstance(s, OpfaEncodeJointsStep))
    batch = batch_of(frames, [2, 12, 30, 50] if dataset == "merged" else [2, 12])
    trained = _before_normalization(pre, batch)
    wrist, deployed = encoder.wrist_dim, []
    universal = wrist + len(UNIVERSAL_JOINT_NAMES)
    for state, ids in zip(batch[OBS_STATE], trained[OBS_EMBODIMENT], strict=True):
        index = int(ids[0])
        hand = encoder.embodiments[index]
        if dataset == "merged":
            body, q = state[:, :wrist], load_hand(hand).from_universal(state[:, wrist:universal])
        else:
            body, (q,) = encoder.trained_map((index,)).split(state, OBS_STATE)
        held = encoder.decode(index, encoder.encode(index, q))  # what the hand reaches, commanded decoded
        live = create_transition(  # a frame of that hand, no action
            observation={OBS_STATE: torch.cat([body, held], dim=-1)}, complementary_data={ROBOT_TYPE: hand}
        )
        deployed.append(encoder(live)[TransitionKey.OBSERVATION][OBS_STATE])
    gap = (trained[OBS_STATE] - torch.stack(deployed)).abs().max()
    assert bool(gap < 1e-4) is decoded_state, f"training and deployed states differ by {gap}"


def test_a_single_hand_galr_dataset_is_encoded_once_and_its_batches_looked_up(data, monkeypatch):
    _, pre, _, native = make_policy(data, "leap")
    encoder = next(s for s in pre.steps if isinstance(s, OpfaEncodeJointsStep))
    batch = batch_of(native, [0, 5, 13, 23])
    encoded, encode = [], encoder._encode
    monkeypatch.setattr(
        encoder, "_encode", lambda index, q: encoded.append(q[..., 0].numel()) or encode(index, q)
    )
    cached = _before_normalization(pre, batch)
    assert encoded == []  # every state and action of the window was in the cache
    encoder._latent_caches.clear()
    online = _before_normalization(pre, batch)
    assert sum(encoded) == batch["observation.state"][..., 0].numel() + batch["action"][..., 0].numel()
    for key in ("observation.state", "action"):
        assert torch.allclose(cached[key], online[key], atol=1e-5)


NORMALIZATION_CASES = [
    (space, dataset, mode, wrist)
    for space, dataset in (
        ("raw", "inspire"),
        ("per_embodiment", "merged"),
        ("galr", "merged"),
        ("galr", "leap"),
    )
    for mode in (NormalizationMode.MIN_MAX, NormalizationMode.MEAN_STD)
    for wrist in ("per_embodiment", "shared")
]  # the synthetic demos hold wrist_pitch and wrist_roll at exactly 0 (constant state and action entries)
PITCH, ROLL = 4, 5


def _steps(pre, post):
    normalize = next(s for s in pre.steps if isinstance(s, OpfaNormalizeStep))
    return normalize, next(s for s in post.steps if isinstance(s, OpfaUnnormalizeStep))


@pytest.mark.parametrize(
    ("space", "mode", "wrist"),
    [(s, m, w) for s, _, m, w in NORMALIZATION_CASES if _ == "merged"],
)
def test_normalisation_fitted_from_the_merge_statistics_equals_fitting_it_on_the_frames(
    data, tmp_path, space, mode, wrist
):
    """`dataset merge` writes per-embodiment statistics; fitted from them, without the frames, the tables
    are those fitted on the frames (a merged dataset without the file). They hold the demonstrated states,
    so a `galr` policy with `decoded_state` reads the frames (the test below)."""
    shutil.copytree(data / "galr", tmp_path / "galr")
    shutil.copytree(data / "merged", tmp_path / "merged")
    (tmp_path / "merged" / STATS_FILE).unlink()
    overrides = dict(action_space=space, normalization=mode, wrist_normalization=wrist, decoded_state=False)
    with patch.object(processor_module, "read_columns", side_effect=AssertionError("read the frames")):
        _, pre, post, _ = make_policy(data, "merged", **overrides)
    _, pre_frames, post_frames, _ = make_policy(tmp_path, "merged", **overrides)
    for ours, theirs in zip(_steps(pre, post), _steps(pre_frames, post_frames), strict=True):
        assert ours.tables.keys() == theirs.tables.keys()
        for key, table in ours.tables.items():
            assert torch.allclose(table, theirs.tables[key], rtol=1e-5, atol=1e-7), key


def test_a_galr_policy_with_decoded_states_fits_its_state_on_them(data):
    """The merge's statistics describe the demonstrated states; the policy is fitted on the decoded ones."""
    with patch.object(processor_module, "read_statistics", side_effect=AssertionError("read the merge's")):
        _, pre, _, frames = make_policy(data, "merged")
    normalize = next(s for s in pre.steps if isinstance(s, OpfaNormalizeStep))
    wrist = len(normalize.names) - GALR["latent_dim"]  # z's range is one over every hand's states
    states = _before_normalization(pre, batch_of(frames, list(range(len(frames)))))[OBS_STATE]
    z = states[..., wrist:].reshape(-1, GALR["latent_dim"])
    for high in normalize.tables["observation.state.high"]:
        assert torch.allclose(high[wrist:], z.max(0).values, atol=1e-5)


@pytest.mark.parametrize(("space", "dataset", "mode", "wrist"), NORMALIZATION_CASES)
def test_noise_on_a_constant_state_entry_is_not_amplified(data, space, dataset, mode, wrist):
    """0.57 deg of wrist tilt and of every joint (an entry the demos hold still, real-robot noise) moves the
    normalised state by about one unit, not by thousands."""
    _, pre, _, frames = make_policy(
        data, dataset, action_space=space, normalization=mode, wrist_normalization=wrist
    )
    batch = batch_of(frames, [3, 17])
    noisy = {k: v.clone() if isinstance(v, torch.Tensor) else v for k, v in batch.items()}
    state = noisy["observation.state"]
    state[..., PITCH] += 0.01
    state[..., ROLL] -= 0.01
    joints = slice(6, 6 + 28) if dataset == "merged" else slice(6, None)
    state[..., joints] += 0.01 * (state[..., joints] != 0)  # present joints only (absent ones read 0)
    if dataset == "merged":  # without the cached z, so the noisy joints are encoded
        noisy["observation.state"] = state[..., : 6 + 28]
        batch["observation.state"] = batch["observation.state"][..., : 6 + 28]
    clean, moved = pre(batch)["observation.state"], pre(noisy)["observation.state"]
    change = (moved - clean).abs()
    assert change[..., [PITCH, ROLL]].max() <= 1.0 + 1e-4
    assert change.max() < 5.0, f"largest normalised change {change.max():.2f}"


@pytest.mark.parametrize(("space", "dataset", "mode", "wrist"), NORMALIZATION_CASES)
def test_constant_action_entries_come_out_constant_and_the_rest_round_trips(
    data, space, dataset, mode, wrist
):
    _, pre, post, frames = make_policy(
        data, dataset, action_space=space, normalization=mode, wrist_normalization=wrist
    )
    normalize, unnormalize = _steps(pre, post)
    transition = batch_to_transition(batch_of(frames, list(range(0, len(frames), 7))))
    for step in pre.steps[: pre.steps.index(normalize)]:
        transition = step(transition)
    action = transition[TransitionKey.ACTION]
    normalised = normalize(transition)[TransitionKey.ACTION]
    back = unnormalize(create_transition(action=normalised))[TransitionKey.ACTION]
    assert torch.allclose(back, action, atol=1e-5), "round trip of the demos' own actions"
    wild = torch.randn_like(normalised) * 5  # a denoiser far off, even outside DDIM's clip range
    out = unnormalize(create_transition(action=wild))[TransitionKey.ACTION]
    assert (out[..., [PITCH, ROLL]] == 0).all(), "the demos' constant wrist tilt is emitted as that constant"
    ids = transition[TransitionKey.OBSERVATION][OBS_EMBODIMENT][:, 0]
    low, high = unnormalize.tables["action.low"][ids], unnormalize.tables["action.high"][ids]
    assert ((out >= low[:, None]) & (out <= high[:, None])).all(), "actions stay in their training range"


def test_a_state_of_the_wrong_width_is_an_error_of_the_preprocessor(data):
    _, pre, _, _ = make_policy(data, "merged")
    observation = native_observation("leap", torch.zeros(32 * 3))
    observation["observation.state"] = observation["observation.state"][:-1]
    with pytest.raises(
        ValueError,
        match=r"observation.state has 21 entries; the 'leap' robot .* has 22: 6 body entries, then 16 joints",
    ):
        pre(observation)


def test_state_guard_warns_once_per_episode_and_refuses_nan(data, caplog):
    policy, pre, post, _ = make_policy(data, "inspire", action_space="raw")
    observation = native_observation("inspire", torch.zeros(32 * 3))
    observation["observation.state"][PITCH] = 0.3  # 30 noise floors off a wrist axis the demos never tilt
    with caplog.at_level(logging.WARNING, logger="lerobot_opfa.policy.normalization"):
        for _ in range(3):
            pre(dict(observation))
        pre.reset()
        pre(dict(observation))
    warnings = [r.getMessage() for r in caplog.records if "training range" in r.getMessage()]
    assert len(warnings) == 2, warnings
    assert "'wrist_pitch' of hand 'inspire' is 0.3" in warnings[0] and "[0, 0]" in warnings[0]
    observation["observation.state"][8] = float("nan")
    with pytest.raises(ValueError, match=r"not finite.* in index_mcp_flex:"):
        pre(dict(observation))


def test_cloud_guard_refuses_nan_and_a_size_other_than_the_trained_one(data):
    policy, pre, post, _ = make_policy(data, "inspire", action_space="raw")
    observation = native_observation("inspire", torch.zeros(32 * 3))
    pre(dict(observation))  # the trained size passes
    cloud = torch.zeros(32 * 3)
    cloud[7 * 3 + 1] = float("nan")
    with pytest.raises(ValueError, match=r"observation.pointcloud is not finite \(NaN or inf\) at point 7"):
        pre({**observation, OBS_POINTCLOUD: cloud})
    for n_points in (100, 1024):
        with pytest.raises(ValueError, match=rf"holds {n_points} points .* trained on 32 points"):
            pre({**observation, OBS_POINTCLOUD: torch.zeros(n_points * 3)})


def test_a_robot_state_beyond_its_joint_limits_a_missing_or_unflattened_cloud_are_errors(data):
    policy, pre, post, _ = make_policy(data, "inspire", action_space="raw")
    observation = native_observation("inspire", torch.zeros(32 * 3))
    state = observation["observation.state"].clone()
    joint = 6 + load_hand("inspire").joint_names.index("index_mcp_flex")
    state[joint] = 1.47 * 1.1  # a reading past the limit by contact passes
    pre({**observation, "observation.state": state.clone()})
    state[joint] = 50.0  # limit 1.47 rad: other units
    with pytest.raises(ValueError, match=r"joint 'index_mcp_flex' of hand 'inspire' is outside .*worst 50"):
        pre({**observation, "observation.state": state})
    with pytest.raises(ValueError, match=r"has shape \(32, 3\); give it flattened: \(\.\.\., 96\)"):
        pre({**observation, OBS_POINTCLOUD: torch.zeros(32, 3)})
    with pytest.raises(ValueError, match=r"the observation has no observation.pointcloud \(it has "):
        pre({k: v for k, v in observation.items() if k != OBS_POINTCLOUD})


def test_convert_io_refuses_an_opfa_checkpoint_and_a_missing_folder(data, tmp_path, capsys):
    policy, _, _, _ = make_policy(data, "inspire", action_space="raw")
    policy.save_pretrained(tmp_path / "opfa")
    convert = ["policy", "convert-io", "--output", str(tmp_path / "out")]
    for folder, message in [
        ("opfa", "is an opfa policy"),
        ("nowhere", "not a checkpoint folder (no config.json"),
    ]:
        assert cli.main([*convert, "--policy", str(tmp_path / folder)]) == 2
        assert message in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "out").exists()


def test_a_one_hand_postprocessor_acts_before_its_preprocessor_has_run(data):
    policy, pre, post, _ = make_policy(data, "inspire", action_space="raw")
    action = post(torch.zeros(1, 6 + 6))
    assert action.shape == (1, 6 + 6) and action.isfinite().all()


@pytest.mark.parametrize(
    ("space", "dataset", "width"), [("galr", "merged", 6 + 8), ("raw", "inspire", 6 + 6),
                                    ("per_embodiment", "merged", 6 + 28)]
)  # fmt: skip
def test_each_action_space_trains_and_acts(data, space, dataset, width):
    policy, pre, post, ds = make_policy(data, dataset, action_space=space)
    optimizer = torch.optim.Adam(policy.parameters(), lr=1e-3)
    rows = list(range(0, len(ds), max(1, len(ds) // 8)))[:8]
    batch = pre(batch_of(ds, rows))
    assert batch["action"].shape == (len(rows), 8, width) and batch["action"].abs().max() <= 1 + 1e-5

    def loss_on_fixed_noise():
        torch.manual_seed(0)
        return policy.forward(batch)[0]

    first = loss_on_fixed_noise().item()
    for _ in range(15):
        loss = loss_on_fixed_noise()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert loss_on_fixed_noise().item() < 0.7 * first  # it learns
    policy.eval()
    cloud = ds[0][OBS_POINTCLOUD][-1]
    for hand in policy.config.embodiments:
        actions = rollout(policy, pre, post, hand, cloud)
        model = load_hand(hand)
        assert actions.shape == (5, 6 + model.dof)
        assert (actions[:, 6:] >= model.lower - 1e-5).all() and (actions[:, 6:] <= model.upper + 1e-5).all()


def test_save_load_identical_actions_and_processors_by_name(data, tmp_path):
    policy, pre, post, ds = make_policy(data, "merged")
    policy.eval()
    policy.save_pretrained(tmp_path)
    pre.save_pretrained(tmp_path)
    post.save_pretrained(tmp_path)
    steps = json.loads((tmp_path / "policy_preprocessor.json").read_text())["steps"]
    names = [s["registry_name"] for s in steps]
    assert names[-4:] == ["device_processor", "opfa_encode_joints", "opfa_normalize", "normalizer_processor"]
    cloud = ds[0][OBS_POINTCLOUD][-1]
    expected = {hand: rollout(policy, pre, post, hand, cloud) for hand in HANDS}
    del pre, post  # one pipeline of a checkpoint at a time (see the interleaving test)
    loaded = OpfaPolicy.from_pretrained(tmp_path)
    pre2, post2 = make_pre_post_processors(loaded.config, pretrained_path=str(tmp_path))
    for hand in HANDS:
        assert torch.equal(expected[hand], rollout(loaded, pre2, post2, hand, cloud))
    config = json.loads((tmp_path / "config.json").read_text())
    del config["embodiment_joints"]  # a checkpoint saved before the field existed
    (tmp_path / "config.json").write_text(json.dumps(config))
    assert OpfaPolicy.from_pretrained(tmp_path).config.embodiment_joints == loaded.config.embodiment_joints
    weights = load_file(tmp_path / "model.safetensors")
    dropped = sorted(weights)[0]
    save_file({k: v for k, v in weights.items() if k != dropped}, tmp_path / "model.safetensors")
    with pytest.raises(ValueError, match=f"does not fit this opfa policy .*{dropped}"):
        OpfaPolicy.from_pretrained(tmp_path)


@pytest.mark.parametrize("space", ["galr", "per_embodiment", "raw"])
def test_checkpoints_saved_by_an_earlier_version_give_the_same_actions(space):
    """Checkpoints written by `tests/data/checkpoints_v1/make.py` at an earlier commit act as they did."""
    from safetensors.torch import load_file

    folder = Path(__file__).parent / "data" / "checkpoints_v1"
    expected = load_file(folder / "actions.safetensors")
    policy = OpfaPolicy.from_pretrained(folder / space).eval()
    hands = HANDS if space != "raw" else ["inspire"]
    saved = sorted(k for k in expected if k.startswith(space + "/"))
    assert saved == sorted(f"{space}/{h}" for h in [*hands, "cloud"])
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(folder / space))
    for hand in hands:  # in the order they were made
        actions = rollout(policy, pre, post, hand, expected[f"{space}/cloud"])
        assert torch.allclose(actions, expected[f"{space}/{hand}"], atol=1e-5), hand


def test_interleaved_pipelines_of_one_checkpoint_act_each_for_its_own_hand(data, tmp_path):
    """Two hands through two pipelines loaded from one checkpoint, call by call: each postprocessor decodes
    for the hand its own preprocessor saw (LeRobot pairs them on loading), with no override."""
    policy, pre, post, ds = make_policy(data, "merged")
    policy.eval()
    for obj in (policy, pre, post):
        obj.save_pretrained(tmp_path)
    cloud = ds[0][OBS_POINTCLOUD][-1]
    hands = ("inspire", "leap")  # 6 and 16 joints
    expected = {hand: rollout(policy, pre, post, hand, cloud, steps=1) for hand in hands}
    del pre, post
    pipelines = [make_pre_post_processors(policy.config, pretrained_path=str(tmp_path)) for _ in hands]
    actions = []
    for (pre_, _), hand in zip(pipelines, hands, strict=True):
        policy.reset()
        torch.manual_seed(0)
        with torch.no_grad():
            actions.append(policy.select_action(pre_(native_observation(hand, cloud))))
    decoded = [post_(action) for (_, post_), action in zip(pipelines, actions, strict=True)]
    assert [len(d[0]) for d in decoded] == [6 + 6, 6 + 16]
    assert all(torch.equal(decoded[i], expected[hand]) for i, hand in enumerate(hands))


def test_state_hand_noise_perturbs_the_hands_state_in_training_only(data):
    """`state_hand_noise` moves the hand's part of a training batch's state by about its deviation and
    leaves the body's entries, the action, and any batch outside training as they are."""
    policy, _, _, _ = make_policy(data, "merged", state_hand_noise=0.1)
    body = len(policy.config.wrist_names)
    state = torch.zeros(64, 2, policy.config.state_width)
    batch = {OBS_STATE: state, "action": torch.zeros(64, 16, 3)}
    noisy = policy.train().with_state_noise(batch)
    assert torch.equal(noisy[OBS_STATE][..., :body], state[..., :body]) and noisy["action"] is batch["action"]
    assert abs(noisy[OBS_STATE][..., body:].std().item() - 0.1) < 0.01
    assert policy.eval().with_state_noise(batch) is batch
    with pytest.raises(FlagError, match="state_hand_noise"):
        make_policy(data, "merged", state_hand_noise=-0.1)


def test_galr_trains_by_default_on_a_hand_state_as_loose_as_a_deployed_one(data):
    """The cause of `galr`'s `pull_drawer` losses (docs/results.md): a deployed `galr` hand holds the decoded
    predicted z, off every demonstrated state, so by default a `galr` policy trains on a perturbed hand
    state; `per_embodiment` (joints, like `raw`), whose hand reads back what it was sent, trains on the
    demonstrated one."""
    body_and_hand = {}
    for space in ("galr", "per_embodiment"):
        policy, _, _, _ = make_policy(data, "merged", action_space=space)
        state = torch.zeros(64, 2, policy.config.state_width)
        noisy = policy.train().with_state_noise({OBS_STATE: state})[OBS_STATE]
        body = len(policy.config.wrist_names)
        body_and_hand[space] = noisy[..., :body].abs().max().item(), noisy[..., body:].std().item()
    assert body_and_hand["galr"][0] == 0 and abs(body_and_hand["galr"][1] - 0.05) < 0.01
    assert body_and_hand["per_embodiment"] == (0, 0)


def test_a_checkpoint_saves_the_robot_record_once_in_its_encode_step(data, tmp_path):
    """The robot's entries, hands, maps and GaLR are written by the encode step alone; the decode step saves
    nothing and decodes with its paired encode step's, so a postprocessor loaded without its preprocessor
    says in one line how to load it."""
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action

    policy, pre, post, _ = make_policy(data, "merged")
    for obj in (pre, post):
        obj.save_pretrained(tmp_path)
    saved = {
        name: {s["registry_name"]: s for s in json.loads((tmp_path / f"{name}.json").read_text())["steps"]}
        for name in ("policy_preprocessor", "policy_postprocessor")
    }
    encode, decode = (
        saved["policy_preprocessor"]["opfa_encode_joints"],
        saved["policy_postprocessor"]["opfa_decode_joints"],
    )
    assert decode["config"] == {} and "state_file" not in decode
    assert encode["config"]["embodiments"] == policy.config.embodiments and encode["config"]["joint_maps"]
    weights = load_file(tmp_path / encode["state_file"])
    assert any(k.startswith("decoder.") for k in weights) and any(k.startswith("encoder.") for k in weights)
    alone = PolicyProcessorPipeline.from_pretrained(
        tmp_path, config_filename="policy_postprocessor.json", to_transition=policy_action_to_transition,
        to_output=transition_to_policy_action,
    )  # fmt: skip
    with pytest.raises(ValueError, match="make_pre_post_processors") as error:
        alone(torch.zeros(1, policy.config.output_features["action"].shape[0]))
    assert "\n" not in str(error.value)


def test_a_policy_given_an_observation_its_preprocessor_did_not_make_says_so(data):
    policy, _, _, _ = make_policy(data, "merged")
    policy.eval()
    raw = native_observation("leap", torch.zeros(32 * 3))
    batch = {k: v.unsqueeze(0) if isinstance(v, torch.Tensor) else v for k, v in raw.items()}
    with pytest.raises(ValueError, match="was not made by this policy's preprocessor") as error:
        policy.select_action(batch)
    assert "\n" not in str(error.value)


def test_embodiment_ids_are_read_per_slot_and_two_hands_are_not_read_as_a_history():
    from lerobot_opfa.features import frame_embodiments

    histories = (torch.tensor([[2, 2], [0, 0]]), torch.tensor([[[2], [2]], [[0], [0]]]))
    for ids in (torch.tensor([2, 0]), torch.tensor([[2], [0]]), *histories):
        assert frame_embodiments(ids).tolist() == [[2], [0]]
    for two_hands in (torch.tensor([[2, 1], [0, 1]]), torch.tensor([[[1], [2]], [[0], [0]]])):
        with pytest.raises(ValueError, match=r"names several hands in one row"):
            frame_embodiments(two_hands)
    assert frame_embodiments(torch.tensor([[2, 1], [0, 1]]), slots=2).tolist() == [[2, 1], [0, 1]]


def test_a_checkpoint_of_several_robots_is_pinned_to_one_for_frames_that_do_not_say(data, tmp_path, capsys):
    """`lerobot-rollout` drops a robot's identity before the preprocessor: frames without one are refused
    by a policy of several robots, and `policy for-robot` pins a copy to one of them."""
    policy, pre, post, ds = make_policy(data, "merged")
    policy.eval()
    for obj in (policy, pre, post):
        obj.save_pretrained(tmp_path / "all")
    cloud = ds[0][OBS_POINTCLOUD][-1]
    expected = rollout(policy, pre, post, "leap", cloud, steps=1)
    silent = {k: v for k, v in native_observation("leap", cloud).items() if k != ROBOT_TYPE}
    with pytest.raises(
        ValueError, match=r"drives several robots \(umi, inspire, leap\) and the frames do not"
    ):
        pre(dict(silent))
    pin = ["policy", "for-robot", "--policy", str(tmp_path / "all"), "--output"]
    assert cli.main([*pin, str(tmp_path / "nope"), "--hand", "shadow"]) == 2
    assert "it cannot drive hand 'shadow'" in capsys.readouterr().err
    assert not (tmp_path / "nope").exists()
    pinned = run_command(  # the command as a user runs it: a fresh process, no module of ours imported yet
        [sys.executable, "-m", "lerobot_opfa.cli", *pin, str(tmp_path / "leap"), "--hand", "leap"],
        timeout=300, env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )  # fmt: skip
    assert pinned.returncode == 0, pinned.stderr[-2000:]
    loaded = OpfaPolicy.from_pretrained(tmp_path / "leap").eval()
    pre2, post2 = make_pre_post_processors(loaded.config, pretrained_path=str(tmp_path / "leap"))
    torch.manual_seed(0)
    with torch.no_grad():
        action = post2(loaded.select_action(pre2(dict(silent))))
    assert torch.equal(action, expected)


def test_a_preprocessed_observation_can_be_copied_pickled_and_saved(data, tmp_path):
    import copy
    import pickle

    _, pre, _, _ = make_policy(data, "merged")
    batch = pre(native_observation("leap", torch.zeros(32 * 3)))
    for copied in (copy.deepcopy(batch), pickle.loads(pickle.dumps(batch))):
        assert torch.equal(copied["observation.state"], batch["observation.state"])
    torch.save(batch, tmp_path / "batch.pt")
    assert torch.equal(torch.load(tmp_path / "batch.pt")["observation.state"], batch["observation.state"])


def test_hub_push_and_pull_through_lerobot(data, tmp_path, monkeypatch):
    """`push_to_hub` with the Hub replaced by a folder: only what LeRobot uploads must suffice."""
    import huggingface_hub

    hub = tmp_path / "hub"

    def create_repo(self, repo_id, **kwargs):
        return huggingface_hub.RepoUrl(f"https://huggingface.co/{repo_id}")

    def upload_folder(self, repo_id, folder_path, allow_patterns=None, **kwargs):
        for file in Path(folder_path).rglob("*"):
            if file.is_file() and (allow_patterns is None or any(file.match(p) for p in allow_patterns)):
                target = hub / repo_id / file.relative_to(folder_path)
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(file, target)
        return f"https://huggingface.co/{repo_id}"

    monkeypatch.setattr(huggingface_hub.HfApi, "create_repo", create_repo)
    monkeypatch.setattr(huggingface_hub.HfApi, "upload_folder", upload_folder)
    policy, pre, post, ds = make_policy(data, "merged")
    policy.eval()
    for obj in (policy, pre, post):
        obj.push_to_hub("user/opfa_tiny")
    shutil.rmtree(data / "galr")  # the pushed policy must not need the GaLR checkpoint any more
    try:
        loaded = OpfaPolicy.from_pretrained(hub / "user/opfa_tiny")
        pre2, post2 = make_pre_post_processors(loaded.config, pretrained_path=str(hub / "user/opfa_tiny"))
        cloud = ds[0][OBS_POINTCLOUD][-1]
        expected = rollout(policy, pre, post, "leap", cloud)
        del pre, post  # one pipeline of a checkpoint at a time
        assert torch.equal(expected, rollout(loaded, pre2, post2, "leap", cloud))
    finally:
        save_galr(data / "galr", HANDS)


def test_stock_diffusion_in_galr_space_then_joint_io(data, tmp_path):
    """LeRobot's own diffusion policy trains on a latent dataset, whose frames are what opfa's preprocessor
    makes of them (the same joint maps, GaLR and per-embodiment normalisation), then acts in joint space."""
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
    from lerobot.policies.factory import make_policy as make_stock_policy

    latent_dataset(data / "merged", tmp_path / "latent", str(data / "galr"))
    meta = LeRobotDatasetMetadata("local/latent", root=tmp_path / "latent")
    assert meta.features["action"]["shape"] == (6 + 8,)
    opfa, opfa_pre, _, merged = make_policy(data, "merged")
    rows, now = [0, 30, 60], opfa.config.n_obs_steps - 1  # the windows' current frame
    expected = opfa_pre(batch_of(merged, rows))
    latent = LeRobotDataset("local/latent", root=tmp_path / "latent")
    for key in ("observation.state", "action"):
        frames = torch.stack([latent[r][key] for r in rows])
        assert torch.allclose(frames, expected[key][:, now], atol=1e-5), key
    config = DiffusionConfig(
        device="cpu", down_dims=(16, 32), horizon=8, n_action_steps=4, n_groups=4,
        diffusion_step_embed_dim=16, noise_scheduler_type="DDIM", num_inference_steps=10,
        pretrained_backbone_weights=None,
    )  # fmt: skip
    policy = make_stock_policy(config, ds_meta=meta)
    pre, post = make_pre_post_processors(config, dataset_stats=meta.stats)
    dataset = LeRobotDataset(
        "local/latent", root=tmp_path / "latent", delta_timestamps=resolve_delta_timestamps(config, meta)
    )
    loss, _ = policy.forward(pre(batch_of(dataset, [0, 30, 60])))
    loss.backward()
    policy.eval()
    for obj in (policy, pre, post):
        obj.save_pretrained(tmp_path / "stock")
    convert = [
        "policy",
        "convert-io",
        "--policy",
        str(tmp_path / "stock"),
        "--dataset",
        str(tmp_path / "latent"),
    ]
    assert cli.main([*convert, "--output", str(tmp_path / "joint_io")]) == 0
    loaded = DiffusionPolicy.from_pretrained(tmp_path / "joint_io")
    pre2, post2 = make_pre_post_processors(loaded.config, pretrained_path=str(tmp_path / "joint_io"))
    cloud = dataset[0][OBS_POINTCLOUD][-1]
    for hand in HANDS:
        assert rollout(loaded, pre2, post2, hand, cloud, steps=2).shape == (2, 6 + load_hand(hand).dof)


# --- the stock CLIs ------------------------------------------------------------------------------------
def test_lerobot_train_then_eval_every_hand(data, tmp_path, monkeypatch):
    """`lerobot-train` as a subprocess, with no GaLR flag (the merged dataset names the GaLR its latents came
    from), then fine-tuning the checkpoint (LeRobot reconfigures its processors by name) and `lerobot-eval`
    (an episode per hand), their entry points run in this process."""
    out = tmp_path / "train"
    command = [
        str(Path(sys.executable).parent / "lerobot-train"), "--policy.type=opfa",
        "--dataset.repo_id=local/merged", f"--dataset.root={data / 'merged'}",
        "--policy.device=cpu", "--policy.push_to_hub=false",
        "--policy.down_dims=[16,32]", "--policy.horizon=8", "--policy.n_action_steps=4",
        "--policy.pointcloud_widths=[16,32]", "--policy.pointcloud_feature_dim=16", "--policy.n_groups=4",
        "--steps=3", "--batch_size=4", "--save_freq=3", "--log_freq=1", "--num_workers=0",
        f"--output_dir={out}", "--wandb.enable=false",
    ]  # fmt: skip
    result = run_command(command, env=ENV, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"
    policy = OpfaPolicy.from_pretrained(checkpoint)
    assert policy.config.embodiments == HANDS and policy.config.latent_dim == 8
    assert policy.config.galr_path == str((data / "galr").resolve())
    finetune = [f"--policy.path={checkpoint}", *command[2:5], "--policy.push_to_hub=false", "--steps=1",
                "--batch_size=4", "--num_workers=0", f"--output_dir={tmp_path / 'finetune'}"]  # fmt: skip
    run_lerobot_here("lerobot_train", finetune, monkeypatch)
    finetuned = tmp_path / "finetune" / "checkpoints" / "last" / "pretrained_model"
    assert (finetuned / "model.safetensors").is_file()
    monkeypatch.setenv("MUJOCO_GL", "egl")
    for hand in HANDS:
        argv = [
            f"--policy.path={checkpoint}", "--policy.device=cpu", "--env.type=opfa",
            f"--env.hand={hand}", "--env.task=lift", "--env.n_points=32", "--env.pointcloud_source=geometry",
            "--env.episode_length=6", "--eval.n_episodes=1", "--eval.batch_size=1",
            f"--output_dir={tmp_path / f'eval_{hand}'}",
        ]  # fmt: skip
        run_lerobot_here("lerobot_eval", argv, monkeypatch)
        info = json.loads((tmp_path / f"eval_{hand}" / "eval_info.json").read_text())
        assert info["overall"]["n_episodes"] == 1


def test_galr_of_a_policy_comes_from_its_flag_its_dataset_or_the_default(data, tmp_path):
    from lerobot_opfa.policy.record import policy_galr

    def galr_path(dataset: str, flag: str | None = None) -> str:
        path, _ = policy_galr(OpfaConfig(**{**POLICY, "galr_path": flag}), data / dataset)
        return path

    assert galr_path("merged") == str((data / "galr").resolve())  # the one its latents came from
    assert galr_path("merged", str(data / "galr")) == str(data / "galr")
    assert galr_path("inspire") == "default"  # a dataset without latents names none
    torch.manual_seed(1)
    other = tmp_path / "other_galr"
    Galr(GalrConfig(**GALR, hands=[hand_record(load_hand(h)) for h in HANDS])).save_pretrained(other)
    with pytest.raises(ValueError, match=f"--policy.galr_path={other} is not the GaLR the dataset's latents"):
        galr_path("merged", str(other))


@pytest.mark.parametrize(
    ("space", "dataset"), [("galr", "merged"), ("raw", "inspire"), ("per_embodiment", "merged")]
)
def test_wrist_and_hand_each_carry_half_the_loss(data, space, dataset):
    """However wide the hand part (64 z entries, 6 joints, the universal table), the wrist keeps half the
    loss; under `per_embodiment` a hand's absent joints carry none."""
    policy, *_ = make_policy(data, dataset, action_space=space)
    weights, wrist = policy.loss_weights, len(policy.config.wrist_names)
    assert torch.allclose(weights[:, :wrist].sum(-1), torch.tensor(0.5))
    assert torch.allclose(weights[:, wrist:].sum(-1), torch.tensor(0.5))
    if space == "per_embodiment":
        for e, hand in enumerate(policy.config.embodiments):
            present = torch.zeros(weights.shape[-1] - wrist, dtype=torch.bool)
            present[load_hand(hand).universal_index] = True
            assert (weights[e, wrist:][~present] == 0).all() and (weights[e, wrist:][present] > 0).all()


@pytest.mark.parametrize("state_hand", [True, False])
def test_the_state_encoder_reads_the_hand_only_where_asked(data, state_hand):
    policy, *_ = make_policy(data, "leap", action_space="galr", state_hand=state_hand)
    config, n_obs = policy.config, policy.config.n_obs_steps
    wrist = len(config.wrist_names)
    torch.manual_seed(0)
    state, cloud = torch.rand(2, n_obs, config.state_width), torch.rand(2, n_obs, 32 * 3)
    batch = {OBS_STATE: state, OBS_POINTCLOUD: cloud}

    def moved(entries: slice) -> bool:
        state = batch[OBS_STATE].clone()
        state[..., entries] += 0.5
        with torch.no_grad():
            condition = policy.encode_observation(batch | {OBS_STATE: state})
            return not torch.equal(condition, policy.encode_observation(batch))

    assert moved(slice(0, wrist))
    assert moved(slice(wrist, None)) is state_hand


def test_a_state_encoder_without_the_hand_needs_body_entries(data):
    policy, *_ = make_policy(data, "leap", action_space="galr", state_hand=False)
    handless = copy.deepcopy(policy.config)
    handless.wrist_names = []
    with pytest.raises(ValueError, match="state_hand=false leaves the state encoder nothing to read"):
        OpfaPolicy(handless)


def test_state_guard_reads_the_right_frame_of_a_history(caplog):
    """A (batch, time, entries) state: the warning reports the frame that is out of range."""
    tables = {f"observation.state.{k}": v for k, v in
              {"shift": torch.zeros(1, 2), "scale": torch.ones(1, 2), "low": -torch.ones(1, 2),
               "high": torch.ones(1, 2)}.items()}  # fmt: skip
    step = OpfaNormalizeStep(keys=["observation.state"], tables=tables, names=["a", "b"], embodiments=["h"])
    state = torch.tensor([[[0.5, 0.0], [0.0, 42.0]]])
    observation = {"observation.state": state, OBS_EMBODIMENT: torch.zeros(1, 1, dtype=torch.long)}
    with caplog.at_level(logging.WARNING, logger="lerobot_opfa.policy.normalization"):
        step(create_transition(observation=observation))
    (message,) = [r.getMessage() for r in caplog.records]
    assert "entry 'b' of hand 'h' is 42, 20 range-widths outside its training range [-1, 1]" in message


def test_another_checkpoints_postprocessor_beside_a_preprocessor_is_named_as_such(data, tmp_path):
    """A checkpoint folder given another's postprocessor files: LeRobot pairs its steps with this
    preprocessor's encode step, whose robots are others."""
    from lerobot.policies.factory import make_pre_post_processors

    policy, pre, post, frames = make_policy(data, "leap")
    _, _, other_post, _ = make_policy(data, "merged")
    for obj in (policy, pre):
        obj.save_pretrained(tmp_path / "leap")
    other_post.save_pretrained(tmp_path / "leap")  # the merged checkpoint's postprocessor, over leap's
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(tmp_path / "leap"))
    batch = pre(native_observation("leap", frames[0][OBS_POINTCLOUD][-1]))
    with pytest.raises(ValueError, match=r"another checkpoint's: it acts for umi, inspire, leap, its prepro"):
        post(policy.eval().select_action(batch))


def test_building_a_policy_and_its_processors_leaves_their_config_as_passed(data):
    """The record is resolved from the dataset into the policy's own copy of the config; the config a user
    (or lerobot-train) passed is not written into."""
    import copy
    import dataclasses

    meta = LeRobotDatasetMetadata("local/merged", root=data / "merged")
    config = OpfaConfig(**{**POLICY, "galr_path": str(data / "galr")})
    features = dataset_to_policy_features(meta.features)
    config.output_features = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config.input_features = {k: f for k, f in features.items() if k not in config.output_features}
    passed = {field.name: copy.deepcopy(getattr(config, field.name)) for field in dataclasses.fields(config)}
    policy = OpfaPolicy(config, dataset_meta=meta)
    make_opfa_pre_post_processors(config, dataset_meta=meta)
    for name, value in passed.items():
        assert getattr(config, name) == value, name
    assert policy.config.embodiments == ["umi", "inspire", "leap"] and not config.embodiments
