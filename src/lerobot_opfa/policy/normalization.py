"""Normalisation that is right per embodiment: one affine map per hand for the wrist and joint entries,
one shared map for z (a space all hands share).

LeRobot's normaliser keeps one set of statistics per feature, and pooled over hands it would squash a
gripper's 4 cm aperture next to a hand's wrist range, and mix absent universal joints (zeros) into present
ones. Here each feature has tables `shift`, `scale` of shape (E, D), row e for embodiment e:
x_norm = (x - shift[e]) / scale[e]. MIN_MAX puts the data in [-1, 1] (DDIM clips samples to that range).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch
from lerobot.configs import NormalizationMode
from lerobot.processor import ProcessorStep, ProcessorStepRegistry, TransitionKey
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.policy.configuration_opfa import OBS_EMBODIMENT
from lerobot_opfa.policy.joint_steps import embodiment_ids

MIN_SCALE = 1e-6
"""Below this spread an entry is constant for the hand (absent joints, a fixed wrist axis): map it to 0."""


def affine_tables(
    values: torch.Tensor, ids: torch.Tensor, n_embodiments: int, mode: NormalizationMode, pooled: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """(shift, scale), each (E, D), from policy-space rows `values` (F, D) with embodiment `ids` (F,).

    Entries where `pooled` (D,) is True use statistics over all rows (the same in every row of the table).
    """
    dim = values.shape[-1]
    shift, scale = torch.zeros(n_embodiments, dim), torch.ones(n_embodiments, dim)
    if mode is NormalizationMode.IDENTITY:
        return shift, scale
    if mode not in (NormalizationMode.MIN_MAX, NormalizationMode.MEAN_STD):
        raise ValueError(f"opfa normalises with MIN_MAX, MEAN_STD or IDENTITY, not {mode}")

    def stats(rows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if mode is NormalizationMode.MIN_MAX:
            low, high = rows.min(dim=0).values, rows.max(dim=0).values
            return (high + low) / 2, (high - low) / 2
        return rows.mean(dim=0), rows.std(dim=0, unbiased=False)

    all_shift, all_scale = stats(values)
    for e in range(n_embodiments):
        rows = values[ids == e]
        if len(rows):
            shift[e], scale[e] = stats(rows)
        shift[e, pooled], scale[e, pooled] = all_shift[pooled], all_scale[pooled]
    constant = scale < MIN_SCALE
    scale[constant] = 1.0
    return shift, scale


@dataclass
class _EmbodimentAffine:
    keys: list[str] = field(default_factory=lambda: [OBS_STATE, ACTION])
    tables: dict[str, torch.Tensor] = field(default_factory=dict, repr=False)
    """`{key}.shift` and `{key}.scale`, (E, D) each; saved as the step's state."""

    def _apply(self, key: str, x: torch.Tensor, ids: torch.Tensor, inverse: bool) -> torch.Tensor:
        shape = (len(ids), *([1] * (x.dim() - 2)), x.shape[-1])
        shift = self.tables[f"{key}.shift"].to(x.device)[ids].view(shape)
        scale = self.tables[f"{key}.scale"].to(x.device)[ids].view(shape)
        return x * scale + shift if inverse else (x - shift) / scale

    def state_dict(self) -> dict[str, torch.Tensor]:
        return dict(self.tables)

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.tables = {k: v.clone() for k, v in state.items()}

    def transform_features(self, features):
        return features


@ProcessorStepRegistry.register("opfa_normalize")
@dataclass
class OpfaNormalizeStep(_EmbodimentAffine, ProcessorStep):
    """Normalises `observation.state` and `action` by the embodiment of each batch row."""

    def __call__(self, transition):
        new = transition.copy()
        obs = dict(new[TransitionKey.OBSERVATION])
        ids = obs[OBS_EMBODIMENT]
        if OBS_STATE in self.keys:
            obs[OBS_STATE] = self._apply(OBS_STATE, obs[OBS_STATE], ids, inverse=False)
        action = new.get(TransitionKey.ACTION)
        if ACTION in self.keys and isinstance(action, torch.Tensor):
            new[TransitionKey.ACTION] = self._apply(ACTION, action, ids, inverse=False)
        new[TransitionKey.OBSERVATION] = obs
        return new

    def get_config(self) -> dict[str, Any]:
        return {"keys": list(self.keys)}


@ProcessorStepRegistry.register("opfa_unnormalize")
@dataclass
class OpfaUnnormalizeStep(_EmbodimentAffine, ProcessorStep):
    """Maps policy actions back, using the embodiments its linked preprocessor saw."""

    link: str = ""

    def __call__(self, transition):
        new = transition.copy()
        action = new[TransitionKey.ACTION]
        n_embodiments = len(self.tables[f"{ACTION}.shift"])
        ids = embodiment_ids(self.link, len(action), n_embodiments).to(action.device)
        new[TransitionKey.ACTION] = self._apply(ACTION, action, ids, inverse=True)
        return new

    def get_config(self) -> dict[str, Any]:
        return {"keys": [ACTION], "link": self.link}
