"""A vendor's hand in minutes: from the model file as its package ships it to recorded demos and to a GaLR
that knows the hand.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_vendor_hands.py \
        [--out outputs/bench_vendor_hands]

Five vendor models, each read through a spec that names its actuated joints (and, where the model holds more
than the hand, its root link or the links that are not the hand), with no `links` table: example-robot-data's
Allegro URDF, gymnasium-robotics' Shadow MJCF, dexi-rs' Fourier 6-DoF URDF and the ORCA hand in orca_arm's
bimanual robot URDF (all in the [test] extra), and the Shadow URDF in the genesis-world wheel (fetched with
`pip download --no-deps`, not installed). Per hand: the spec's lines,
`hands check` (its warnings), `sim demos` of `press_button` and `lift` (20 episodes each, `mid_center`:
successes of attempts and wall minutes), and `galr pretrain --init default --hands +SPEC` (1100 steps, as
bench_galr_add_hand.py) with the new hand's joint RMSE. Every step is skipped when its output exists.
Results: benchmarks/results/vendor_hands.{json,png}.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import subprocess
import sys
import sysconfig
import time
import zipfile
from pathlib import Path

from lerobot_opfa.experiments.jobs import source_commit

ROOT = Path(__file__).parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "vendor_hands.json"
BIN = Path(sys.executable).parent
GENESIS = "genesis-world==1.4.5"
TASKS = ("press_button", "lift")
EPISODES, GALR_STEPS = 20, 1100

GENESIS_SHADOW_SPEC = """\
# The Shadow hand URDF in the genesis-world wheel (genesis/assets/urdf/shadow_hand), as it ships.
name: genesis_shadow
kind: hand
model: shadow_hand.urdf
description: Shadow hand URDF shipped in the genesis-world wheel
base: {xyz: [0.0052, -0.0099, 0.2359], rpy: [0.0, 0.0, 3.1415926536]}
fixed: {forearm_joint: 0.0, wrist_joint: 0.0}
joints:
  thumb_joint1: thumb_cmc_yaw
  thumb_joint2: thumb_cmc_abd
  thumb_joint3: thumb_cmc_roll
  thumb_joint4: thumb_mcp_flex
  thumb_joint5: thumb_ip_flex
  index_finger_joint1: index_mcp_abd
  index_finger_joint2: index_mcp_flex
  index_finger_joint3: index_pip_flex
  middle_finger_joint1: middle_mcp_abd
  middle_finger_joint2: middle_mcp_flex
  middle_finger_joint3: middle_pip_flex
  ring_finger_joint1: ring_mcp_abd
  ring_finger_joint2: ring_mcp_flex
  ring_finger_joint3: ring_pip_flex
  little_finger_joint1: little_cmc_flex
  little_finger_joint2: little_mcp_abd
  little_finger_joint3: little_mcp_flex
  little_finger_joint4: little_pip_flex
couplings:
  index_finger_joint4: {source: index_finger_joint3}
  middle_finger_joint4: {source: middle_finger_joint3}
  ring_finger_joint4: {source: ring_finger_joint3}
  little_finger_joint5: {source: little_finger_joint4}
links: {forearm: null, wrist: null}
poses:
  open: {}
  grasp: {thumb_joint1: 0.9, thumb_joint2: 1.1, thumb_joint4: 0.2, thumb_joint5: 0.3,
          index_finger_joint2: 0.9, index_finger_joint3: 0.9,
          middle_finger_joint2: 0.9, middle_finger_joint3: 0.9,
          ring_finger_joint2: 0.9, ring_finger_joint3: 0.9,
          little_finger_joint3: 0.9, little_finger_joint4: 0.9}
"""


def without_link_labels(text: str) -> str:
    """A spec with its `links` table cut to the links that are not the hand (`null`), or gone."""
    out, table, kept = [], False, []
    for line in text.splitlines():
        if line.startswith("links:"):
            table = True
        elif table and line.startswith("  "):
            kept += [line] if line.rstrip().endswith("null") else []
        else:
            out += (["links:", *kept] if table and kept else []) + [line]
            table = False
    return "\n".join(out) + "\n"


def spec_from_test_data(folder: Path, name: str, model: Path) -> Path:
    """tests/data/NAME/spec.yaml with `model` filled in and no finger labels, written to `folder`."""
    text = (ROOT / "tests" / "data" / name / "spec.yaml").read_text().replace("MODEL_PATH", str(model))
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "spec.yaml").write_text(without_link_labels(text))
    return folder / "spec.yaml"


def package_folder(module: str) -> Path:
    return Path(importlib.util.find_spec(module).submodule_search_locations[0])


def erd_allegro(folder: Path) -> Path:
    share = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data"
    urdf = share / "robots" / "allegro_hand_description" / "urdf" / "allegro_right_hand.urdf"
    return spec_from_test_data(folder, "user_allegro", urdf)


def gym_shadow(folder: Path) -> Path:
    assets = package_folder("gymnasium_robotics") / "envs" / "assets"
    shutil.copytree(assets / "hand", folder / "assets" / "hand", dirs_exist_ok=True)
    shutil.copytree(assets / "stls" / "hand", folder / "assets" / "stls" / "hand", dirs_exist_ok=True)
    shutil.copy(ROOT / "tests" / "data" / "user_shadow_mjcf" / "shadow_hand.xml", folder / "assets" / "hand")
    text = (ROOT / "tests" / "data" / "user_shadow_mjcf" / "spec.yaml").read_text()
    (folder / "spec.yaml").write_text(
        without_link_labels(text.replace("MODEL_PATH", str(folder / "assets" / "hand" / "shadow_hand.xml")))
    )
    return folder / "spec.yaml"


def genesis_shadow(folder: Path) -> Path:
    model = folder / "genesis" / "assets" / "urdf" / "shadow_hand"
    if not model.exists():
        wheels = folder / "wheel"
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--no-deps", "-d", wheels, GENESIS], check=True
        )
        with zipfile.ZipFile(next(wheels.glob("genesis_world-*.whl"))) as wheel:
            wheel.extractall(
                folder, [n for n in wheel.namelist() if n.startswith("genesis/assets/urdf/shadow_hand/")]
            )
    (model / "spec.yaml").write_text(GENESIS_SHADOW_SPEC)
    return model / "spec.yaml"


def dexi_fourier(folder: Path) -> Path:
    hands = package_folder("dexi_rs") / "resources" / "assets" / "robots" / "hands"
    return spec_from_test_data(
        folder, "user_fourier", hands / "fourier_hand" / "base_urdf" / "fourier_right_hand_6dof.urdf"
    )


def orca_right(folder: Path) -> Path:
    return spec_from_test_data(folder, "user_orca", package_folder("orca_arm") / "orcabot.urdf")


HANDS = {
    "erd_allegro": erd_allegro,
    "gym_shadow": gym_shadow,
    "genesis_shadow": genesis_shadow,
    "dexi_fourier": dexi_fourier,
    "orca_right": orca_right,
}


def timed(command: list, log: Path) -> float:
    start = time.monotonic()
    with log.open("w") as out:
        subprocess.run([str(c) for c in command], stdout=out, stderr=subprocess.STDOUT, check=True)
    return time.monotonic() - start


def spec_lines(spec: Path) -> int:
    return sum(
        1 for line in spec.read_text().splitlines() if line.strip() and not line.lstrip().startswith("#")
    )


def measure(out: Path, name: str) -> dict:
    folder = out / name
    done = folder / "result.json"
    if done.exists():
        return json.loads(done.read_text())
    spec = HANDS[name](folder)
    check = subprocess.run([BIN / "lerobot-opfa", "hands", "check", spec], capture_output=True, text=True)
    warnings = [
        line.strip() for line in (check.stdout + check.stderr).splitlines() if "warning" in line.lower()
    ]
    result = {
        "hand": name,
        "spec_lines": spec_lines(spec),
        "check_exit": check.returncode,
        "warnings": warnings,
    }
    for task in TASKS:
        demos = folder / f"demos_{task}"
        shutil.rmtree(demos, ignore_errors=True)
        seconds = timed([BIN / "lerobot-opfa", "sim", "demos", "--task", task, "--hand", spec,
                         "--regions", "mid_center", "--episodes", EPISODES, "--pointcloud-source", "geometry",
                         "--n-points", 256, "--output-dir", demos], folder / f"demos_{task}.log")  # fmt: skip
        record = json.loads((demos / "meta" / "opfa_demos.json").read_text())
        result[task] = {"successes": len(record["episodes"]), "attempts": record["attempts"],
                        "minutes": round(seconds / 60, 2)}  # fmt: skip
    galr = folder / "galr"
    shutil.rmtree(galr, ignore_errors=True)
    seconds = timed([BIN / "lerobot-opfa", "galr", "pretrain", "--init", "default", "--hands", f"+{spec}",
                     "--steps", GALR_STEPS, "--lr", "3e-4", "--validate-every", GALR_STEPS, "--save-every",
                     GALR_STEPS, "--output-dir", galr], folder / "galr.log")  # fmt: skip
    subprocess.run([BIN / "lerobot-opfa", "galr", "eval", "--checkpoint", galr, "--states", "256", "--json",
                    folder / "galr_eval.json"], check=True, capture_output=True)  # fmt: skip
    evaluated = json.loads((folder / "galr_eval.json").read_text())["hands"][name]  # the spec's name
    result["galr"] = {"minutes": round(seconds / 60, 2), "joint_rmse_deg": evaluated["joint_rmse_deg"],
                      "fingertip_error_mm": evaluated["fingertip_error_mm"]}  # fmt: skip
    result["commit"] = source_commit()
    done.write_text(json.dumps(result, indent=2))
    return result


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6))
    names = [r["hand"] for r in results]
    parts = [("press_button", lambda r: r["press_button"]["minutes"]),
             ("lift", lambda r: r["lift"]["minutes"]),
             ("GaLR +hand", lambda r: r["galr"]["minutes"])]  # fmt: skip
    left = [0.0] * len(results)
    for label, minutes in parts:
        widths = [minutes(r) for r in results]
        ax.barh(names, widths, left=left, label=label)
        left = [a + b for a, b in zip(left, widths, strict=True)]
    for i, r in enumerate(results):
        ax.text(left[i], i, f"  {r['spec_lines']} spec lines", va="center", fontsize=8)
    ax.set_xlabel("wall minutes on 2 CPU cores (demos: 20 episodes each)")
    ax.set_xlim(0, max(left) * 1.35)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_vendor_hands"))
    out = parser.parse_args().out
    results = [measure(out, name) for name in HANDS]
    RESULTS.write_text(json.dumps({"hands": results}, indent=2) + "\n")
    plot(results, RESULTS.with_suffix(".png"))
    for r in results:
        print(r["hand"], r["spec_lines"], r["press_button"], r["lift"], r["galr"])


if __name__ == "__main__":
    main()
