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
    stem: torch.Tensor
    groups: list[tuple[str, slice, torch.Tensor]]
    """(hand name, its rows of the batch, its joint targets in loss units (n, dof))."""

    def encoder_inputs(self) -> tuple[torch.Tensor, ...]:
        return self.points, self.labels, self.level1, self.superpoints, self.stem


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
    return HandBatch(*(torch.cat(x) for x in zip(*parts, strict=True)), groups)


SHARES = ("dof", "even")


def hand_counts(dofs: list[int], batch_size: int, shares: str, generator: torch.Generator) -> torch.Tensor:
    """States per hand in a batch of `batch_size`. `even`: equal shares (the remainder at random). `dof`:
    one each, the rest drawn in proportion to the hands' joint counts, since an 18-joint hand has more to
    learn from each batch than a 1-joint gripper (a batch no larger than the hand count is shared evenly)."""
    if shares not in SHARES:
        raise ValueError(f"unknown hand shares '{shares}'; valid: {', '.join(SHARES)}")
    n = len(dofs)
    if shares == "even" or batch_size <= n:
        counts = torch.full((n,), batch_size // n)
        counts[torch.randperm(n, generator=generator)[: batch_size % n]] += 1
        return counts
    weights = torch.tensor(dofs, dtype=torch.float)
    extra = torch.multinomial(weights, batch_size - n, replacement=True, generator=generator)
    return 1 + torch.bincount(extra, minlength=n)


def sample_batch(
    galr: Galr,
    hands: list[str],
    batch_size: int,
    generator: torch.Generator,
    shares: str,
    focus: tuple[str, ...] = (),
) -> HandBatch:
    """`batch_size` random reachable states of `hands`, shared out as `hand_counts` says; the `focus` hands
    (ones being added to a trained GaLR) get half of every batch between them."""
    models = [galr.hand(name)[0] for name in hands]
    groups = [[i for i, h in enumerate(hands) if (h in focus) == inside] for inside in (True, False)]
    groups = [g for g in groups if g]
    sizes = [batch_size // 2, batch_size - batch_size // 2] if len(groups) == 2 else [batch_size]
    counts = torch.zeros(len(hands), dtype=torch.long)
    for group, size in zip(groups, sizes, strict=True):
        counts[group] = hand_counts([models[i].dof for i in group], size, shares, generator)
    joints = {
        name: model.sample_joints(int(n), generator)
        for name, model, n in zip(hands, models, counts.tolist(), strict=True)
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
