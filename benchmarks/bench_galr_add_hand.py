"""Adding a vendor hand to a trained GaLR (`galr pretrain --init`): the new hand's accuracy and the old
hands' before and after, and the CPU time it took, in one run.

The hand is the Shadow MJCF that gymnasium-robotics ships, read with tests/data/user_shadow_mjcf/spec.yaml
(the package is in the [test] extra).

    .venv/bin/python benchmarks/bench_galr_add_hand.py [--init long] [--steps 1100]

Writes benchmarks/results/galr_add_hand.json and galr_add_hand.png.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = Path(__file__).parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def shadow_spec(folder: Path) -> Path:
    """The gymnasium-robotics Shadow hand with its meshes, the wrapper beside it, and its spec."""
    found = importlib.util.find_spec("gymnasium_robotics")
    if found is None:
        sys.exit("gymnasium-robotics is not installed: pip install -e '.[test]'")
    assets = Path(found.submodule_search_locations[0]) / "envs" / "assets"
    shutil.copytree(assets / "hand", folder / "assets" / "hand")
    shutil.copytree(assets / "stls" / "hand", folder / "assets" / "stls" / "hand")
    shutil.copy(ROOT / "tests" / "data" / "user_shadow_mjcf" / "shadow_hand.xml", folder / "assets" / "hand")
    spec = folder / "spec.yaml"
    text = (ROOT / "tests" / "data" / "user_shadow_mjcf" / "spec.yaml").read_text()
    spec.write_text(text.replace("MODEL_PATH", str(folder / "assets" / "hand" / "shadow_hand.xml")))
    return spec


def cli(*args: str) -> float:
    """Runs `lerobot-opfa ARGS`; returns the CPU seconds (user + system) it used."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([str(Path(sys.executable).parent / "lerobot-opfa"), *args], check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--init", default="long")
    parser.add_argument("--steps", type=int, default=1100)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--states", type=int, default=256)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        spec = shadow_spec(work / "shadow")
        before, after, run = work / "before.json", work / "after.json", work / "galr"
        cli("galr", "eval", "--checkpoint", args.init, "--states", str(args.states), "--json", str(before))
        command = ["galr", "pretrain", "--init", args.init, "--hands", f"+{spec}", "--steps", str(args.steps),
                   "--lr", str(args.lr), "--validate-every", str(args.steps),
                   "--save-every", str(args.steps), "--output-dir", str(run)]  # fmt: skip
        cpu_s = cli(*command)
        cli("galr", "eval", "--checkpoint", str(run), "--states", str(args.states), "--json", str(after))
        old, new = json.loads(before.read_text())["hands"], json.loads(after.read_text())["hands"]
        shown = (
            " ".join(command).replace(str(spec), "shadow/spec.yaml").replace(str(run), "outputs/galr_shadow")
        )

    name = "gym_shadow"
    hands = {
        hand: {
            "joint_rmse_deg_before": old[hand]["joint_rmse_deg"],
            "joint_rmse_deg_after": new[hand]["joint_rmse_deg"],
            "ratio": new[hand]["joint_rmse_deg"] / old[hand]["joint_rmse_deg"],
            "fingertip_error_mm_before": old[hand]["fingertip_error_mm"],
            "fingertip_error_mm_after": new[hand]["fingertip_error_mm"],
        }
        for hand in old
    }
    report = {
        "benchmark": "add a vendor hand to a trained GaLR",
        "command": f"lerobot-opfa {shown}",
        "init": args.init,
        "new_hand": name,
        "new_hand_joint_rmse_deg": new[name]["joint_rmse_deg"],
        "new_hand_fingertip_error_mm": new[name]["fingertip_error_mm"],
        "cpu_minutes": cpu_s / 60,
        "worst_old_hand_ratio": max(h["ratio"] for h in hands.values()),
        "states_per_hand": args.states,
        "hands": hands,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "galr_add_hand.json").write_text(json.dumps(report, indent=2))

    names = list(hands) + [name]
    figure, axis = plt.subplots(figsize=(10, 4))
    x = range(len(names))
    axis.bar([i - 0.2 for i in x], [hands[h]["joint_rmse_deg_before"] if h in hands else 0 for h in names],
             0.4, label=f"{args.init}")  # fmt: skip
    axis.bar([i + 0.2 for i in x], [new[h]["joint_rmse_deg"] for h in names], 0.4,
             label=f"{args.init} + {name}, {cpu_s / 60:.1f} CPU min")  # fmt: skip
    axis.set_xticks(list(x), names, rotation=30, ha="right")
    axis.set_ylabel("joint RMSE (deg), held-out states")
    axis.set_title("Adding the gymnasium-robotics Shadow hand to a trained GaLR")
    axis.legend()
    figure.tight_layout()
    figure.savefig(RESULTS / "galr_add_hand.png", dpi=120)
    print(json.dumps({k: v for k, v in report.items() if k != "hands"}, indent=2))


if __name__ == "__main__":
    main()
