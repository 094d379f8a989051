"""`HandModel`: a hand's batched forward kinematics, reachable-state sampling and surface point clouds.

Couplings and fixed joints are folded into one affine map from the actuated joints to every model joint,
so FK of a batch is one matmul plus one pytorch-kinematics call; link poses are returned in the
documented hand frame (the spec's `base`), whatever frame the vendor's file uses. Surface points are drawn
once per link in the link's own frame; a cloud for a batch of poses is then one matrix product per link
that joints move, and one posed copy of the links that none moves (a palm, a gripper body).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import pytorch_kinematics as pk
import torch

from lerobot_opfa.hands.geometry import allocate_points, sample_surface
from lerobot_opfa.hands.labels import tree_labels
from lerobot_opfa.hands.model_file import load_model_file
from lerobot_opfa.hands.spec import HandSpec, HandSpecError
from lerobot_opfa.hands.universal import UNIVERSAL_INDEX, UNIVERSAL_JOINTS

DEFAULT_MIN_POINTS_PER_LINK = 8
POSING_CHUNK_BYTES = 1 << 20
LIMIT_TOLERANCE = 0.05
"""How far past a joint limit a recorded value may lie, as a share of the joint's range (a simulator's
or a servo's overshoot), before it is refused as a wrong unit or column."""
LIVE_LIMIT_TOLERANCE = 0.5
"""A robot's live reading goes past its limits by contact and calibration; only a reading in other units
is refused at inference."""


@dataclass(frozen=True)
class SurfaceSamples:
    """Points fixed on the hand's surface: (N, 3) in their link's frame, their link, their (u, v) label.
    The points are grouped by link in `link_names` order."""

    local_points: torch.Tensor
    link_index: torch.Tensor
    labels: torch.Tensor

    @cached_property
    def posing_weights(self) -> tuple[torch.Tensor, ...]:
        """Per link, (12, 3 n_l): a link's flattened (3, 4) pose times this is its n_l points posed,
        flattened (n_l, 3). Posing a batch is then one matrix product per link with the output already in
        (B, N, 3) order; gathering each point's pose instead moves 16 floats per point, about 10x slower."""
        ones = self.local_points.new_ones(len(self.local_points), 1)
        counts = torch.bincount(self.link_index).tolist()
        weights = []
        for local in torch.cat([self.local_points, ones], dim=1).split(counts):
            weight = local.new_zeros(3, 4, len(local), 3)
            for axis in range(3):
                weight[axis, :, :, axis] = local.T
            weights.append(weight.view(12, -1))
        return tuple(weights)


@dataclass(frozen=True)
class HandCloud:
    points: torch.Tensor
    """(B, N, 3) in the hand's base frame, metres."""
    labels: torch.Tensor
    """(B, N, 2) semantic label (finger u, segment v) of each point."""
    joints: torch.Tensor
    """(B, dof) the actuated joint values that produced the cloud."""


class HandModel:
    """One end-effector, built from its spec: `HandModel.from_spec(path)` or `registry.load_hand(name)`."""

    def __init__(
        self, spec: HandSpec, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
    ):
        try:
            self.model_file = load_model_file(spec.model_path, spec.root)
        except ValueError as err:
            raise HandSpecError(spec.path, "model", str(err)) from err
        spec.check_joints(self.model_file.joint_names)
        geometry_links = set(self.model_file.link_meshes)
        # The labels of the links the spec leaves out, from the kinematic tree (`hands check` prints them).
        self.inferred_links = tree_labels(spec, self.model_file.chain, geometry_links)
        spec = replace(spec, links={**self.inferred_links, **spec.links})
        spec.check_links(self.model_file.link_names, geometry_links)
        self.spec = spec
        self.device, self.dtype = torch.device(device), dtype

        chain_joints = self.model_file.joint_names
        lower, upper = (
            torch.tensor(x, dtype=torch.float64) for x in self.model_file.chain.get_joint_limits()
        )
        actuated = [chain_joints.index(j) for j in spec.actuated_joints]
        # q_all = q @ coupling_matrix.T + coupling_offset, built in the spec's source-first order.
        matrix = torch.zeros(len(chain_joints), len(actuated), dtype=torch.float64)
        offset = torch.zeros(len(chain_joints), dtype=torch.float64)
        matrix[actuated, torch.arange(len(actuated))] = 1.0
        for joint, value in spec.fixed.items():
            j = chain_joints.index(joint)
            if not lower[j] - 1e-6 <= value <= upper[j] + 1e-6:
                raise HandSpecError(
                    spec.path,
                    f"fixed.{joint}",
                    f"{value} is outside its limits [{lower[j]:.4f}, {upper[j]:.4f}]",
                )
            offset[j] = value
        for coupling in spec.couplings.values():
            j, s = chain_joints.index(coupling.joint), chain_joints.index(coupling.source)
            matrix[j] = coupling.scale * matrix[s]
            offset[j] = coupling.scale * offset[s] + coupling.offset
        self._coupling_matrix, self._coupling_offset = matrix, offset
        self._lower_all, self._upper_all = lower, upper
        self._lower, self._upper = lower[actuated], upper[actuated]
        if not torch.all(self._upper > self._lower):
            bad = [
                spec.actuated_joints[i] for i in torch.nonzero(self._upper <= self._lower).flatten().tolist()
            ]
            raise HandSpecError(
                spec.path, "joints", f"joint(s) {bad} have no range in the model (upper <= lower)"
            )
        for pose, values in spec.poses.items():
            for joint, value in values.items():
                i = spec.actuated_joints.index(joint)
                if not self._lower[i] - 1e-6 <= value <= self._upper[i] + 1e-6:
                    raise HandSpecError(
                        spec.path,
                        f"poses.{pose}.{joint}",
                        f"{value} is outside the model's limits [{self._lower[i]:.4f}, {self._upper[i]:.4f}]",
                    )

        hand_links = set(self.model_file.link_meshes) - set(spec.ignored_links)
        self.link_names = sorted(hand_links, key=self.model_file.link_names.index)
        self._samples: dict[tuple[int, int, int], SurfaceSamples] = {}
        hand_from_model = torch.linalg.inv(self._model_from_hand())
        identity = torch.allclose(hand_from_model, torch.eye(4, dtype=torch.float64))
        # (4, 4) float64 model root frame -> hand frame, from the spec's `base`; None when they coincide
        # (every built-in hand), so that FK, on every cloud, pays nothing for it.
        self.base_transform = None if identity else hand_from_model
        self.to(device, dtype)

    def _model_from_hand(self) -> torch.Tensor:
        """(4, 4) pose of the documented hand frame in the model's root frame, from the spec's `base`."""
        base = self.spec.base
        frame = torch.eye(4, dtype=torch.float64)
        roll, pitch, yaw = base.rpy  # URDF: R = Rz(yaw) Ry(pitch) Rx(roll)
        frame[:3, :3] = pk.euler_angles_to_matrix(
            torch.tensor([yaw, pitch, roll], dtype=torch.float64), "ZYX"
        )
        frame[:3, 3] = torch.tensor(base.xyz, dtype=torch.float64)
        if base.link is None:
            return frame
        if base.link not in self.static_links:
            raise HandSpecError(
                self.spec.path,
                "base.link",
                f"'{base.link}' moves with the actuated joints; name the wrist or palm",
            )
        chain = self.model_file.chain.to(dtype=torch.float64)
        rest = self._coupling_offset[None]  # actuated joints at 0, fixed joints at their values
        return chain.forward_kinematics(rest)[base.link].get_matrix()[0] @ frame

    @cached_property
    def static_links(self) -> frozenset[str]:
        """Model links that no actuated joint moves: every joint between them and the root is fixed in the
        file or held by the spec's `fixed`. Their pose, and so their surface points, is the same in every
        configuration."""
        chain = self.model_file.chain
        moving = self._coupling_matrix.any(dim=1).tolist()  # per model joint
        return frozenset(
            chain.idx_to_frame[frame]
            for frame, path in enumerate(chain.parents_indices)
            if not any(joint >= 0 and moving[joint] for joint in chain.joint_indices[path].tolist())
        )

    @classmethod
    def from_spec(cls, path: str | Path, **kwargs) -> HandModel:
        return cls(HandSpec.load(path), **kwargs)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> HandModel:
        """Move in place (FK chain, limits, couplings); cached surface samples are redrawn there."""
        device = torch.device(device) if device is not None else self.device
        if hasattr(self, "chain") and device == self.device and (dtype or self.dtype) == self.dtype:
            return self
        self.device, self.dtype = device, dtype or self.dtype
        self.chain = self.model_file.chain.to(device=self.device, dtype=self.dtype)
        cast = dict(device=self.device, dtype=self.dtype)
        self.coupling_matrix, self.coupling_offset = (
            self._coupling_matrix.to(**cast),
            self._coupling_offset.to(**cast),
        )
        self.lower, self.upper = self._lower.to(**cast), self._upper.to(**cast)
        self.lower_all, self.upper_all = self._lower_all.to(**cast), self._upper_all.to(**cast)
        self._base = None if self.base_transform is None else self.base_transform.to(**cast)
        # Each actuated joint's place in the universal table, and -1 where the spec flips its sense into the
        # table's: read on every batch the processors and the GaLR decoder convert, so built once here.
        self.universal_index = torch.tensor([UNIVERSAL_INDEX[u] for u in self.universal_names], device=device)
        self.universal_sign = torch.tensor([self.spec.signs.get(j, 1.0) for j in self.joint_names], **cast)
        self._samples.clear()
        return self

    # --- joints -------------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def dof(self) -> int:
        return len(self.spec.joints)

    @property
    def joint_names(self) -> list[str]:
        """Actuated model joints, in the order of the joint vector."""
        return self.spec.actuated_joints

    @property
    def chain_joint_names(self) -> list[str]:
        """Every movable model joint, in pytorch-kinematics' order (the order of `expand`)."""
        return self.model_file.joint_names

    @property
    def universal_names(self) -> list[str]:
        return self.spec.universal_names

    def to_universal(self, q: torch.Tensor) -> torch.Tensor:
        """(..., dof) this hand's joints -> (..., universal joints), zero where the hand has none."""
        out = q.new_zeros(*q.shape[:-1], len(UNIVERSAL_JOINTS))
        out[..., self.universal_index.to(q.device)] = q * self.universal_sign.to(q.device, q.dtype)
        return out

    def from_universal(self, universal: torch.Tensor) -> torch.Tensor:
        """(..., universal joints) -> (..., dof) this hand's joints, in its vendor's senses."""
        sign = self.universal_sign.to(universal.device, universal.dtype)
        return universal[..., self.universal_index.to(universal.device)] * sign

    @property
    def prismatic_mask(self) -> torch.Tensor:
        return torch.tensor(
            [UNIVERSAL_JOINTS[UNIVERSAL_INDEX[u]].kind == "prismatic" for u in self.universal_names]
        )

    def pose(self, name: str) -> torch.Tensor:
        """A named pose of the spec as a joint vector (dof,); unlisted joints are 0, clipped to limits."""
        if name not in self.spec.poses:
            raise KeyError(f"hand '{self.name}' has no pose '{name}'; it has {sorted(self.spec.poses)}")
        values = self.spec.poses[name]
        q = torch.tensor([values.get(j, 0.0) for j in self.joint_names], device=self.device, dtype=self.dtype)
        return q.clamp(self.lower, self.upper)

    def expand(self, q: torch.Tensor) -> torch.Tensor:
        """(B, dof) actuated joints -> (B, n_chain_joints) every model joint, couplings applied."""
        self._check_joints(q)
        return q @ self.coupling_matrix.T + self.coupling_offset

    def sample_joints(self, batch_size: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """Uniformly random reachable states within the model's limits, (B, dof)."""
        u = torch.rand(batch_size, self.dof, generator=generator, dtype=self.dtype, device="cpu").to(
            self.device
        )
        return self.lower + u * (self.upper - self.lower)

    def _check_joints(self, q: torch.Tensor) -> None:
        if q.ndim != 2 or q.shape[1] != self.dof:
            raise ValueError(
                f"hand '{self.name}' expects joints of shape (B, {self.dof}) {self.joint_names}, "
                f"got {tuple(q.shape)}"
            )

    def check_within_limits(
        self,
        q: torch.Tensor,
        source: str,
        tolerance: float = LIMIT_TOLERANCE,
        hint: str = "check the joints' units and order (`lerobot-opfa hands list`)",
    ) -> None:
        """Refuses joint values (B, dof) from `source` that are not finite or lie beyond the model's limits
        by more than `tolerance` of the joint's range (a recording in other units, or the wrong
        columns): the GaLR would encode them without a word, into latents no policy should learn."""
        self._check_joints(q)
        q = q.detach().to("cpu", torch.float64)
        bad = ~q.isfinite()
        if bad.any():
            joint = self.joint_names[int(bad.any(0).nonzero()[0])]
            raise ValueError(
                f"{source}: joint values of hand '{self.name}' are not finite (NaN or inf) in "
                f"{int(bad.any(1).sum())} of {len(q)} frames, first in joint '{joint}'"
            )
        lower, upper = self._lower, self._upper
        slack = tolerance * (upper - lower)
        beyond = (lower - slack - q).maximum(q - upper - slack)
        outside = beyond > 0
        if outside.any():
            j = int(beyond.max(0).values.argmax())
            worst = q[beyond[:, j].argmax(), j]
            raise ValueError(
                f"{source}: joint '{self.joint_names[j]}' of hand '{self.name}' is outside its limits "
                f"[{lower[j]:.4g}, {upper[j]:.4g}] in {int(outside[:, j].sum())} of {len(q)} frames (worst "
                f"{worst:.4g}); {hint}"
            )

    # --- kinematics ---------------------------------------------------------------------------------
    def forward_kinematics(self, q: torch.Tensor) -> torch.Tensor:
        """(B, dof) -> (B, L, 4, 4) base-frame poses of the links in `link_names` (those with geometry)."""
        return self.link_poses(q, self.link_names)

    def link_poses(self, q: torch.Tensor, links: list[str]) -> torch.Tensor:
        """(B, dof) -> (B, len(links), 4, 4) hand-frame poses of any model links."""
        frames = self.chain.forward_kinematics(self.expand(q.to(self.device, self.dtype)))
        poses = torch.stack([frames[link].get_matrix() for link in links], dim=1)
        return poses if self._base is None else self._base @ poses

    # --- point clouds -------------------------------------------------------------------------------
    def surface_samples(
        self, n_points: int, seed: int = 0, min_per_link: int = DEFAULT_MIN_POINTS_PER_LINK
    ) -> SurfaceSamples:
        """`n_points` surface points fixed to the links, the same for every pose (cached per seed)."""
        key = (n_points, seed, min_per_link)
        if key not in self._samples:
            if n_points < len(self.link_names):
                raise ValueError(
                    f"hand '{self.name}' has {len(self.link_names)} links with geometry; "
                    "n_points must be at least that"
                )
            meshes = [self.model_file.link_meshes[link] for link in self.link_names]
            counts = allocate_points(np.array([m.area for m in meshes]), n_points, min_per_link)
            rng = np.random.default_rng(seed)
            points = np.concatenate([sample_surface(m, c, rng) for m, c in zip(meshes, counts, strict=True)])
            link_index = np.repeat(np.arange(len(meshes)), counts)
            labels = np.array([self.spec.links[link] for link in self.link_names])[link_index]
            self._samples[key] = SurfaceSamples(
                torch.tensor(points, device=self.device, dtype=self.dtype),
                torch.tensor(link_index, device=self.device),
                torch.tensor(labels, device=self.device),
            )
        return self._samples[key]

    def point_cloud(self, q: torch.Tensor, n_points: int = 1024, seed: int = 0) -> HandCloud:
        """Surface cloud of the hand at each configuration: points (B, N, 3), labels (B, N, 2)."""
        samples = self.surface_samples(n_points, seed)
        poses = self.forward_kinematics(q)[..., :3, :].flatten(2)  # (B, L, 12)
        weights = samples.posing_weights
        points = poses.new_empty(len(poses), 3 * len(samples.local_points))
        # A link no joint moves has the same points in every row: posed once and copied (28-66 % of points).
        static = {
            link: poses[:1, link] @ w
            for link, (name, w) in enumerate(zip(self.link_names, weights, strict=True))
            if name in self.static_links
        }
        # Rows in chunks whose per-link products stay under 1 MB: larger temporaries go back to the OS
        # when freed and fault their pages in again on every call (up to 5x slower for a 3-link gripper).
        widest = max((w.shape[1] for link, w in enumerate(weights) if link not in static), default=1)
        rows = max(1, POSING_CHUNK_BYTES // (poses.element_size() * widest))
        for start in range(0, len(poses), rows):
            chunk = poses[start : start + rows]
            torch.cat(
                [
                    static[link].expand(len(chunk), -1) if link in static else chunk[:, link] @ w
                    for link, w in enumerate(weights)
                ],
                dim=1,
                out=points[start : start + rows],
            )
        points = points.view(len(poses), -1, 3)
        labels = samples.labels.expand(points.shape[0], -1, -1)
        return HandCloud(points, labels, q.to(self.device, self.dtype))

    # --- fingertips ---------------------------------------------------------------------------------
    @cached_property
    def fingertip_links(self) -> list[str]:
        """Each finger's (u >= 1) most distal link with geometry: the highest segment, and of links that share
        it the last in the tree (a fingertip fixed to its distal link shares the distal link's segment)."""
        tips: dict[int, tuple[int, str]] = {}
        for link in self.link_names:
            u, v = self.spec.links[link]
            if u > 0 and (u not in tips or v >= tips[u][0]):
                tips[u] = (v, link)
        return [tips[u][1] for u in sorted(tips)]

    @cached_property
    def _fingertip_local(self) -> torch.Tensor:
        """(F, 3) the surface point of each fingertip link farthest from its joint, in the link frame."""
        points = []
        for link in self.fingertip_links:
            vertices = self.model_file.link_meshes[link].vertices
            points.append(vertices[np.linalg.norm(vertices, axis=1).argmax()])
        return torch.tensor(np.array(points), dtype=torch.float64)

    def fingertip_positions(self, q: torch.Tensor) -> torch.Tensor:
        """(B, dof) -> (B, F, 3) fingertip points in the base frame, one per finger in `fingertip_links`."""
        poses = self.link_poses(q, self.fingertip_links)
        local = self._fingertip_local.to(self.device, self.dtype)
        return torch.einsum("bfij,fj->bfi", poses[..., :3, :3], local) + poses[..., :3, 3]

    def __repr__(self) -> str:
        joints, links = len(self.chain_joint_names), len(self.link_names)
        return f"HandModel(name={self.name!r}, dof={self.dof}, joints={joints}, links={links})"
