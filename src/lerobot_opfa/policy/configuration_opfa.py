"""`OpfaConfig`: the `opfa` policy type (DP3 acting in GaLR space), registered with LeRobot.

Every hyper-parameter lives here once. The fields under "resolved" are filled from the dataset and the GaLR
checkpoint the first time a policy is built for training, and saved with the checkpoint, so evaluation
and reloading need neither.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PreTrainedConfig
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.optim import AdamConfig
from lerobot.optim.schedulers import CosineDecayWithWarmupSchedulerConfig
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.features import OBS_POINTCLOUD
from lerobot_opfa.flags import flag
from lerobot_opfa.pointclouds import DepthRig
from lerobot_opfa.policy.action_spaces import ACTION_SPACES, ActionSpace
from lerobot_opfa.policy.image_encoder import IMAGE_BACKBONES

WRIST_NORMALIZATIONS = ("per_embodiment", "shared")
VISUAL_INPUTS = ("pointcloud", "rgb", "pointcloud_rgb")
EPISODE_EDGE = 1_000_000
"""Frames: a delta that far reaches past any episode, so the clamped window gives its first or last frame."""


@PreTrainedConfig.register_subclass("opfa")
@dataclass
class OpfaConfig(PreTrainedConfig):
    """DP3 (point-cloud diffusion policy) whose hand state and action are GaLR latents.

    `action_space` picks the method or a baseline of the paper's tables (`action_spaces`): `galr` (OPFA),
    `raw` ("w/o co-train") or `per_embodiment` ("naive co-train").
    """

    n_obs_steps: int = 2
    horizon: int = 16
    n_action_steps: int = 8

    action_space: str = "galr"
    galr_path: str | None = None
    """A GaLR checkpoint (local folder or Hub repo id). Needed to train `galr`; its weights then travel
    inside the saved processors, so a trained policy does not need it any more."""

    joint_map: str | None = None
    """A joint map (YAML, docs/usage.md) for a single-hand dataset whose state/action entries are not named
    after its hand's joints; read at the first training run and saved inside the processors."""

    cameras: str | None = None
    """A camera calibration (YAML, docs/usage.md) for a dataset recorded with depth cameras: their depth-map
    features become the policy's cloud in the preprocessor (`depth_step`); saved inside the processors."""
    cloud_points: int = 1024
    """Points of the cloud made from depth frames (with `cameras`)."""

    normalization: NormalizationMode = NormalizationMode.MIN_MAX
    """Per-embodiment normalisation of state and action (MIN_MAX, MEAN_STD or IDENTITY); MIN_MAX keeps z and
    joints in [-1, 1], the range DDIM clips its samples to."""
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {"STATE": NormalizationMode.IDENTITY, "ACTION": NormalizationMode.IDENTITY}
    )
    """For LeRobot's own (un)normaliser steps, kept in the pipelines as identities: lerobot-train
    reconfigures them by name when it resumes or fine-tunes a checkpoint. Normalisation is `normalization`."""
    wrist_normalization: str = "per_embodiment"
    """`per_embodiment`: each hand's wrist poses span [-1, 1] on their own (robust to hands whose data sit
    in different places); `shared`: one range pooled over all hands (keeps absolute positions comparable,
    what spatial generalisation across hands needs)."""

    # resolved from the dataset and the GaLR at the first training run
    embodiments: list[str] = field(default_factory=list)
    """Hands trained on; a frame's embodiment id indexes this list."""
    embodiment_joints: list[list[str]] = field(default_factory=list)
    """Per embodiment, the universal joints its actuated joints map to (a checkpoint needs no hand model)."""
    robots: list[list[int]] = field(default_factory=list)
    """Per robot trained on, the embodiment each of its hand slots holds (two for a two-handed robot);
    empty (saved before): one one-handed robot per embodiment."""
    wrist_names: list[str] = field(default_factory=list)
    """Leading state entries that are not hand joints (the wrist pose, an arm's joints): the body."""
    action_body_names: list[str] | None = None
    """The action's body entries where they are not the state's (end-effector deltas against arm joints);
    None: the same as `wrist_names`."""
    latent_dim: int | None = None

    visual_inputs: str = "pointcloud"
    """What the policy sees besides the robot's state: `pointcloud` (DP3: `observation.pointcloud`, or the
    cloud `cameras` makes from depth), `rgb` (the colour cameras, `observation.images.*` of 3 channels,
    through `image_encoder`) or `pointcloud_rgb` (both). The action space does not change."""
    image_backbone: str = "small"
    """`small` (four convolutions down to an eighth of the image; trains in minutes on a CPU) or
    `resnet18` (LeRobot's diffusion policy's, GroupNorm from scratch): see `image_encoder`."""
    image_backbone_weights: str | None = None
    """torchvision weights of the ResNet-18 (e.g. ResNet18_Weights.IMAGENET1K_V1) where installed."""
    image_feature_dim: int = 64
    image_crop_ratio: float = 0.9
    """Side of the random training crop (centre crop at inference), as a fraction of the image's."""
    image_goal: bool = True
    """With colour cameras: the image features of each episode's first frame also learn to predict the
    episode's last wrist pose (all its last action's entries where there is no wrist), a loss beside the
    denoising one, so every sample asks the encoder where the object is. Trained on denoising alone, RGB
    policies from 20 demos ignored the object though the encoder can place it (docs/results.md, "Datasets
    as a rig records them")."""

    # DP3 point encoder
    pointcloud_widths: tuple[int, ...] = (64, 128, 256)
    pointcloud_feature_dim: int = 64
    state_mlp_dims: tuple[int, int] = (64, 64)
    """DP3's state encoder: hidden and output width of the MLP the state passes before conditioning."""
    state_hand: bool = True
    """The state encoder reads the hand's part of the state (z, or the hand's joints) beside the body's
    entries; off, the body's entries only, and the hand's state reaches the policy through the cloud or
    cameras alone. Off, `galr` on `pull_drawer` in `mid_center` succeeded 50, 49 and 50 of 50 times
    (Allegro, SVH, LEAP) against 37, 25 and 38 with it on and no `state_hand_noise`, but SVH `lift` 32
    against 50; without `decoded_state`, LEAP in `far_left` succeeded 230/250 over five training seeds,
    against 191/250. Two hands: co-trained on (Inspire, Inspire) and (XHand, XHand), off, the unseen pair
    (Inspire, XHand) succeeded 30/50 against 6/50 (docs/results.md)."""
    state_hand_noise: float | None = None
    """Standard deviation of the Gaussian noise added in training to the hand's part of the normalised state;
    unset, the action space's (`galr` 0.05, `raw` and `per_embodiment` 0). A deployed `galr` hand holds the
    decoded *predicted* z, a little off the demonstrated pose, while a demo's hand during a reach is one pose
    in every frame: a policy that reads that exactness as the phase moves on early (Allegro `pull_drawer`:
    deployed reach states 0.2 from every demo reach state, nearest to the grasp's). Without it, `galr` on
    `pull_drawer` succeeded 37/50 (Allegro) and 25/50 (SVH), with it 50/50 and 45/50 (docs/results.md)."""
    decoded_state: bool = True
    """`galr`: train on the hand states the policy meets when deployed. A deployed robot's hand holds the
    decoded action, the GaLR round trip of the demonstrated pose (on LEAP 1.5 deg off on average, up to 9
    deg); a demo's hand state during a reach is one open pose, so a policy trained on the exact poses never
    learns what that offset should do to the wrist. On, a training frame's hand state is its round trip,
    encode(decode(z)): LEAP `pull_drawer` 48/50 at the default seed, against 34/50 off (docs/results.md)."""

    # FiLM-conditioned 1-D U-Net. DP3 uses 512/1024/2048 (the `paper` experiment scale); this default trains
    # on 2 CPU cores in hours, not days.
    down_dims: tuple[int, ...] = (64, 128, 256)
    kernel_size: int = 5
    n_groups: int = 8
    diffusion_step_embed_dim: int = 128
    use_film_scale_modulation: bool = True
    cpu_fast_sampling: bool = True
    """Sample on a CPU through `fast_sampling` (time-major convolutions in one frozen TorchScript graph)
    outside training: about 3x faster per chunk at batch 1 (benchmarks/bench_policy.py), the same actions
    as the plain U-Net to 1e-5 (tested). Other devices sample through the plain U-Net."""
    cpu_float16_weights: bool = False
    """With `cpu_fast_sampling` on a CPU, multiply by float16 copies of the U-Net's convolution weights
    (float32 sums): about twice as fast at batch 1, but the actions differ from float32 by up to 1e-3 in
    normalised units (benchmarks/bench_policy.py), so it is asked for. Training always uses float32."""

    # DDIM
    num_train_timesteps: int = 100
    num_inference_steps: int = 10
    beta_schedule: str = "squaredcos_cap_v2"
    beta_start: float = 0.0001
    beta_end: float = 0.02
    prediction_type: str = "sample"
    clip_sample: bool = True
    clip_sample_range: float = 1.0

    # training
    optimizer_lr: float = 1e-4
    optimizer_betas: tuple[float, float] = (0.95, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-6
    scheduler_warmup_steps: int = 500
    scheduler_decay_steps: int = 100_000

    def __post_init__(self):
        # refused as a `--policy.*` flag (`flags.FlagError`), its message kept; before LeRobot settles the
        # device, so that a wrong flag is the one line it prints, not the last of LeRobot's device warnings
        with flag("policy"):
            self._check_and_settle()
        super().__post_init__()

    def _check_and_settle(self) -> None:
        self.down_dims = tuple(self.down_dims)
        self.pointcloud_widths = tuple(self.pointcloud_widths)
        self.state_mlp_dims = tuple(self.state_mlp_dims)
        self.optimizer_betas = tuple(self.optimizer_betas)
        for name, value, valid in (
            ("action_space", self.action_space, ACTION_SPACES),
            ("visual_inputs", self.visual_inputs, VISUAL_INPUTS),
            ("image_backbone", self.image_backbone, IMAGE_BACKBONES),
            ("wrist_normalization", self.wrist_normalization, WRIST_NORMALIZATIONS),
            ("prediction_type", self.prediction_type, ("sample", "epsilon")),
            ("beta_schedule", self.beta_schedule, ("squaredcos_cap_v2", "linear")),
        ):
            if value not in valid:
                raise ValueError(f"`{name}` must be one of {list(valid)}, got '{value}'")
        if self.cloud_points < 1:
            raise ValueError(f"`cloud_points` must be positive, got {self.cloud_points}")
        if self.state_hand_noise is None:
            self.state_hand_noise = self.space.state_hand_noise
        if self.state_hand_noise < 0:
            raise ValueError(f"`state_hand_noise` (a deviation) must be >= 0, got {self.state_hand_noise}")
        if not 0.1 <= self.image_crop_ratio <= 1:
            raise ValueError(f"`image_crop_ratio` must be in [0.1, 1], got {self.image_crop_ratio}")
        factor = 2 ** (len(self.down_dims) - 1)
        if self.horizon % factor:
            raise ValueError(
                f"`horizon` ({self.horizon}) must be a multiple of {factor}: the U-Net of down_dims="
                f"{self.down_dims} halves it {len(self.down_dims) - 1} times"
            )
        if not 0 < self.n_action_steps <= self.horizon - self.n_obs_steps + 1:
            raise ValueError(
                f"need 0 < n_action_steps <= horizon - n_obs_steps + 1, got {self.n_action_steps=}, "
                f"{self.horizon=}, {self.n_obs_steps=}"
            )
        if not 0 < self.num_inference_steps <= self.num_train_timesteps:
            raise ValueError("need 0 < num_inference_steps <= num_train_timesteps")
        if self.embodiments:
            self.space.check_robots(self.slot_robots, self.embodiments)

    @property
    def space(self) -> ActionSpace:
        return ACTION_SPACES[self.action_space]

    @property
    def action_body(self) -> list[str]:
        return self.wrist_names if self.action_body_names is None else self.action_body_names

    @property
    def slot_robots(self) -> list[list[int]]:
        """`robots`, or for a policy saved before it, one one-handed robot per embodiment."""
        return self.robots or [[index] for index in range(len(self.embodiments))]

    @property
    def slot_widths(self) -> list[int]:
        """Width of each hand slot's part of the policy's state and action."""
        return self.space.slot_widths(self.latent_dim, self.embodiment_joints, self.slot_robots[0])

    def blocks(self, key: str) -> list[int]:
        """The policy's `key` ("observation.state" or "action") in parts: its body, then each hand slot."""
        body = self.wrist_names if key == OBS_STATE else self.action_body
        return [len(body), *self.slot_widths]

    @property
    def state_width(self) -> int:
        """Width of the policy's state: the body's entries, then each hand slot's."""
        return sum(self.blocks(OBS_STATE))

    @property
    def state_encoder_width(self) -> int:
        """Leading state entries the state encoder reads (`state_hand`)."""
        return self.state_width if self.state_hand else len(self.wrist_names)

    @property
    def action_width(self) -> int:
        """Width of the policy's action: the action's body entries, then the space's."""
        return sum(self.blocks(ACTION))

    @property
    def drop_n_last_frames(self) -> int:
        """Frames at an episode's end whose action chunk would be mostly padding (the sampler skips them)."""
        return self.horizon - self.n_action_steps - self.n_obs_steps + 1

    @property
    def observation_delta_indices(self) -> list[int]:
        """The history, after (`image_goal`) the episode's first frame."""
        first = [-EPISODE_EDGE] if self.learns_image_goal else []
        return first + list(range(1 - self.n_obs_steps, 1))

    @property
    def learns_image_goal(self) -> bool:
        return self.uses_rgb and self.image_goal

    @property
    def action_delta_indices(self) -> list[int]:
        """The chunk's actions, then (`image_goal`) the episode's last, where the window is clamped."""
        goal = [EPISODE_EDGE] if self.learns_image_goal else []
        return list(range(1 - self.n_obs_steps, 1 - self.n_obs_steps + self.horizon)) + goal

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamConfig:
        return AdamConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
        )

    def get_scheduler_preset(self) -> CosineDecayWithWarmupSchedulerConfig:
        return CosineDecayWithWarmupSchedulerConfig(
            num_warmup_steps=self.scheduler_warmup_steps,
            num_decay_steps=self.scheduler_decay_steps,
            peak_lr=self.optimizer_lr,
            decay_lr=self.optimizer_lr * 0.01,
        )

    @property
    def uses_pointcloud(self) -> bool:
        return "pointcloud" in self.visual_inputs

    @property
    def uses_rgb(self) -> bool:
        return "rgb" in self.visual_inputs

    @property
    def image_keys(self) -> list[str]:
        """The colour cameras the policy reads (with `rgb`): every visual input of 3 channels."""
        if not self.uses_rgb:
            return []
        inputs = self.input_features or {}
        return sorted(k for k, f in inputs.items() if f.type is FeatureType.VISUAL and f.shape[0] == 3)

    def validate_features(self) -> None:
        inputs = self.input_features or {}
        if self.uses_pointcloud and OBS_POINTCLOUD not in inputs and self.cameras:
            self._cloud_from_depth(inputs)
        needed = [OBS_STATE] + ([OBS_POINTCLOUD] if self.uses_pointcloud else [])
        missing = [k for k in needed if k not in inputs]
        if missing or ACTION not in (self.output_features or {}):
            depth = [k for k, f in inputs.items() if f.type is FeatureType.VISUAL and f.shape[0] == 1]
            hint = (
                f"; give the depth cameras {depth} their calibration: --policy.cameras=FILE" if depth else ""
            )
            raise ValueError(
                f"the opfa policy with visual_inputs={self.visual_inputs} needs inputs {needed} and output "
                f"{ACTION}; missing {missing + ([] if ACTION in (self.output_features or {}) else [ACTION])}"
                f"{hint}"
            )
        if self.uses_rgb and not self.image_keys:
            visual = {k: tuple(f.shape) for k, f in inputs.items() if f.type is FeatureType.VISUAL}
            raise ValueError(
                f"visual_inputs={self.visual_inputs} needs colour cameras (observation.images.* of shape "
                f"(3, H, W)); the inputs have {visual or 'no cameras'}"
            )
        shapes = {tuple(inputs[k].shape) for k in self.image_keys}
        if len(shapes) > 1:
            raise ValueError(f"the colour cameras {self.image_keys} differ in size ({sorted(shapes)})")
        unread = [k for k, f in inputs.items() if f.type is FeatureType.VISUAL and k not in self.image_keys]
        for key in unread:  # cameras the policy does not read: a robot need not have them to run it
            del inputs[key]
        if self.uses_pointcloud:
            shape = tuple(inputs[OBS_POINTCLOUD].shape)
            if len(shape) != 1 or shape[0] % 3:
                raise ValueError(f"{OBS_POINTCLOUD} must be flattened xyz of shape (N*3,), got {shape}")

    def _cloud_from_depth(self, inputs: dict[str, PolicyFeature]) -> None:
        """The calibrated depth features leave the inputs; the cloud the depth step makes from them enters."""
        rig = DepthRig.load(self.cameras)
        missing = [k for k in rig.cameras if k not in inputs]
        if missing:
            raise ValueError(
                f"--policy.cameras={self.cameras} calibrates {missing}, not features of the dataset "
                f"({', '.join(k for k, f in inputs.items() if f.type is FeatureType.VISUAL) or 'no cameras'})"
            )
        for key in rig.cameras:
            del inputs[key]
        inputs[OBS_POINTCLOUD] = PolicyFeature(FeatureType.STATE, (3 * self.cloud_points,))

    @property
    def n_points(self) -> int:
        return self.input_features[OBS_POINTCLOUD].shape[0] // 3
