"""`OpfaPolicy`: DP3 in GaLR space. Point-cloud (or colour camera) features and the (wrist + z) state of the
last `n_obs_steps` frames condition a U-Net that denoises a chunk of (wrist + z) actions with DDIM.

The policy never sees joints: the preprocessor maps them to its space and the postprocessor back, so the
same network serves a 1-DoF gripper and a 16-DoF hand. Importing this module registers those processors'
steps, which LeRobot's registry finds by name: a policy loaded in Python loads its processors as it would
through the plugin.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from pathlib import Path

import torch
import torch.nn.functional as F  # noqa: N812
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.policies.utils import populate_queues
from lerobot.utils.constants import ACTION, OBS_STATE
from torch import Tensor, nn

from lerobot_opfa import checkpoint_files
from lerobot_opfa.features import OBS_EMBODIMENT, OBS_POINTCLOUD, column_embodiments
from lerobot_opfa.galr.pointnet import PointNetEncoder
from lerobot_opfa.hands.registry import load_spec
from lerobot_opfa.policy import depth_step, joint_steps, normalization  # noqa: F401  (registers the steps)
from lerobot_opfa.policy.configuration_opfa import OpfaConfig
from lerobot_opfa.policy.diffusion import ConditionalUnet1d, Ddim
from lerobot_opfa.policy.fast_sampling import FastSampler
from lerobot_opfa.policy.image_encoder import ImageEncoder
from lerobot_opfa.policy.record import resolve_config
from lerobot_opfa.process_group import hold_until_exit


def loss_weights(config: OpfaConfig) -> Tensor:
    """(embodiments, width) weights of the action entries in the loss: the wrist and the hands each carry
    half, the hands' half shared by the hand slots, spread evenly over the entries that mean something for
    the embodiment (`ActionSpace.hand_mask`); an entry takes the row of its slot's hand
    (`features.column_embodiments`).

    A plain mean over entries lets the hand part outweigh the wrist by its width: 64 z entries against 6
    wrist entries under `galr`, which then fits the joints and leaves the wrist at the demos' average
    motion (denoising error of the wrist 10x that of `raw` after the same training). For `per_embodiment`,
    a hand's share goes to the universal joints it has."""
    n_wrist, widths = len(config.action_body), config.slot_widths
    mask = config.space.hand_mask(config.latent_dim, config.embodiment_joints)
    slot_share = (0.5 if n_wrist else 1.0) / len(widths)
    wrist = torch.full((len(config.embodiments), n_wrist), (1 - slot_share * len(widths)) / max(n_wrist, 1))
    slots = [slot_share * mask[:, :w] / mask[:, :w].sum(-1, keepdim=True).clamp(min=1) for w in widths]
    return torch.cat([wrist, *slots], dim=-1)


def check_complete(folder: Path) -> None:
    """A checkpoint folder holds its weights and every state file its processors' configs name: a folder
    copied in part would otherwise fail in safetensors' or LeRobot's loaders with a traceback that names no
    fix. (A Hub checkpoint's processor files are fetched later, each with its state files.)"""
    wanted = [folder / "model.safetensors", *checkpoint_files.state_files(folder)]
    missing = [path.name for path in wanted if not path.is_file()]
    if missing:
        raise ValueError(
            f"{folder} is an incomplete checkpoint: {', '.join(missing)} missing (a folder copied in part?); "
            "copy or download the whole pretrained_model folder again"
        )


class OpfaPolicy(PreTrainedPolicy):
    config_class = OpfaConfig
    name = "opfa"

    def __init__(self, config: OpfaConfig, dataset_meta=None, **kwargs):
        """`config` is left as it is: the policy keeps a copy resolved from `dataset_meta` (training), or
        `config` itself (a trained checkpoint's)."""
        meta = dataset_meta if dataset_meta is not None else getattr(config, "_runtime_dataset_meta", None)
        if meta is not None:
            config, _, _ = resolve_config(config, meta)
        elif config.embodiments and not config.embodiment_joints:  # saved before the field existed
            joints = [load_spec(hand).universal_names for hand in config.embodiments]
            config = dataclasses.replace(config, embodiment_joints=joints)
        super().__init__(config)
        config.validate_features()
        if not config.embodiment_joints or (config.space.uses_galr and config.latent_dim is None):
            raise ValueError("an opfa policy is built from a dataset (dataset_meta) or a trained checkpoint")
        if not config.state_encoder_width:
            raise ValueError(
                "--policy.state_hand=false leaves the state encoder nothing to read: this robot's state has "
                "no body entries (wrist pose, arm joints), only the hand's"
            )
        self.config = config
        hold_until_exit()  # a torchrun/accelerate rank of lerobot-train exits without hanging
        width = config.action_width
        self.image_keys = tuple(config.image_keys)
        clouds = (OBS_POINTCLOUD,) if config.uses_pointcloud else ()
        self.observation_keys = (OBS_STATE, *clouds, *self.image_keys)
        """The observation entries the policy reads, each with a history of `n_obs_steps` frames."""
        self.point_encoder = (
            PointNetEncoder(config.pointcloud_feature_dim, config.pointcloud_widths, in_dim=3)
            if config.uses_pointcloud
            else None
        )
        self.image_encoder = (
            ImageEncoder(
                tuple(config.input_features[self.image_keys[0]].shape),
                config.image_feature_dim,
                config.image_backbone,
                config.image_backbone_weights,
                crop_ratio=config.image_crop_ratio,
            )
            if config.uses_rgb
            else None
        )
        image_dim = len(self.image_keys) * config.image_feature_dim
        visual_dim = len(clouds) * config.pointcloud_feature_dim + image_dim
        # The image goal is the last action's wrist entries (all entries without a wrist): where the hand
        # ends up is what the picture shows. With the hand's joints too (the same grasp in every episode),
        # Inspire's 6 joints diluted it: its goal loss sat at the mean's for most of training and RGB lift
        # succeeded 29/50, against 46/50 with the wrist alone (docs/results.md).
        goal_width = len(config.action_body) or width
        self.image_goal = nn.Linear(image_dim, goal_width) if config.learns_image_goal else None
        """An episode's first frame's image features -> its last wrist pose (`image_goal`; training only)."""
        # DP3's state encoder. Fed raw into the U-Net's conditioning, the state would pass its Mish first,
        # which flattens inputs below -0.6 (normalised) to about -0.3: the lower part of every entry's range
        # (the wrist's last centimetres above a button) would barely reach the network.
        hidden, out = config.state_mlp_dims
        self.state_encoder = nn.Sequential(
            nn.Linear(config.state_encoder_width, hidden), nn.ReLU(), nn.Linear(hidden, out)
        )
        self.unet = ConditionalUnet1d(
            action_dim=width,
            cond_dim=config.n_obs_steps * (visual_dim + config.state_mlp_dims[-1]),
            down_dims=config.down_dims,
            kernel=config.kernel_size,
            groups=config.n_groups,
            step_embed_dim=config.diffusion_step_embed_dim,
            use_scale=config.use_film_scale_modulation,
            n_heads=config.space.n_heads(len(config.embodiments)),
        )
        self.fast_sampler = (
            FastSampler(self.unet, config.cpu_float16_weights) if config.cpu_fast_sampling else None
        )
        self.ddim = Ddim(
            config.num_train_timesteps,
            config.num_inference_steps,
            config.beta_schedule,
            config.beta_start,
            config.beta_end,
            config.prediction_type,
            config.clip_sample_range if config.clip_sample else None,
        )
        self.register_buffer("loss_weights", loss_weights(config), persistent=False)
        self.reset()

    @classmethod
    def _load_as_safetensor(cls, model, model_file: str, map_location: str, strict: bool):
        """LeRobot loads weights non-strictly by default, which leaves a layer the file lacks at its random
        initialisation without a word (a warning at most): here a file that does not fit is an error. So is
        a damaged file, named (safetensors' own error names none), and a folder without all its files."""
        from lerobot.utils.device_utils import resolve_safetensors_device
        from safetensors import SafetensorError
        from safetensors.torch import load_model

        check_complete(Path(model_file).parent)
        device = resolve_safetensors_device(map_location)
        try:
            missing, unexpected = load_model(model, model_file, strict=False, device=device)
        except SafetensorError as err:
            raise ValueError(
                f"{model_file} is damaged (cut short or not a safetensors file: {err}); download the "
                "checkpoint again, or save it again from where it was trained"
            ) from None
        goal = [k for k in missing if k.startswith("image_goal.")]
        if goal and len(goal) == len(missing) and not unexpected:
            raise ValueError(
                f"{model_file} has no image_goal head: the policy was trained before `image_goal` existed "
                f'(it only adds a training loss); add the line "image_goal": false to '
                f"{Path(model_file).parent / 'config.json'}, or pass --policy.image_goal=false"
            )
        if missing or unexpected:
            raise ValueError(
                f"{model_file} does not fit this opfa policy (weights missing from the file: "
                f"{sorted(missing)[:4]}, in the file but not the policy: {sorted(unexpected)[:4]}): it was "
                "saved by another version of lerobot-opfa; load it with that version or train again"
            )
        return model

    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self) -> None:
        """Clears the observation history and the queued actions; call on env.reset()."""
        keys = (*self.observation_keys, OBS_EMBODIMENT)
        self._queues = {k: deque(maxlen=self.config.n_obs_steps) for k in keys}
        self._queues[ACTION] = deque(maxlen=self.config.n_action_steps)

    # --- conditioning ------------------------------------------------------------------------------
    def encode_observation(self, batch: dict[str, Tensor], images: Tensor | None = None) -> Tensor:
        """state (B, n_obs, S), pointcloud (B, n_obs, N*3), images (B, n_obs, 3, H, W) -> global condition
        (B, n_obs * (F + I * cameras + E)), F, I and E the point, image and state encoders' widths. `images`:
        the colour cameras' features where already encoded (`encode_images`)."""
        state = batch[OBS_STATE]
        b, n_obs = state.shape[:2]
        features = []
        if self.point_encoder is not None:
            cloud = batch[OBS_POINTCLOUD]
            features.append(self.point_encoder(cloud.reshape(b * n_obs, -1, 3)).view(b, n_obs, -1))
        if self.image_encoder is not None:
            features.append(self.encode_images(batch) if images is None else images)
        read = state[..., : self.config.state_encoder_width]  # the body first, then the hand (`state_hand`)
        return torch.cat([*features, self.state_encoder(read)], dim=-1).flatten(1)

    def encode_images(self, batch: dict[str, Tensor]) -> Tensor:
        """Colour cameras (B, T, 3, H, W) each -> features (B, T, I * cameras)."""
        images = torch.stack([batch[k] for k in self.image_keys], dim=2)  # (B, T, cams, ...)
        return self.image_encoder(images.flatten(0, 2)).view(*images.shape[:2], -1)

    # --- training ----------------------------------------------------------------------------------
    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Denoising loss of the action chunk (prediction target: the clean sample by default), plus (with
        `image_goal`) the error of the episode's last wrist pose predicted from its first picture."""
        batch = self.with_state_noise(batch)
        if self.image_goal is None:
            return self.denoising_loss(batch, batch[ACTION]), {}
        # The windows start with the episode's first frame and end with its last action: one encoder pass.
        images, actions = self.encode_images(batch), batch[ACTION]
        goal_loss = F.mse_loss(self.image_goal(images[:, 0]), actions[:, -1, : self.image_goal.out_features])
        history = batch | {k: batch[k][:, 1:] for k in self.observation_keys}
        denoising = self.denoising_loss(history, actions[:, :-1], images[:, 1:])
        return denoising + goal_loss, {
            "denoising_loss": denoising.item(),
            "image_goal_loss": goal_loss.item(),
        }

    def with_state_noise(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """The batch with `state_hand_noise` on the hand's part of the state, in training."""
        sigma = self.config.state_hand_noise
        if not (self.training and sigma):
            return batch
        state, body = batch[OBS_STATE], len(self.config.wrist_names)
        hand = state[..., body:] + sigma * torch.randn_like(state[..., body:])
        return batch | {OBS_STATE: torch.cat([state[..., :body], hand], dim=-1)}

    def denoising_loss(self, batch: dict[str, Tensor], x0: Tensor, images: Tensor | None = None) -> Tensor:
        """The chunk `x0` (B, horizon, A) noised at random steps, denoised under the observation."""
        cond = self.encode_observation(batch, images)
        noise = torch.randn_like(x0)
        t = torch.randint(0, self.config.num_train_timesteps, (len(x0),), device=x0.device)
        head = self.action_embodiments(batch[OBS_EMBODIMENT])
        pred = self.unet(self.ddim.add_noise(x0, noise, t), t, cond, head)
        error = F.mse_loss(pred, self.ddim.target(x0, noise), reduction="none")
        weights = self.loss_weights[head, torch.arange(head.shape[-1], device=head.device)]
        return (error * weights.unsqueeze(1)).sum(-1).mean()

    def action_embodiments(self, ids: Tensor) -> Tensor:
        """(B, A) embodiment of each action entry, from the frames' (B, slots) ids: its loss row and, for
        `per_embodiment`, its output head."""
        return column_embodiments(ids, self.config.blocks(ACTION))

    # --- inference ---------------------------------------------------------------------------------
    @torch.inference_mode()
    def predict_action_chunk(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """(B, n_action_steps, A) normalised policy-space actions from the current observation history
        (the queues, filled by `select_action`) or from a batch that already has the time axis."""
        if len(self._queues[OBS_STATE]):
            batch = {k: torch.stack(list(self._queues[k]), dim=1) for k in self.observation_keys} | {
                OBS_EMBODIMENT: self._queues[OBS_EMBODIMENT][-1]
            }
        else:
            self.check_observation(batch)
        cond = self.encode_observation(batch)
        head = self.action_embodiments(batch[OBS_EMBODIMENT])
        b = len(cond)
        shape = (b, self.config.horizon, self.unet.action_dim)
        if noise is None:
            noise = torch.randn(shape, device=cond.device, dtype=cond.dtype)
        actions = self.sample(cond, head, noise)
        start = self.config.n_obs_steps - 1
        return actions[:, start : start + self.config.n_action_steps]

    def sample(self, cond: Tensor, head: Tensor | None, noise: Tensor) -> Tensor:
        """The DDIM reverse process from `noise` (B, horizon, A) for global conditions cond (B, C)."""
        steps = self.ddim.timesteps
        fast = cond.device.type == "cpu" and not (self.training or torch.is_grad_enabled())
        if self.fast_sampler is not None and fast:
            return self.ddim.sample(self.fast_sampler.denoiser(steps, cond, head), noise)

        def denoise(x: Tensor, i: int) -> Tensor:
            return self.unet(x, torch.full((len(x),), steps[i], device=x.device), cond, head)

        return self.ddim.sample(denoise, noise)

    def check_observation(self, batch: dict[str, Tensor]) -> None:
        """The observation is one this policy's preprocessor made (the robot's entries mapped into the policy
        space, its embodiment named), and every entry the policy reads is there, each colour camera at the
        size the policy was trained on (its input features): a larger picture would be centre-cropped to
        another part of the view at another scale without a word, and resizing cannot promise the same
        view."""
        state = batch.get(OBS_STATE)
        if OBS_EMBODIMENT not in batch or (state is not None and state.shape[-1] != self.config.state_width):
            raise ValueError(
                "this observation was not made by this policy's preprocessor (it has no "
                f"{OBS_EMBODIMENT}, or its state is not {self.config.state_width} wide): pass it through "
                "the preprocessor of make_pre_post_processors(policy.config, pretrained_path=...) first"
            )
        missing = [k for k in self.observation_keys if k not in batch]
        if missing:
            raise ValueError(
                f"the observation has no {missing} (it has {', '.join(sorted(batch)) or 'nothing'}): this "
                "policy reads what it was trained on; give the robot or env those cameras, under those names"
            )
        for key in self.image_keys:
            (height, width), given = self.config.input_features[key].shape[-2:], tuple(batch[key].shape[-2:])
            if given != (height, width):
                raise ValueError(
                    f"{key}: this policy was trained on {width}x{height} pictures (width x height), this one "
                    f"is {given[1]}x{given[0]}: give the camera at {width}x{height} (another size shows the "
                    "policy another part of the view at another scale)"
                )

    @torch.inference_mode()
    def select_action(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """One action per call; a new chunk is sampled every `n_action_steps` calls (as in LeRobot's
        diffusion policy: observations n-o+1..n condition actions n..n+a-1)."""
        batch = {k: v for k, v in batch.items() if k != ACTION}
        self.check_observation(batch)
        self._queues = populate_queues(self._queues, batch)
        if not self._queues[ACTION]:
            self._queues[ACTION].extend(self.predict_action_chunk({}, noise=noise).transpose(0, 1))
        return self._queues[ACTION].popleft()
