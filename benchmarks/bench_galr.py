"""GaLR encoder and decoder throughput (clouds/s, B = 256, N = 1024) on the CPU next to DP3's PointNet
encoder of similar width, in the same run; parameter counts; peak memory of each forward pass.

    .venv/bin/python benchmarks/bench_galr.py [--checkpoint DIR] [--repeats 3]

Each model runs in its own fresh process, so its peak resident memory (ru_maxrss) is its own.
Writes benchmarks/results/galr.json and galr.png.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import platform
import resource
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

from lerobot_opfa.galr.data import sample_batch  # noqa: E402
from lerobot_opfa.galr.model import Galr, GalrConfig, hand_record  # noqa: E402
from lerobot_opfa.galr.pointnet import PointNetEncoder  # noqa: E402
from lerobot_opfa.hands import builtin_hands, load_hand  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def _galr(checkpoint: str | None) -> Galr:
    if checkpoint:
        return Galr.from_pretrained(checkpoint).eval()
    torch.manual_seed(0)
    return Galr(GalrConfig(hands=[hand_record(load_hand(h)) for h in builtin_hands()])).eval()


def _measure(kind: str, checkpoint: str | None, batch: int, repeats: int, queue: mp.Queue) -> None:
    torch.set_num_threads(torch.get_num_threads())
    galr = _galr(checkpoint)
    inputs = sample_batch(
        galr, galr.config.hand_names, batch, torch.Generator().manual_seed(0), "even"
    ).encoder_inputs()
    if kind == "galr_encoder":
        module, run = galr.encoder, lambda: galr(*inputs)
    elif kind == "galr_decoder":
        z = torch.randn(batch, galr.config.latent_dim)
        module, run = galr.decoder, lambda: galr.decoder(z)
    else:  # DP3's encoder at GaLR's widths, on xyz only, as DP3 uses it
        module = PointNetEncoder(galr.config.latent_dim, galr.config.widths).eval()
        run = lambda: module(inputs[0])  # noqa: E731
    baseline_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with torch.no_grad():
        run()  # warm-up
        start = time.perf_counter()
        for _ in range(repeats):
            run()
        seconds = (time.perf_counter() - start) / repeats
    queue.put({
        "model": kind,
        "parameters": sum(p.numel() for p in module.parameters()),
        "items_per_s": batch / seconds,
        "ms_per_batch": 1000 * seconds,
        "peak_rss_increase_mb": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - baseline_kb) / 1024,
    })  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--checkpoint", help="a GaLR checkpoint (default: a fresh model of the default config)"
    )
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    context = mp.get_context("spawn")
    rows = []
    for kind in ("galr_encoder", "dp3_pointnet_encoder", "galr_decoder"):
        queue = context.Queue()
        process = context.Process(
            target=_measure, args=(kind, args.checkpoint, args.batch, args.repeats, queue)
        )
        process.start()
        rows.append(queue.get())
        process.join()
        r = rows[-1]
        print(f"{kind:<22} {r['parameters']:>9,} params  {r['items_per_s']:8.0f} /s  "
              f"{r['ms_per_batch']:8.1f} ms/batch  peak +{r['peak_rss_increase_mb']:.0f} MB")  # fmt: skip
    encoder, pointnet = rows[0], rows[1]
    config = _galr(args.checkpoint).config
    result = {
        "benchmark": "GaLR encoder/decoder throughput vs DP3 PointNet encoder",
        "command": "python benchmarks/bench_galr.py"
        + (f" --checkpoint {args.checkpoint}" if args.checkpoint else ""),
        "settings": {"batch": args.batch, "n_points": config.n_points, "n_level1": config.n_level1,
                     "n_superpoints": config.n_superpoints, "device": "cpu",
                     "torch_threads": torch.get_num_threads(),
                     "inference": "no_grad, eval mode; clouds made beforehand (see hand_clouds.json)"},
        "machine": {"cpu": platform.processor() or platform.machine(), "python": platform.python_version(),
                    "torch": torch.__version__},
        "models": rows,
        "encoder_slowdown_vs_pointnet": pointnet["items_per_s"] / encoder["items_per_s"],
    }  # fmt: skip
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "galr.json").write_text(json.dumps(result, indent=2))

    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    names = [r["model"].replace("_", "\n") for r in rows]
    keys = ("items_per_s", "parameters", "peak_rss_increase_mb")
    labels = ("per second (log)", "parameters (log)", "peak memory increase (MB)")
    for ax, key, label in zip(axes, keys, labels, strict=True):
        ax.bar(names, [r[key] for r in rows], color=["#1f77b4", "#ff7f0e", "#2ca02c"])
        ax.set_ylabel(label)
        if key != "peak_rss_increase_mb":
            ax.set_yscale("log")
    fig.suptitle(
        f"GaLR vs DP3 PointNet, CPU ({torch.get_num_threads()} threads), B={args.batch}, N={config.n_points}"
    )
    fig.tight_layout()
    fig.savefig(RESULTS / "galr.png", dpi=110)
    slowdown = result["encoder_slowdown_vs_pointnet"]
    print(f"GaLR encoder time / PointNet encoder time: {slowdown:.2f}; wrote {RESULTS}/galr.*")


if __name__ == "__main__":
    main()
