"""Normalisation that is right per embodiment and safe in closed loop.

One affine map per hand for the wrist and joint entries, one shared map for z (a space all hands share):
LeRobot's normaliser keeps one set of statistics per feature, and pooled over hands it would squash a
gripper's 4 cm aperture next to a hand's wrist range, and mix absent universal joints (zeros) into present
ones. Each feature has tables of shape (E, D), row e for embodiment e: `shift`, `scale` with
x_norm = (x - shift[e]) / scale[e], and the training range `low`, `high`. A two-handed robot's entries
each take the row of their own slot's hand (the body's: the first slot's), `features.column_embodiments`.

Two rules keep a rollout from running away:
- a scale is never below the entry's noise floor (what the physical noise of `datasets.statistics` moves it
  by): an entry that is near-constant in the demos (a wrist axis holding still)
  is not amplified into a huge input when the robot jitters;
- actions come out clamped to their training range, so an entry that is constant in the demos comes out
  as that constant, whatever the denoiser outputs for it.
The preprocessor also refuses non-finite states and warns, once per episode and entry, about states far
outside the training range (the policy has never seen them).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import torch
from lerobot.configs import NormalizationMode
from lerobot.processor import ProcessorStep, ProcessorStepRegistry, TransitionKey
from lerobot.processor.relative_action_processor import AbsoluteActionsProcessorStep
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.datasets.statistics import pool
from lerobot_opfa.features import OBS_EMBODIMENT, column_embodiments
from lerobot_opfa.policy.joint_steps import paired_frames

logger = logging.getLogger(__name__)

MIN_SCALE = 1e-6
"""Below this scale an entry never moves, not even by noise (a universal joint the hand lacks): scale 1."""
GUARD_WIDTHS = 10.0
"""A state entry this many range-widths outside its training range gets a warning."""


def affine_tables(
    stats: dict[str, torch.Tensor], mode: NormalizationMode, pooled: torch.Tensor, floor: torch.Tensor
) -> dict[str, torch.Tensor]:
    """`shift`, `scale`, `low`, `high`, each (E, D), from policy-space statistics `stats`
    (`statistics.column_statistics`) and noise floors `floor` (E, D). Entries where `pooled` (D,) is True
    use statistics over all rows (the same in every row of the table)."""
    if mode not in (NormalizationMode.MIN_MAX, NormalizationMode.MEAN_STD, NormalizationMode.IDENTITY):
        raise ValueError(f"opfa normalises with MIN_MAX, MEAN_STD or IDENTITY, not {mode}")
    low, high = pool(stats, "min", pooled), pool(stats, "max", pooled)
    if mode is NormalizationMode.IDENTITY:
        shift, scale = torch.zeros_like(low), torch.ones_like(low)
    elif mode is NormalizationMode.MIN_MAX:
        known = low.isfinite()
        shift = torch.where(known, (high + low) / 2, 0.0)
        scale = torch.where(known, (high - low) / 2, 1.0).maximum(floor)
    else:
        shift, scale = pool(stats, "mean", pooled), pool(stats, "std", pooled).maximum(floor)
    scale[scale < MIN_SCALE] = 1.0
    return {"shift": shift, "scale": scale, "low": low, "high": high}


@dataclass
class _EmbodimentAffine:
    keys: list[str] = field(default_factory=lambda: [OBS_STATE, ACTION])
    tables: dict[str, torch.Tensor] = field(default_factory=dict, repr=False)
    """`{key}.shift`, `{key}.scale`, `{key}.low`, `{key}.high`, (E, D) each; saved as the step's state."""
    slot_widths: list[int] = field(default_factory=list)
    """Width of each hand slot's part, after the body's; empty (saved before slots): one robot's entries,
    every one by its first slot's row."""

    def columns(self, key: str, ids: torch.Tensor) -> torch.Tensor:
        """(B, D) table row of each entry of `key` for frames of (B, slots) embodiment ids."""
        width = self.tables[f"{key}.shift"].shape[-1]
        blocks = [width - sum(self.slot_widths), *self.slot_widths] if self.slot_widths else []
        return column_embodiments(ids, blocks).expand(len(ids), width)

    def _table(self, key: str, name: str, x: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        """Each frame's row of a table by its ids (B, slots), shaped to broadcast against x (B, [T], D)."""
        table = self.tables[f"{key}.{name}"].to(x.device)
        rows = table[self.columns(key, ids).to(x.device), torch.arange(table.shape[-1], device=x.device)]
        return rows.view(len(ids), *([1] * (x.dim() - 2)), x.shape[-1])

    def state_dict(self) -> dict[str, torch.Tensor]:
        return dict(self.tables)

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.tables = {k: v.clone() for k, v in state.items()}

    def transform_features(self, features):
        return features


@ProcessorStepRegistry.register("opfa_normalize")
@dataclass
class OpfaNormalizeStep(_EmbodimentAffine, ProcessorStep):
    """Normalises `observation.state` and `action` by the embodiment of each batch row, after checking
    that the state is finite and warning when it is far outside what the policy was trained on."""

    names: list[str] = field(default_factory=list)
    """Policy-space entry names (wrist, then joints or z), for the messages."""
    embodiments: list[str] = field(default_factory=list)

    def __post_init__(self):
        self._warned: set[tuple[int, int]] = set()

    def __call__(self, transition):
        new = transition.copy()
        obs = dict(new[TransitionKey.OBSERVATION])
        ids = obs[OBS_EMBODIMENT]
        if OBS_STATE in self.keys:
            obs[OBS_STATE] = self._checked_state(obs[OBS_STATE], ids)
        action = new.get(TransitionKey.ACTION)
        if ACTION in self.keys and isinstance(action, torch.Tensor):
            new[TransitionKey.ACTION] = self._normalize(ACTION, action, ids)
        new[TransitionKey.OBSERVATION] = obs
        return new

    def _normalize(self, key: str, x: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        return (x - self._table(key, "shift", x, ids)) / self._table(key, "scale", x, ids)

    def _checked_state(self, state: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        self._check_state(state, ids)
        return self._normalize(OBS_STATE, state, ids)

    def _check_state(self, state: torch.Tensor, ids: torch.Tensor) -> None:
        bad = ~state.isfinite()
        if bad.any():
            entries = sorted({self._name(i) for i in bad.nonzero()[:, -1].tolist()})
            raise ValueError(
                f"{OBS_STATE} is not finite (NaN or inf) in {', '.join(entries)}: check the robot's readings "
                "(z entries are the GaLR latent of the hand's joints)"
            )
        low, high = self._table(OBS_STATE, "low", state, ids), self._table(OBS_STATE, "high", state, ids)
        width = (high - low).maximum(self._table(OBS_STATE, "scale", state, ids))
        widths_out = ((low - state).maximum(state - high) / width).flatten(0, -2)
        hands = self.columns(OBS_STATE, ids).repeat_interleave(len(widths_out) // len(ids), dim=0)
        flat, low, high = (x.expand_as(state).flatten(0, -2) for x in (state, low, high))
        for row, entry in (widths_out > GUARD_WIDTHS).nonzero().tolist():
            hand = int(hands[row, entry])
            if (hand, entry) in self._warned:
                continue
            self._warned.add((hand, entry))
            logger.warning(
                "%s entry '%s' of hand '%s' is %.4g, %.0f range-widths outside its training range "
                "[%.4g, %.4g]: the policy has not seen such inputs (the robot has drifted out of the data)",
                OBS_STATE, self._name(entry), self._hand(hand), flat[row, entry],
                widths_out[row, entry], low[row, entry], high[row, entry],
            )  # fmt: skip

    def _name(self, entry: int) -> str:
        return self.names[entry] if entry < len(self.names) else f"#{entry}"

    def _hand(self, index: int) -> str:
        return self.embodiments[index] if index < len(self.embodiments) else f"#{index}"

    def reset(self) -> None:
        """A new episode: its out-of-range entries are reported again."""
        self._warned.clear()

    def get_config(self) -> dict[str, Any]:
        return {
            "keys": list(self.keys),
            "names": list(self.names),
            "embodiments": list(self.embodiments),
            **({"slot_widths": list(self.slot_widths)} if self.slot_widths else {}),
        }


@ProcessorStepRegistry.register("opfa_unnormalize")
@dataclass
class OpfaUnnormalizeStep(_EmbodimentAffine, AbsoluteActionsProcessorStep):
    """Maps policy actions back, by the embodiments its paired preprocessor saw (`joint_steps`), into the
    actions' training range (a constant action entry comes out as that constant)."""

    embodiments: list[str] = field(default_factory=list)
    link: str = ""
    """Read from checkpoints saved before LeRobot paired the steps; unused."""

    def __call__(self, transition):
        new = transition.copy()
        action = new[TransitionKey.ACTION]
        names = self.embodiments or [str(i) for i in range(len(self.tables[f"{ACTION}.shift"]))]
        ids = paired_frames(self, len(action), names).ids.to(action.device)
        x = action * self._table(ACTION, "scale", action, ids) + self._table(ACTION, "shift", action, ids)
        low, high = self._table(ACTION, "low", action, ids), self._table(ACTION, "high", action, ids)
        new[TransitionKey.ACTION] = x.clamp(low, high)
        return new

    def get_config(self) -> dict[str, Any]:
        slots = {"slot_widths": list(self.slot_widths)} if self.slot_widths else {}
        return {"keys": [ACTION], "embodiments": list(self.embodiments), **slots}
