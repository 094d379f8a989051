"""The GaLR model: encoder f_theta (hand cloud -> z) and decoder g_psi (z -> universal-hand joints).

A checkpoint (`save_pretrained` / `from_pretrained` / `push_to_hub`, safetensors + config.json) records
the hand registry it was trained on; using it with a hand it has not seen, or whose spec or model file
changed since, is an error rather than a silent mismatch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import torch
from huggingface_hub import PyTorchModelHubMixin
from torch import nn

from lerobot_opfa.galr.kpconv import KPConv, ResidualBlock
from lerobot_opfa.galr.neighbors import gather_neighbors, radius_neighbors
from lerobot_opfa.galr.pointnet import PointNetEncoder
from lerobot_opfa.galr.pyramid import PyramidIndex, pyramid_index
from lerobot_opfa.galr.transformer import GeometricTransformer, SemanticEmbedding, SemanticTarget
from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.registry import builtin_hands, load_hand
from lerobot_opfa.hands.universal import UNIVERSAL_JOINT_NAMES, UNIVERSAL_JOINTS

PRISMATIC_SCALE = 20.0
"""Prismatic joints enter the loss in units of 5 cm, so a gripper's ~4 cm jaw travel spans about as much
of the loss as a finger's ~1 rad flexion; metrics report them back in metres."""


@dataclass
class GalrConfig:
    latent_dim: int = 64
    encoder: Literal["kpconv_transformer", "pointnet"] = "kpconv_transformer"
    semantic_embedding: SemanticEmbedding = "linear"
    semantic_target: SemanticTarget = "features"
    """Where r^s enters the transformer: the superpoint features (`features`) or the attention's relative
    term (`attention`, the only choice before this field existed; see `transformer.py`)."""
    decoder: Literal["unified", "per_embodiment"] = "unified"
    stem_neighbors: Literal["link", "radius"] = "link"
    """The stem's neighbourhoods (dense points -> level 1): the points within the radius on the query's own
    link, found once per hand (`link`), or on any link, searched in every cloud (`radius`, the only choice
    before this field existed, three times the stem's cost). Contacts between links enter at level 1."""
    n_points: int = 1024
    n_level1: int = 128
    n_superpoints: int = 32
    sample_seed: int = 0
    """Seed of the per-link surface samples: fixed, so a hand's cloud is the same in pretraining and use."""
    grid: float = 0.011
    """Level-1 grid size dl_1 in metres; superpoints use 2 dl_1. Radii and sigmas are in grid units. With 128
    level-1 points a hand's level-1 spacing is about 1.1 cm, so each keeps ~9 neighbours within 2.5 dl_1."""
    radius_factor: float = 2.5
    sigma_factor: float = 1.5
    kernel_points: int = 15
    neighbor_limits: tuple[int, int, int, int] = (40, 16, 40, 12)
    """Neighbours kept for dense->level1, level1, level1->superpoints, superpoints: about the 60th-90th
    percentile of the counts within each radius over random states of the paper's 11 hands."""
    widths: tuple[int, int, int] = (64, 128, 256)
    transformer_dim: int = 128
    transformer_heads: int = 4
    transformer_layers: int = 2
    structure_dim: int = 32
    """Width of the pairwise structure embedding r_ij (GeoTransformer uses the feature width)."""
    decoder_hidden: int = 256
    hands: list[dict] = field(default_factory=list)
    """The registry trained on: name, spec path, sha256 of spec + model file, universal joint names."""
    universal_joints: list[str] = field(default_factory=lambda: list(UNIVERSAL_JOINT_NAMES))
    """The universal joint table the decoder's outputs follow."""

    def __post_init__(self):
        self.neighbor_limits = tuple(self.neighbor_limits)
        self.widths = tuple(self.widths)
        if self.encoder not in ("kpconv_transformer", "pointnet"):
            raise ValueError(f"encoder must be 'kpconv_transformer' or 'pointnet', got '{self.encoder}'")
        if self.decoder not in ("unified", "per_embodiment"):
            raise ValueError(f"decoder must be 'unified' or 'per_embodiment', got '{self.decoder}'")
        if self.stem_neighbors not in ("link", "radius"):
            raise ValueError(f"stem_neighbors must be 'link' or 'radius', got '{self.stem_neighbors}'")
        if self.semantic_target not in ("features", "attention"):
            raise ValueError(
                f"semantic_target must be 'features' or 'attention', got '{self.semantic_target}'"
            )
        if list(self.universal_joints) != list(UNIVERSAL_JOINT_NAMES):
            raise ValueError(
                "this GaLR was trained on another universal joint table than this version of lerobot-opfa "
                f"has ({len(self.universal_joints)} vs {len(UNIVERSAL_JOINT_NAMES)} joints); retrain it"
            )

    @property
    def radii(self) -> tuple[float, float]:
        """Neighbourhood radii (metres) at level 1 (the stem's too) and at the superpoints."""
        return self.radius_factor * self.grid, 2 * self.radius_factor * self.grid

    @property
    def hand_names(self) -> list[str]:
        return [h["name"] for h in self.hands]


def hand_record(hand: HandModel) -> dict:
    return {
        "name": hand.name,
        "spec": str(hand.spec.path),
        "sha256": hand.spec.sha256,
        "joints": hand.universal_names,
    }


class KPConvTransformerEncoder(nn.Module):
    """Dense cloud -> KPConv to level 1 -> residual blocks -> superpoints -> geometric transformer -> mean."""

    def __init__(self, config: GalrConfig):
        super().__init__()
        dl1, dl2 = config.grid, 2 * config.grid
        r1, r2 = config.radii
        s1, s2 = config.sigma_factor * dl1, config.sigma_factor * dl2
        c1, c2, c3 = config.widths
        self.radii, self.limits = (r1, r1, r2, r2), config.neighbor_limits
        self.search_stem = config.stem_neighbors == "radius"
        self.stem = KPConv(1, c1, r1, s1, config.kernel_points)
        self.stem_norm = nn.Sequential(nn.LayerNorm(c1), nn.LeakyReLU(0.1))
        self.level1 = ResidualBlock(c1, c2, r1, s1, strided=False, n_kernel=config.kernel_points)
        self.down = ResidualBlock(c2, c3, r2, s2, strided=True, n_kernel=config.kernel_points)
        self.level2 = ResidualBlock(c3, c3, r2, s2, strided=False, n_kernel=config.kernel_points)
        self.to_transformer = nn.Linear(c3, config.transformer_dim)
        self.transformer = GeometricTransformer(
            config.transformer_dim,
            config.transformer_heads,
            config.transformer_layers,
            dl2,
            config.semantic_embedding,
            config.structure_dim,
            config.semantic_target,
        )
        self.to_latent = nn.Linear(config.transformer_dim, config.latent_dim)

    def forward(self, points, labels, level1, superpoints, stem) -> torch.Tensor:
        p1, p2 = _select(points, level1), _select(points, superpoints)
        searches = ((p1, p1), (p2, p1), (p2, p2))
        with torch.no_grad():
            if self.search_stem:
                stem = radius_neighbors(p1, points, self.radii[0], self.limits[0])
            n11, n12, n22 = (
                radius_neighbors(q, s, r, k)
                for (q, s), r, k in zip(searches, self.radii[1:], self.limits[1:], strict=True)
            )
        f1 = self.stem_norm(self.stem(p1, points, None, stem))
        f1 = self.level1(p1, p1, f1, n11)
        f2 = self.level2(p2, p2, self.down(p2, p1, f1, n12), n22)
        x = self.transformer(self.to_transformer(f2), p2, _select(labels, superpoints))
        return self.to_latent(x.mean(dim=1))


class PointNetLatentEncoder(nn.Module):
    """The ablation: DP3's PointNet on the dense cloud (xyz + labels), no pyramid, no transformer."""

    def __init__(self, config: GalrConfig):
        super().__init__()
        self.pointnet = PointNetEncoder(config.latent_dim, config.widths, in_dim=5)

    def forward(self, points, labels, level1, superpoints, stem) -> torch.Tensor:
        return self.pointnet(torch.cat([points, labels.float()], dim=-1))


def _select(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """(B, N, C) values at (B, M) indices -> (B, M, C)."""
    return gather_neighbors(values, index.unsqueeze(-1)).squeeze(2)


class Galr(nn.Module, PyTorchModelHubMixin, library_name="lerobot-opfa", tags=["lerobot", "opfa", "galr"]):
    """f_theta and g_psi together. Use `encode_joints(hand, q)` and `decode(z, hand)` for a hand's joints."""

    def __init__(self, config: GalrConfig | dict):
        super().__init__()
        if isinstance(config, dict):  # a checkpoint saved before these fields existed
            config = {"semantic_target": "attention", "stem_neighbors": "radius"} | config
        self.config = config if isinstance(config, GalrConfig) else GalrConfig(**config)
        encoders = {"kpconv_transformer": KPConvTransformerEncoder, "pointnet": PointNetLatentEncoder}
        self.encoder = encoders[self.config.encoder](self.config)
        hidden = self.config.decoder_hidden

        def mlp(out: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Linear(self.config.latent_dim, hidden), nn.LayerNorm(hidden), nn.ReLU(),
                nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, out),
            )  # fmt: skip

        if self.config.decoder == "unified":
            self.decoder = mlp(len(UNIVERSAL_JOINT_NAMES))
        else:
            self.decoder = nn.ModuleDict({h["name"]: mlp(len(h["joints"])) for h in self.config.hands})
        self._hands: dict[tuple[str, str], tuple[HandModel, PyramidIndex]] = {}

    # --- hands --------------------------------------------------------------------------------------
    def hand(self, hand: str | HandModel) -> tuple[HandModel, PyramidIndex]:
        """The hand (a registry name, a spec path or a HandModel) checked against the registry once, with
        its pyramid indices, on the model's device; cached, as every batch asks for it."""
        device = self.device
        key = (str(hand.spec.path) if isinstance(hand, HandModel) else str(hand), str(device))
        if key not in self._hands:
            if isinstance(hand, HandModel):
                model = hand.to(device)
            else:
                model = load_hand(self._spec_for(hand), device=str(device))
            record = self._record(model.name)
            if record["sha256"] != model.spec.sha256:
                raise ValueError(
                    f"hand '{model.name}' changed since this GaLR checkpoint was trained (spec or model file "
                    f"{model.spec.path} has a different hash); retrain or use the original files"
                )
            c = self.config
            index = pyramid_index(
                model,
                c.n_points,
                c.n_level1,
                c.n_superpoints,
                c.sample_seed,
                c.radii[0],
                c.neighbor_limits[0],
            )
            self._hands[key] = (model, index.to(device))
        return self._hands[key]

    def _record(self, name: str) -> dict:
        for record in self.config.hands:
            if record["name"] == name:
                return record
        raise ValueError(
            f"hand '{name}' is not in this GaLR checkpoint's registry ({', '.join(self.config.hand_names)}); "
            "pretrain a GaLR that includes it"
        )

    def _spec_for(self, hand: str) -> str:
        """Registry names resolve to the spec recorded at training time when it is not a built-in."""
        for record in self.config.hands:
            if record["name"] == hand:
                return hand if hand in builtin_hands() else record["spec"]
        return hand

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    # --- encode / decode ----------------------------------------------------------------------------
    def forward(self, points, labels, level1, superpoints, stem) -> torch.Tensor:
        """points (B, N, 3), labels (B, N, 2), pyramid indices (B, N1), (B, N2), (B, N1, K) -> z (B, L)."""
        return self.encoder(points, labels, level1, superpoints, stem)

    def cloud_inputs(self, hand: str | HandModel, q: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Everything `forward` needs for a batch of one hand's joint vectors (B, dof)."""
        model, index = self.hand(hand)
        cloud = model.point_cloud(q.to(self.device), self.config.n_points, seed=self.config.sample_seed)
        b = len(q)
        return (
            cloud.points,
            cloud.labels,
            index.level1.expand(b, -1),
            index.superpoints.expand(b, -1),
            index.stem.expand(b, -1, -1),
        )

    def encode_joints(self, hand: str | HandModel, q: torch.Tensor) -> torch.Tensor:
        """(B, dof) joints of `hand` -> (B, latent_dim): G = f_theta o FK."""
        return self(*self.cloud_inputs(hand, q))

    def decode_scaled(self, z: torch.Tensor, hand: str | HandModel) -> torch.Tensor:
        """(B, latent) -> (B, dof) in loss units (prismatic joints x PRISMATIC_SCALE)."""
        model, _ = self.hand(hand)
        if self.config.decoder == "unified":
            return model.from_universal(self.decoder(z))
        return self.decoder[model.name](z)

    def decode(self, z: torch.Tensor, hand: str | HandModel) -> torch.Tensor:
        """(B, latent) -> (B, dof) joint values of `hand` (radians, metres), clipped to its limits."""
        model, _ = self.hand(hand)
        q = self.decode_scaled(z, model) / joint_scale(model).to(z.device)
        return q.clamp(model.lower, model.upper)


def joint_scale(hand: HandModel) -> torch.Tensor:
    """(dof,) factor from joint units to loss units."""
    kinds = [UNIVERSAL_JOINTS[UNIVERSAL_JOINT_NAMES.index(u)].kind for u in hand.universal_names]
    return torch.tensor([PRISMATIC_SCALE if k == "prismatic" else 1.0 for k in kinds])
