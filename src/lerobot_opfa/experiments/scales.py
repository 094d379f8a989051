"""How big an experiment runs: demonstrations, training length, policy size and evaluation episodes.

Training length is counted in epochs, as DP3 does, so a policy co-trained on nine hands' demos takes nine
times the steps of one trained on a single hand's, clamped to [min_steps, max_steps].

`paper` uses the paper's counts (72 demonstrations per embodiment, DP3's 3000 epochs and U-Net); `small`
trains every policy for 50 epochs, the length at which every single-hand policy of the learnability
benchmark (benchmarks/bench_learnability.py: umi, Inspire and XHand, raw and GaLR actions) reached 90 % on
press_button and lift in its demos' region (`lerobot-opfa train` on 2 cores: about 8 steps of 32 samples a
second with one thread, 14 with two on an idle machine); `toy` exists for the tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Scale:
    name: str
    demos: int
    """Demonstrations per embodiment (the paper's 72)."""
    fewshot_counts: tuple[int, ...]
    """Demonstrations of the new embodiment in the few-shot experiment."""
    epochs: float
    """Passes over the training dataset."""
    min_steps: int
    max_steps: int | None
    batch_size: int
    eval_episodes: int
    """Episodes per evaluated (condition, embodiment) cell."""
    eval_batch_size: int
    n_points: int
    policy_args: tuple[str, ...]
    """Extra `lerobot-train` flags that size the policy."""
    episode_length: int | None = None
    """Steps per evaluation episode; None: the task's default."""

    def steps(self, frames: int) -> int:
        """Optimiser steps for a dataset of `frames` frames."""
        steps = max(self.min_steps, math.ceil(self.epochs * frames / self.batch_size))
        return steps if self.max_steps is None else min(self.max_steps, steps)

    def train_args(self, frames: int, untrained: bool = False) -> list[str]:
        """The training flags for a dataset of `frames` frames; `untrained`: one step at learning rate 0,
        the policy as initialised with the dataset's normalisation (the control)."""
        steps = 1 if untrained else self.steps(frames)
        return [
            *(["--policy.optimizer_lr=0"] if untrained else []),
            f"--steps={steps}",
            f"--batch_size={self.batch_size}",
            f"--policy.scheduler_warmup_steps={min(500, steps // 10)}",
            f"--policy.scheduler_decay_steps={steps}",
            f"--save_freq={steps}",
            f"--log_freq={max(1, steps // 20)}",
            *self.policy_args,
        ]


PAPER_FEWSHOT_COUNTS = (1, 2, 4, 8, 12, 18, 36)

SCALES = {
    "toy": Scale(
        name="toy",
        demos=2,
        fewshot_counts=(1, 2),
        epochs=1,
        min_steps=2,
        max_steps=2,
        batch_size=4,
        eval_episodes=2,
        eval_batch_size=2,
        n_points=64,
        policy_args=(
            "--policy.down_dims=[16,32]",
            "--policy.horizon=8",
            "--policy.n_action_steps=4",
            "--policy.pointcloud_widths=[16,32]",
            "--policy.pointcloud_feature_dim=16",
            "--policy.n_groups=4",
            "--policy.diffusion_step_embed_dim=16",
        ),
        episode_length=6,
    ),
    "small": Scale(
        name="small",
        demos=24,
        fewshot_counts=PAPER_FEWSHOT_COUNTS,
        epochs=50,
        min_steps=200,
        max_steps=20_000,
        batch_size=32,
        eval_episodes=50,
        eval_batch_size=25,
        n_points=256,
        policy_args=(
            "--policy.pointcloud_widths=[32,64,128]",
            "--policy.optimizer_lr=3e-4",
        ),
    ),
    "paper": Scale(
        name="paper",
        demos=72,
        fewshot_counts=PAPER_FEWSHOT_COUNTS,
        epochs=3000,  # DP3's
        min_steps=0,
        max_steps=None,
        batch_size=128,
        eval_episodes=100,
        eval_batch_size=50,
        n_points=1024,
        policy_args=("--policy.down_dims=[512,1024,2048]",),  # DP3's U-Net
    ),
}


DEMO_SCALE = Scale(
    name="demo",
    demos=20,
    fewshot_counts=(),
    epochs=32,
    min_steps=1,
    max_steps=None,
    batch_size=32,
    eval_episodes=20,
    eval_batch_size=10,
    n_points=256,
    policy_args=SCALES["small"].policy_args,
)
"""What `make demo` trains and evaluates. Single-hand policies on press_button in their demos' region
(benchmarks/bench_learnability.py) reach 90 % within 30 epochs, but for `galr` Inspire, 84 % at 30 and
94 % at 100. Co-trained on the three hands' demos, 40 epochs gave 20 of 20 per hand in 10 min 38 s of
`make demo` on 2 idle cores (7.5 min of it training); 32 epochs keep it within 10 minutes."""


def get_scale(name: str) -> Scale:
    if name not in SCALES:
        raise ValueError(f"unknown scale '{name}'; valid scales: {', '.join(SCALES)}")
    return SCALES[name]


def fixed_epochs(name: str, demos: int, epochs: int, episodes: int) -> Scale:
    """The `small` scale's policy and evaluation, trained for exactly `epochs` passes over `demos` demos per
    embodiment and evaluated on `episodes` episodes (the benchmarks that measure training length)."""
    small = SCALES["small"]
    return Scale(
        name=name,
        demos=demos,
        fewshot_counts=(),
        epochs=epochs,
        min_steps=1,
        max_steps=None,
        batch_size=small.batch_size,
        eval_episodes=episodes,
        eval_batch_size=small.eval_batch_size,
        n_points=small.n_points,
        policy_args=small.policy_args,
    )
