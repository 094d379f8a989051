"""Train the `opfa` policy on three hands at once, end to end on the CPU with LeRobot's own CLI.

    .venv/bin/python examples/train_opfa_synthetic.py [--galr checkpoints/galr_default] [--steps 200]

Synthetic per-hand datasets (a gripper, a 6-DoF and a 16-DoF hand) stand in for demonstrations; swap in
`lerobot-opfa sim demos` datasets or your own. Prints the checkpoint, ready for `lerobot-eval`.
"""

import argparse
import os
import subprocess
import sys
from pathlib import Path

from lerobot_opfa.datasets.merge import merge_datasets
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--galr", default="checkpoints/galr_default")
parser.add_argument("--steps", type=int, default=200)
parser.add_argument("--out", type=Path, default=Path("outputs/example_opfa"))
args = parser.parse_args()

hands = ["umi", "inspire", "leap"]
for seed, hand in enumerate(hands):
    if not (args.out / hand).exists():
        write_synthetic_dataset(args.out / hand, hand, episodes=4, frames=40, n_points=256, seed=seed)
merged = args.out / "merged"
if not merged.exists():
    merge_datasets([args.out / h for h in hands], merged, galr_path=args.galr)

train = args.out / "train"
subprocess.run(
    [
        str(Path(sys.executable).parent / "lerobot-train"),
        "--policy.type=opfa",
        f"--policy.galr_path={args.galr}",
        "--dataset.repo_id=local/merged",
        f"--dataset.root={merged}",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        f"--steps={args.steps}",
        "--batch_size=16",
        f"--output_dir={train}",
    ],
    env={**os.environ, "HF_HUB_OFFLINE": "1"},
    check=True,
)
checkpoint = train / "checkpoints" / "last" / "pretrained_model"
print(f"checkpoint: {checkpoint}")
print(f"next: lerobot-eval --policy.path={checkpoint} --env.type=opfa --env.hand=leap --env.n_points=256")
