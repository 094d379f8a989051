"""How a left hand should enter the GaLR encoder: as the right-hand model of its hand at its joints (the
mirror image of its cloud, which is what the policy's joint maps do), or as its own cloud, the mirror image
of the right hand's, which the encoder never saw in pretraining.

For each built-in hand, held-out joint states (the seeds `galr evaluate` uses) are encoded from the right
hand's cloud and from that cloud mirrored across the hand frame's x = 0 plane (the thumb moves from -x to
+x: a left hand), then decoded into the hand's joints. The right cloud's error is the left hand's under
the joint-map route, by construction; the mirrored cloud's is what feeding the left geometry would cost.

    .venv/bin/python benchmarks/bench_left_hands.py [--checkpoint default] [--states 256]

Writes benchmarks/results/left_hands.json and left_hands.png.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from lerobot_opfa.galr.evaluate import held_out_joints  # noqa: E402
from lerobot_opfa.galr.frozen import load_galr  # noqa: E402
from lerobot_opfa.galr.model import Galr, joint_scale  # noqa: E402

RESULTS = Path(__file__).parents[1] / "benchmarks" / "results"
MIRROR = torch.tensor([-1.0, 1.0, 1.0])
"""The hand frame's x (the thumb's side) reversed: a right hand's cloud becomes a left hand's."""


@torch.no_grad()
def round_trip_deg(galr: Galr, hand: str, q: torch.Tensor, mirrored: bool, chunk: int = 64) -> float:
    """Joint RMSE (degrees; prismatic joints in the GaLR's loss units) of decode(encode(cloud))."""
    model, _ = galr.hand(hand)
    z = []
    for part in q.split(chunk):
        points, *rest = galr.cloud_inputs(hand, part)
        z.append(galr(points * MIRROR.to(points) if mirrored else points, *rest))
    error = (galr.decode(torch.cat(z), hand) - q) * joint_scale(model)
    return math.degrees(error.square().mean().sqrt().item())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", default="default")
    parser.add_argument("--states", type=int, default=256)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    galr = load_galr(args.checkpoint)
    rows = []
    for hand in galr.config.hand_names:
        q = held_out_joints(galr, hand, args.states, args.seed)
        right = round_trip_deg(galr, hand, q, mirrored=False)
        mirrored = round_trip_deg(galr, hand, q, mirrored=True)
        rows.append({"hand": hand, "right_cloud_rmse_deg": right, "mirrored_cloud_rmse_deg": mirrored})
        print(f"{hand:>16}: right cloud {right:6.2f} deg, mirrored cloud {mirrored:6.2f} deg", flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout
    report = {
        "checkpoint": args.checkpoint,
        "states_per_hand": args.states,
        "seed": args.seed,
        "commit": commit.strip(),
        "hands": rows,
        "mean_right_cloud_rmse_deg": float(np.mean([r["right_cloud_rmse_deg"] for r in rows])),
        "mean_mirrored_cloud_rmse_deg": float(np.mean([r["mirrored_cloud_rmse_deg"] for r in rows])),
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "left_hands.json").write_text(json.dumps(report, indent=2) + "\n")
    figure, axis = plt.subplots(figsize=(9, 3.6))
    x = np.arange(len(rows))
    axis.bar(x - 0.2, [r["right_cloud_rmse_deg"] for r in rows], 0.4, label="left hand as the right model")
    axis.bar(
        x + 0.2, [r["mirrored_cloud_rmse_deg"] for r in rows], 0.4, label="left hand's own (mirrored) cloud"
    )
    axis.set_xticks(x, [r["hand"] for r in rows], rotation=30, ha="right")
    axis.set_ylabel("joint RMSE after the round trip (deg)")
    axis.set_title(
        f"GaLR '{args.checkpoint}': how a left hand enters the encoder ({args.states} states/hand)"
    )
    axis.legend()
    figure.tight_layout()
    figure.savefig(RESULTS / "left_hands.png", dpi=120)
    print(f"wrote {RESULTS / 'left_hands.json'} and left_hands.png")


if __name__ == "__main__":
    main()
