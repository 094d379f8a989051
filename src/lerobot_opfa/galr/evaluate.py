"""How well GaLR round-trips each hand: joint RMSE, fingertip error (FK of decoded vs true joints),
throughput, and pictures (per-hand bars, original vs decoded clouds)."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure

from lerobot_opfa.galr.model import PRISMATIC_SCALE, Galr, joint_scale
from lerobot_opfa.hands.plot import plot_clouds


def held_out_joints(galr: Galr, hand: str, n: int, seed: int) -> torch.Tensor:
    """States no training or validation batch draws (their generators use other seeds)."""
    return galr.hand(hand)[0].sample_joints(n, torch.Generator().manual_seed(20_000 + seed))


@torch.no_grad()
def evaluate_hand(galr: Galr, hand: str, q: torch.Tensor, chunk: int = 128) -> dict:
    model, _ = galr.hand(hand)
    q = q.to(galr.device)
    start = time.perf_counter()
    z = torch.cat([galr.encode_joints(hand, part) for part in q.split(chunk)])
    encode_s = time.perf_counter() - start
    start = time.perf_counter()
    decoded = galr.decode(z, hand)
    decode_s = time.perf_counter() - start
    scale = joint_scale(model).to(q.device)
    error = decoded - q
    prismatic = model.prismatic_mask.to(q.device)
    tips = (model.fingertip_positions(decoded) - model.fingertip_positions(q)).norm(dim=-1)
    result = {
        "dof": model.dof,
        "joint_rmse_deg": math.degrees((error * scale).square().mean().sqrt().item()),
        "fingertip_error_mm": 1000 * tips.mean().item(),
        "encode_clouds_per_s": len(q) / encode_s,
        "decode_per_s": len(q) / decode_s,
        "worst_joint": model.joint_names[int(error.abs().mean(0).argmax())],
    }
    if (~prismatic).any():
        result["revolute_rmse_deg"] = math.degrees(error[:, ~prismatic].square().mean().sqrt().item())
    if prismatic.any():
        result["prismatic_rmse_mm"] = 1000 * error[:, prismatic].square().mean().sqrt().item()
    return result


def evaluate(galr: Galr, hands: list[str], states: int, seed: int, out: Path | None = None) -> dict:
    per_hand = {hand: evaluate_hand(galr, hand, held_out_joints(galr, hand, states, seed)) for hand in hands}
    keys = ("joint_rmse_deg", "fingertip_error_mm", "encode_clouds_per_s", "decode_per_s")
    report = {
        "states_per_hand": states,
        "seed": seed,
        "units": f"joint_rmse_deg counts prismatic joints as {PRISMATIC_SCALE:g} rad per metre "
        "(1 mm = 1.15 deg); revolute_rmse_deg and prismatic_rmse_mm separate them",
        "config": {k: v for k, v in vars(galr.config).items() if k != "hands"},
        "hands": per_hand,
        "mean": {k: float(np.mean([h[k] for h in per_hand.values()])) for k in keys},
    }
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(report, indent=2))
    return report


def plot_errors(report: dict, out: Path) -> Path:
    hands = list(report["hands"])
    fig = Figure(figsize=(12, 4))
    axes = fig.subplots(1, 2)
    for ax, key, label in zip(
        axes,
        ("joint_rmse_deg", "fingertip_error_mm"),
        ("joint RMSE (deg)", "fingertip error (mm)"),
        strict=True,
    ):
        values = [report["hands"][h][key] for h in hands]
        ax.bar(hands, values, color="#1f77b4")
        ax.axhline(report["mean"][key], color="k", ls="--", lw=1, label=f"mean {report['mean'][key]:.2f}")
        ax.set_ylabel(label)
        ax.tick_params(axis="x", rotation=60, labelsize=8)
        ax.legend()
    fig.suptitle(f"GaLR round trip on {report['states_per_hand']} held-out states per hand")
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return Path(out)


@torch.no_grad()
def plot_reconstructions(galr: Galr, hands: list[str], out: Path, seed: int = 0, n_hands: int = 4) -> Path:
    """Original vs decoded clouds (FK of the decoded joints) of one held-out state of a few hands."""
    clouds = {}
    for hand in hands[:n_hands]:
        model, _ = galr.hand(hand)
        q = held_out_joints(galr, hand, 1, seed).to(galr.device)
        decoded = galr.decode(galr.encode_joints(hand, q), hand)
        for name, joints in (("original", q), ("decoded", decoded)):
            cloud = model.point_cloud(joints, galr.config.n_points, seed=galr.config.sample_seed)
            clouds[f"{hand} {name}"] = (cloud.points[0].cpu().numpy(), cloud.labels[0].cpu().numpy())
    return plot_clouds(
        clouds, out, title="GaLR: original (FK of true joints) vs decoded (FK of decoded joints)"
    )


def plot_training_curves(runs: dict[str, Path], out: Path) -> Path:
    """Validation RMSE against wall-clock training time for each run's `metrics.jsonl`."""
    fig = Figure(figsize=(7, 4.5))
    ax = fig.subplots()
    for label, run in runs.items():
        metrics = Path(run) / "metrics.jsonl"
        if not metrics.is_file():
            raise ValueError(f"{run}: no metrics.jsonl (not a `galr pretrain` output folder)")
        rows = [json.loads(line) for line in metrics.read_text().splitlines()]
        rows = [r for r in rows if "val/rmse_deg_mean" in r]
        if not rows:
            raise ValueError(f"{metrics} has no validation rows yet (they come every --validate-every steps)")
        ax.plot([r["elapsed_s"] / 60 for r in rows], [r["val/rmse_deg_mean"] for r in rows], marker="o", ms=3,
                label=f"{label} (final {rows[-1]['val/rmse_deg_mean']:.2f} deg)")  # fmt: skip
    ax.set(xlabel="training time (min)", ylabel="validation joint RMSE, mean over hands (deg)", yscale="log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return Path(out)
