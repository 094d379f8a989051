"""An arm's inverse kinematics per action chunk, next to the policy's own time per chunk, in the same run.

    HF_HUB_OFFLINE=1 .venv/bin/python benchmarks/bench_ik.py [--chunks 200] [--threads 1]

For each arm example-robot-data ships that the tests use (UR5, Franka Panda): `--chunks` chunks of
`n_action_steps` (8) flange poses, each a trajectory from a random start near the arm's working pose that
moves every joint up to 0.02 rad a step (a wrist at 20 Hz), solved with `arms.ik.solve_chunk` from the
start's joints; errors at the 95th percentile over every pose. The baseline: `select_action` per chunk of a
batch-1 rollout of the `opfa` policy at its default sizes (bench_policy.py's data and timing: synthetic
umi / Inspire / LEAP demos merged with a GaLR of the default architecture). Writes
benchmarks/results/ik.json and ik.png.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from bench_policy import MATCHED, build, build_data, observation, rollout_chunk_ms  # noqa: E402
from test_arm_ik import ARMS, arm  # noqa: E402

from lerobot_opfa.arms.ik import pose_error, solve_chunk  # noqa: E402
from lerobot_opfa.policy.configuration_opfa import OpfaConfig  # noqa: E402

RESULTS = Path(__file__).parent / "results"
STEP = 0.02
"""rad: the most a joint moves a step in the benchmark's trajectories."""


def ik_run(name: str, chunks: int, poses: int, seed: int = 0) -> dict:
    """The arm `name`'s IK over `chunks` random chunks: ms per chunk (median), p95 errors (mm, deg)."""
    chain, generator = arm(name), torch.Generator().manual_seed(seed)
    working = torch.tensor(ARMS[name][2], dtype=torch.float64)
    times, mm, deg = [], [], []
    for _ in range(chunks + 2):
        start = working + 0.3 * (2 * torch.rand(len(working), generator=generator, dtype=torch.float64) - 1)
        start = start.clamp(chain.lower, chain.upper)
        velocity = STEP * (2 * torch.rand(len(working), generator=generator, dtype=torch.float64) - 1)
        trajectory = (start + torch.arange(1, poses + 1, dtype=torch.float64)[:, None] * velocity).clamp(
            chain.lower, chain.upper
        )
        targets = chain.flange_pose(trajectory)
        began = time.perf_counter()
        q, _ = solve_chunk(chain, targets, start)
        times.append(1000 * (time.perf_counter() - began))
        error = pose_error(chain.flange_pose(q), targets)
        mm.append(1000 * error[:, :3].norm(dim=-1))
        deg.append(torch.rad2deg(error[:, 3:].norm(dim=-1)))
    mm, deg = torch.cat(mm[2:]), torch.cat(deg[2:])
    return {
        "arm": name,
        "poses_per_chunk": poses,
        "ik_ms_per_chunk": statistics.median(times[2:]),
        "p95_mm": float(mm.quantile(0.95)),
        "p95_deg": float(deg.quantile(0.95)),
    }


def select_action_ms_per_chunk(chunks: int) -> float:
    """`select_action` per chunk of a batch-1 rollout of the default-size `opfa` policy."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        galr_path = build_data(root, None, 512)
        policy, pre, _, dataset = build(OpfaConfig(galr_path=galr_path, **MATCHED), root, "merged")
        policy.eval()
        _, select = rollout_chunk_ms(policy, pre, observation(dataset, "leap", False), chunks)
    return select


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chunks", type=int, default=200)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    poses = MATCHED["n_action_steps"]
    select = select_action_ms_per_chunk(min(args.chunks, 20))
    runs = [
        {**ik_run(name, args.chunks, poses), "select_action_ms_per_chunk": select} for name in sorted(ARMS)
    ]
    for run in runs:
        print({k: round(v, 3) if isinstance(v, float) else v for k, v in run.items()})
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=30).stdout
    result = {
        "benchmark": "ik",
        "command": "HF_HUB_OFFLINE=1 .venv/bin/python benchmarks/bench_ik.py " + " ".join(sys.argv[1:]),
        "commit": commit.strip(),
        "settings": {
            "chunks": args.chunks,
            "torch_threads": torch.get_num_threads(),
            "trajectory_step_rad": STEP,
            "solver": "arms.ik.solve_chunk: damped least squares, 8 iterations, from the current joints",
            "policy": "opfa, default sizes (horizon 16, 2 observation steps, 8 action steps, 10 DDIM steps)",
        },
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "torch": torch.__version__,
            "load_average_1_5_15_min": os.getloadavg(),
        },
        "runs": runs,
        "ik_vs_select_action_per_chunk": {r["arm"]: r["ik_ms_per_chunk"] / select for r in runs},
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "ik.json").write_text(json.dumps(result, indent=2))
    plot(runs, RESULTS / "ik.png")
    print(f"wrote {RESULTS / 'ik.json'} and ik.png")


def plot(runs: list[dict], out: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 3.6))
    ax = fig.subplots()
    y = range(len(runs))
    ax.barh([i + 0.2 for i in y], [r["select_action_ms_per_chunk"] for r in runs], 0.4, label="select_action")
    ax.barh([i - 0.2 for i in y], [r["ik_ms_per_chunk"] for r in runs], 0.4, label="IK (8 poses)")
    ax.set_yticks(list(y), [f"{r['arm']}\np95 {r['p95_mm']:.3f} mm, {r['p95_deg']:.3f} deg" for r in runs])
    ax.set_xlabel("ms per action chunk (1 CPU thread)")
    ax.set_title("IK back to the arm's joints, per chunk, beside the policy's sampling")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main()
