"""How big an experiment runs: demonstrations, training steps, policy size and evaluation episodes.

`paper` uses the paper's counts (72 demonstrations per embodiment, DP3-sized training); `small` is sized to
finish each experiment on a 2-core CPU machine within two hours; `toy` exists for the tests.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Scale:
    name: str
    demos: int
    """Demonstrations per embodiment (the paper's 72)."""
    fewshot_counts: tuple[int, ...]
    """Demonstrations of the new embodiment in the few-shot experiment."""
    steps: int
    batch_size: int
    eval_episodes: int
    """Episodes per evaluated (condition, embodiment) cell."""
    eval_batch_size: int
    n_points: int
    policy_args: tuple[str, ...]
    """Extra `lerobot-train` flags that size the policy."""
    episode_length: int | None = None
    """Steps per evaluation episode; None: the task's default."""

    def train_args(self) -> list[str]:
        warmup = min(500, self.steps // 10)
        return [
            f"--steps={self.steps}",
            f"--batch_size={self.batch_size}",
            f"--policy.scheduler_warmup_steps={warmup}",
            f"--policy.scheduler_decay_steps={self.steps}",
            *self.policy_args,
        ]


PAPER_FEWSHOT_COUNTS = (1, 2, 4, 8, 12, 18, 36)

SCALES = {
    "toy": Scale(
        name="toy",
        demos=2,
        fewshot_counts=(1, 2),
        steps=2,
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
        steps=1000,
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
        steps=30_000,
        batch_size=128,
        eval_episodes=100,
        eval_batch_size=50,
        n_points=1024,
        policy_args=("--policy.down_dims=[512,1024,2048]",),  # DP3's U-Net
    ),
}


DEMO_SCALE = Scale(
    name="demo",
    demos=12,
    fewshot_counts=(),
    steps=200,
    batch_size=32,
    eval_episodes=10,
    eval_batch_size=10,
    n_points=256,
    policy_args=SCALES["small"].policy_args,
)
"""What `make demo` trains and evaluates: the whole pipeline in minutes, not a benchmark."""


def get_scale(name: str) -> Scale:
    if name not in SCALES:
        raise ValueError(f"unknown scale '{name}'; valid scales: {', '.join(SCALES)}")
    return SCALES[name]
