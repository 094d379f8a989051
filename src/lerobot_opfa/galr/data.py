"""Annotation-free GaLR training data: random reachable states of every hand, clouds made on the fly."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lerobot_opfa.galr.model import Galr, joint_scale


@dataclass
class HandBatch:
    """A mixed-hand batch: encoder inputs for all samples, and per hand the slice and scaled targets."""

    points: torch.Tensor
    labels: torch.Tensor
    level1: torch.Tensor
    superpoints: torch.Tensor
    groups: list[tuple[str, slice, torch.Tensor]]
    """(hand name, its rows of the batch, its joint targets in loss units (n, dof))."""

    def encoder_inputs(self) -> tuple[torch.Tensor, ...]:
        return self.points, self.labels, self.level1, self.superpoints


def make_batch(galr: Galr, joints: dict[str, torch.Tensor]) -> HandBatch:
    """Clouds of each hand's joint vectors (hand -> (n, dof)), stacked into one batch."""
    parts, groups, start = [], [], 0
    for name, q in joints.items():
        model, _ = galr.hand(name)
        parts.append(galr.cloud_inputs(name, q))
        groups.append(
            (name, slice(start, start + len(q)), q.to(galr.device) * joint_scale(model).to(galr.device))
        )
        start += len(q)
    points, labels, level1, superpoints = (torch.cat(x) for x in zip(*parts, strict=True))
    return HandBatch(points, labels, level1, superpoints, groups)


def sample_batch(galr: Galr, hands: list[str], batch_size: int, generator: torch.Generator) -> HandBatch:
    """`batch_size` random reachable states, shared out evenly over `hands` (the remainder at random)."""
    counts = torch.full((len(hands),), batch_size // len(hands))
    counts[torch.randperm(len(hands), generator=generator)[: batch_size % len(hands)]] += 1
    joints = {
        name: galr.hand(name)[0].sample_joints(int(n), generator)
        for name, n in zip(hands, counts.tolist(), strict=True)
        if n > 0
    }
    return make_batch(galr, joints)


def masked_rmse(
    galr: Galr, batch: HandBatch, z: torch.Tensor
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Mean over samples of each sample's RMSE over the joints its hand has (loss units), and the
    per-hand RMSE. The unified decoder predicts every universal joint; the others never enter the loss."""
    per_sample, per_hand = [], {}
    for name, rows, target in batch.groups:
        error = galr.decode_scaled(z[rows], name) - target
        rmse = error.square().mean(dim=1).add(1e-12).sqrt()
        per_sample.append(rmse)
        per_hand[name] = error.detach().square().mean().sqrt()
    return torch.cat(per_sample).mean(), per_hand
