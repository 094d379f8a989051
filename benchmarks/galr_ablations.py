"""GaLR ablations at an equal step budget: the default (KPConv + geometric transformer, linear semantic
embedding added to the superpoint features, unified decoder) against the semantic embedding in the
attention only, no semantic embedding, DP3's PointNet encoder, and per-embodiment decoders. Each is
pretrained with the same CLI (equal batch shares, as the first ablation runs had) and evaluated with
`galr eval`.

    .venv/bin/python benchmarks/galr_ablations.py [--steps 600] [--output-dir outputs/galr_ablations]

Writes benchmarks/results/galr_ablations.json and galr_ablations.png; finished runs are not redone.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

RESULTS = Path(__file__).parent / "results"
VARIANTS = {  # name: (run directory, --model overrides)
    "default": ("default", []),
    "semantic embedding in attention": ("semantic_attention", ["semantic_target=attention"]),
    "no semantic embedding": ("no_semantic", ["semantic_embedding=none"]),
    "PointNet encoder (DP3)": ("pointnet", ["encoder=pointnet"]),
    "per-embodiment decoders, semantic embedding in attention": (
        "per_embodiment_attention",
        ["decoder=per_embodiment", "semantic_target=attention"],
    ),
}


def _cli(*args: str) -> None:
    subprocess.run([str(Path(sys.executable).parent / "lerobot-opfa"), *args], check=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--batch-size", type=int, default=44)
    parser.add_argument("--states", type=int, default=128, help="held-out states per hand in the evaluation")
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/galr_ablations"))
    args = parser.parse_args()

    rows = {}
    for name, (directory, overrides) in VARIANTS.items():
        run = args.output_dir / directory
        report = run / "eval.json"
        if not (run / "model.safetensors").is_file():
            resume = ["--resume"] if (run / "checkpoints").is_dir() else []
            _cli("galr", "pretrain", "--hands", "all", "--steps", str(args.steps), "--batch-size",
                 str(args.batch_size), "--shares", "even", "--validate-every", str(args.steps),
                 "--output-dir", str(run), *resume,
                 *(["--model", *overrides] if overrides else []))  # fmt: skip
        if not report.is_file():
            _cli(
                "galr", "eval", "--checkpoint", str(run), "--states", str(args.states), "--json", str(report)
            )
        result = json.loads(report.read_text())
        metrics = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
        per_hand = {h: m["joint_rmse_deg"] for h, m in result["hands"].items()}
        rows[name] = {"overrides": overrides, "minutes": metrics[-1]["elapsed_s"] / 60, **result["mean"],
                      "per_hand_rmse_deg": per_hand}  # fmt: skip
        rmse, tip = rows[name]["joint_rmse_deg"], rows[name]["fingertip_error_mm"]
        print(f"{name:<26} RMSE {rmse:6.2f} deg  tip {tip:6.2f} mm")

    command = f"python benchmarks/galr_ablations.py --steps {args.steps} --batch-size {args.batch_size}"
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "galr_ablations.json").write_text(
        json.dumps(
            {"command": command, "steps": args.steps, "batch_size": args.batch_size, "runs": rows}, indent=2
        )
    )
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, key, label in zip(axes, ("joint_rmse_deg", "fingertip_error_mm"),
                              ("joint RMSE (deg)", "fingertip error (mm)"), strict=True):  # fmt: skip
        ax.bar([textwrap.fill(n, 16) for n in rows], [r[key] for r in rows.values()], color="#1f77b4")
        ax.tick_params(axis="x", labelsize=7)
        ax.set_ylabel(f"{label}, mean over 11 hands")
    fig.suptitle(f"GaLR ablations, {args.steps} steps x batch {args.batch_size} each, CPU")
    fig.tight_layout()
    fig.savefig(RESULTS / "galr_ablations.png", dpi=110)


if __name__ == "__main__":
    main()
