"""The policy's action spaces, one class each: what follows the wrist pose in a policy state or action.

- `galr`: the hand's GaLR latent z, one space for every hand (OPFA);
- `raw`: one hand's own joints ("w/o co-train");
- `per_embodiment`: the universal joints, zero where a hand has none, one output head per hand over a shared
  trunk ("naive co-train").

Every fact that depends on the choice is a member here: the width, the entry names, which entries a hand's
loss counts, how many heads, whether statistics pool over hands, and how joints map in and out. The config,
the processors and the policy read `ACTION_SPACES[config.action_space]`; a new baseline is a new class.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, ClassVar, Protocol

import torch
from torch import Tensor

from lerobot_opfa.datasets.layout import latent_names
from lerobot_opfa.hands.universal import UNIVERSAL_INDEX, UNIVERSAL_JOINT_NAMES

if TYPE_CHECKING:
    from lerobot_opfa.hands.model import HandModel


class Hands(Protocol):
    """What a space needs from the joint steps: the hand models and the frozen GaLR of the embodiments."""

    latent_dim: int | None
    embodiment_joints: list[list[str]]
    hand_mask: Tensor

    def model(self, index: int) -> HandModel: ...
    def encode(self, index: int, q: Tensor) -> Tensor: ...
    def encode_universal(self, universal: Tensor, ids: Tensor) -> Tensor: ...
    def decode(self, index: int, z: Tensor) -> Tensor: ...


def universal_mask(embodiment_joints: list[list[str]]) -> Tensor:
    """(embodiments, universal joints): 1 where the embodiment has the joint."""
    mask = torch.zeros(len(embodiment_joints), len(UNIVERSAL_JOINT_NAMES))
    for index, joints in enumerate(embodiment_joints):
        mask[index, [UNIVERSAL_INDEX[u] for u in joints]] = 1.0
    return mask


class ActionSpace:
    name: ClassVar[str]
    uses_galr: ClassVar[bool] = False
    pools_hand_statistics: ClassVar[bool] = False
    """Normalise the hand entries with one range over all embodiments (they mean the same for every hand)."""
    state_hand_noise: ClassVar[float] = 0.0
    """The default deviation of the training noise on the hand's part of the normalised state: how far a
    deployed hand state may lie from every demonstrated one (`OpfaConfig.state_hand_noise`)."""

    def check_robots(self, robots: list[list[int]], embodiments: list[str]) -> None:
        """Raises when this space cannot train on these robots (per robot, its slots' embodiments)
        together."""

    def hand_width(self, latent_dim: int | None, embodiment_joints: list[list[str]]) -> int:
        """Width of one hand slot's part of a policy vector (the same for every hand)."""
        raise NotImplementedError

    def slot_widths(
        self, latent_dim: int | None, embodiment_joints: list[list[str]], robot: list[int]
    ) -> list[int]:
        """Width of each hand slot's part of a policy vector, for a robot whose slots hold embodiments
        `robot`."""
        return [self.hand_width(latent_dim, embodiment_joints)] * len(robot)

    def hand_names(self, hands: Hands, index: int) -> list[str]:
        """The entry names of a slot holding embodiment `index`."""
        raise NotImplementedError

    def hand_mask(self, latent_dim: int | None, embodiment_joints: list[list[str]]) -> Tensor:
        """(embodiments, hand width): 1 where an embodiment's entry means something (its loss counts); a
        slot narrower than the widest reads its first columns."""
        return torch.ones(len(embodiment_joints), self.hand_width(latent_dim, embodiment_joints))

    def n_heads(self, n_embodiments: int) -> int:
        return 1

    def merged_columns(self, n_wrist: int, latent_dim: int | None, slots: int = 1) -> list[int] | None:
        """The columns of a merged dataset's state or action (the body, then per hand slot its universal
        joints and its cached z of `latent_dim` entries, 0: none cached) that are this space's entries as
        they are, or None if none are."""
        return None

    def from_joints(self, hands: Hands, index: int, q: Tensor) -> Tensor:
        """Hand `index`'s joints (..., dof) in spec order -> (..., hand width)."""
        raise NotImplementedError

    def from_universal(self, hands: Hands, universal: Tensor, ids: Tensor) -> Tensor:
        """Universal joints (B, ..., U) of a merged dataset, embodiments `ids` (B,) -> (B, ..., width)."""
        raise NotImplementedError

    def to_joints(self, hands: Hands, index: int, rest: Tensor) -> Tensor:
        """(..., hand width) -> hand `index`'s joints (..., dof) in spec order."""
        raise NotImplementedError


class GalrSpace(ActionSpace):
    name = "galr"
    uses_galr = True
    pools_hand_statistics = True
    state_hand_noise = 0.05  # a deployed hand holds the decoded *predicted* z, 0.07-0.2 off the demos' states

    def hand_width(self, latent_dim, embodiment_joints):
        if latent_dim is None:
            raise ValueError("action_space 'galr' needs the GaLR's latent size")
        return latent_dim

    def hand_names(self, hands, index):
        return latent_names(hands.latent_dim)

    def merged_columns(self, n_wrist, latent_dim, slots=1):
        if not latent_dim:
            return None
        u, width = len(UNIVERSAL_JOINT_NAMES), len(UNIVERSAL_JOINT_NAMES) + latent_dim
        z = [n_wrist + s * width + u + i for s in range(slots) for i in range(latent_dim)]
        return [*range(n_wrist), *z]

    def from_joints(self, hands, index, q):
        return hands.encode(index, q)

    def from_universal(self, hands, universal, ids):
        return hands.encode_universal(universal, ids)

    def to_joints(self, hands, index, rest):
        z = rest.reshape(-1, rest.shape[-1])
        return hands.decode(index, z).reshape(*rest.shape[:-1], -1)


class RawSpace(ActionSpace):
    name = "raw"

    def check_robots(self, robots, embodiments):
        if len(robots) != 1:
            hands = [[embodiments[e] for e in robot] for robot in robots]
            raise ValueError(
                f"action_space 'raw' trains one robot; got {len(robots)} ({hands}). "
                "Use 'per_embodiment' (naive co-training) or 'galr' for several"
            )

    def hand_width(self, latent_dim, embodiment_joints):
        return max(map(len, embodiment_joints))

    def slot_widths(self, latent_dim, embodiment_joints, robot):
        return [len(embodiment_joints[e]) for e in robot]

    def hand_names(self, hands, index):
        return hands.model(index).joint_names

    def from_joints(self, hands, index, q):
        return q

    def from_universal(self, hands, universal, ids):
        index = int(ids.reshape(-1)[0]) if ids.numel() else 0  # the one robot's hand in this slot
        return hands.model(index).from_universal(universal)

    def to_joints(self, hands, index, rest):
        return rest


class PerEmbodimentSpace(ActionSpace):
    name = "per_embodiment"

    def hand_width(self, latent_dim, embodiment_joints):
        return len(UNIVERSAL_JOINT_NAMES)

    def hand_names(self, hands, index):
        return list(UNIVERSAL_JOINT_NAMES)

    def hand_mask(self, latent_dim, embodiment_joints):
        return universal_mask(embodiment_joints)

    def n_heads(self, n_embodiments):
        return n_embodiments

    def merged_columns(self, n_wrist, latent_dim, slots=1):
        u = len(UNIVERSAL_JOINT_NAMES)
        width = u + latent_dim
        return [*range(n_wrist), *(n_wrist + s * width + i for s in range(slots) for i in range(u))]

    def from_joints(self, hands, index, q):
        return hands.model(index).to_universal(q)

    def from_universal(self, hands, universal, ids):
        rows = hands.hand_mask.to(universal.device)[ids]
        return universal * rows.view(len(ids), *([1] * (universal.dim() - 2)), -1)

    def to_joints(self, hands, index, rest):
        return hands.model(index).from_universal(rest)


ACTION_SPACES: Mapping[str, ActionSpace] = MappingProxyType(
    {s.name: s for s in (GalrSpace(), RawSpace(), PerEmbodimentSpace())}
)
