"""Why a policy co-trained on two pairs of hands fails on a pair it never saw: its cloud or its state?

A two-handed policy trained on (Inspire, Inspire) and (XHand, XHand) demos of `lift_tray` meets (Inspire,
XHand): each hand is one it knows, the two together are not, in its point cloud and in its state (body,
then a hand part per slot). A shadow scene of a pair the policy saw is posed as the real one every step
(every joint of the same name copied: the wrists, the tray, the hand joints the two hands share by name),
and its observation is put in place of the real one's, one input at a time:

- cloud: closed loop in the real scene, the policy fed the shadow's point cloud (the real state kept);
  success over `--episodes` seeded episodes, beside the real cloud;
- state: at step `--stall-step` of a closed-loop episode, the wrist travel the policy plans over one action
  chunk (mean over 3 noise seeds) with the real state, and with the shadow's state (named by the shadow's
  hands, so each slot decodes through the hand it reads), the real cloud kept; averaged over all episodes
  and over those stalled there (both wrists still above 15 cm).

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_mixed_pair.py --checkpoint CKPT [--episodes 10]
        [--stall-step 48] [--name mixed_pair]

Writes benchmarks/results/NAME.json and NAME.png.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from lerobot.policies.factory import make_pre_post_processors  # noqa: E402
from lerobot.utils.constants import OBS_STATE  # noqa: E402
from tqdm import tqdm  # noqa: E402

import lerobot_policy_opfa  # noqa: E402, F401  (the plugin, as LeRobot loads it: steps, robot_type)
from lerobot_opfa.envs.env import OpfaSimEnv  # noqa: E402
from lerobot_opfa.experiments.jobs import EVAL_SEED  # noqa: E402
from lerobot_opfa.features import OBS_POINTCLOUD, ROBOT_TYPE  # noqa: E402
from lerobot_opfa.policy.modeling_opfa import OpfaPolicy  # noqa: E402

RESULTS = Path(__file__).parent / "results"
MIXED, SEEN = "inspire+xhand", ("inspire+inspire", "xhand+xhand")
STALLED_CM = 15.0
"""A wrist still this high at the probe has not come down to the handles (7 cm; the arms start at 30 cm)."""
FREE_JOINT_SIZES = {int(mujoco.mjtJoint.mjJNT_FREE): 7, int(mujoco.mjtJoint.mjJNT_BALL): 4}


class Pilot:
    """The policy with its processors, acting from a state, a cloud and the hands they belong to."""

    def __init__(self, checkpoint: str):
        self.policy = OpfaPolicy.from_pretrained(checkpoint).eval()
        self.pre, self.post = make_pre_post_processors(self.policy.config, pretrained_path=checkpoint)

    @torch.no_grad()
    def act(self, state: np.ndarray, hands: str, cloud: np.ndarray) -> np.ndarray:
        observation = {
            OBS_STATE: torch.tensor(state).float(),
            ROBOT_TYPE: hands,
            OBS_POINTCLOUD: torch.tensor(cloud).float(),
        }
        return self.post(self.policy.select_action(self.pre(observation)))[0].numpy()

    def chunk(self, state: np.ndarray, hands: str, cloud: np.ndarray, seed: int) -> np.ndarray:
        """(n_action_steps, A) actions of one chunk sampled afresh from this one observation."""
        self.policy.reset()
        torch.manual_seed(seed)
        return np.stack([self.act(state, hands, cloud) for _ in range(self.policy.config.n_action_steps)])


def scene(hands: str) -> OpfaSimEnv:
    return OpfaSimEnv(
        "lift_tray",
        hands,
        obs_type="pointcloud_state",
        pointcloud_source="geometry",
        n_points=256,
        regions="mid_center",
    )


def pose_like(shadow: OpfaSimEnv, real: OpfaSimEnv) -> dict[str, np.ndarray]:
    """The shadow's observation with every joint that has a namesake in the real scene set as it is there."""
    for j in range(shadow.model.njnt):
        name = mujoco.mj_id2name(shadow.model, mujoco.mjtObj.mjOBJ_JOINT, j)
        k = mujoco.mj_name2id(real.model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if k < 0 or real.model.jnt_type[k] != shadow.model.jnt_type[j]:
            continue
        size = FREE_JOINT_SIZES.get(int(shadow.model.jnt_type[j]), 1)
        to, of = shadow.model.jnt_qposadr[j], real.model.jnt_qposadr[k]
        shadow.data.qpos[to : to + size] = real.data.qpos[of : of + size]
    mujoco.mj_forward(shadow.model, shadow.data)
    return shadow.observation()


def wrists(env: OpfaSimEnv) -> list[int]:
    return [env.state_names.index(f"{side}_wrist_{axis}") for side in ("left", "right") for axis in "xyz"]


def cloud_swap(pilot: Pilot, episodes: int) -> dict[str, int]:
    """Successes on the mixed pair with its own cloud and with each seen pair's shadow cloud."""
    real = scene(MIXED)
    successes = {}
    for source in ("own", *SEEN):
        shadow = scene(source) if source != "own" else None
        wins = 0
        for seed in tqdm(range(EVAL_SEED, EVAL_SEED + episodes), desc=f"cloud of {source}", leave=False):
            obs, _ = real.reset(seed=seed)
            if shadow is not None:
                shadow.reset(seed=seed)
            pilot.policy.reset()
            torch.manual_seed(seed)
            for _ in range(real.task.episode_steps):
                cloud = obs["pointcloud"] if shadow is None else pose_like(shadow, real)["pointcloud"]
                obs, _, done, _, _ = real.step(pilot.act(obs["agent_pos"], MIXED, cloud))
                if done:
                    wins += 1
                    break
        successes[source] = wins
    return successes


def state_swap(pilot: Pilot, episodes: int, stall_step: int) -> list[dict]:
    """Per episode, the wrists' height at `stall_step` and the wrist travel (cm; left, right) the policy plans
    there with the real state and with each shadow's."""
    real, shadows = scene(MIXED), {hands: scene(hands) for hands in SEEN}
    rows = []
    for seed in tqdm(range(EVAL_SEED, EVAL_SEED + episodes), desc="state at the stall", leave=False):
        obs, _ = real.reset(seed=seed)
        pilot.policy.reset()
        torch.manual_seed(seed)
        for _ in range(stall_step):
            obs, *_ = real.step(pilot.act(obs["agent_pos"], MIXED, obs["pointcloud"]))
        states = {"own": (obs["agent_pos"], MIXED, wrists(real))}
        for hands, shadow in shadows.items():
            shadow.reset(seed=seed)
            states[hands] = (pose_like(shadow, real)["agent_pos"], hands, wrists(shadow))
        travel = {}
        for source, (state, hands, at) in states.items():
            plans = [pilot.chunk(state, hands, obs["pointcloud"], k)[-1, at] - state[at] for k in range(3)]
            travel[source] = (
                100 * np.mean([np.linalg.norm(p.reshape(2, 3), axis=1) for p in plans], 0)
            ).round(2)
        height = 100 * obs["agent_pos"][wrists(real)].reshape(2, 3)[:, 2]
        rows.append({
            "seed": seed, "wrist_z_cm": height.round(1).tolist(), "stalled": bool(height.min() > STALLED_CM),
            "travel_cm": {k: v.tolist() for k, v in travel.items()},
        })  # fmt: skip
    return rows


def mean_travel(rows: list[dict]) -> dict[str, list[float]]:
    return {
        source: np.mean([row["travel_cm"][source] for row in rows], axis=0).round(2).tolist()
        for source in rows[0]["travel_cm"]
    } if rows else {}  # fmt: skip


def plot(report: dict, path: Path) -> None:
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    swap = report["cloud_swap_successes"]
    left.bar(range(len(swap)), [100 * v / report["episodes"] for v in swap.values()], color="tab:blue")
    left.set(xticks=range(len(swap)), ylabel="success (%)", ylim=(0, 100),
             title=f"{MIXED} in closed loop, fed the cloud of ...")  # fmt: skip
    left.set_xticklabels([f"{k}\n{v}/{report['episodes']}" for k, v in swap.items()])
    travel = report["state_swap_travel_cm_stalled"] or report["state_swap_travel_cm"]
    for i, (lt, rt) in enumerate(travel.values()):
        right.bar([3 * i, 3 * i + 1], [lt, rt], color=["tab:green", "tab:purple"])
    title = f"step {report['stall_step']}, {report['stalled_episodes']} stalled: the state of ..."
    right.set(xticks=[3 * i + 0.5 for i in range(len(travel))], ylabel="planned wrist travel per chunk (cm)",
              title=title)  # fmt: skip
    right.set_xticklabels(list(travel))
    right.legend(handles=[plt.Rectangle((0, 0), 1, 1, color=c) for c in ("tab:green", "tab:purple")],
                 labels=["left wrist", "right wrist"])  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True, help="a policy co-trained on the two seen pairs")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--stall-step", type=int, default=48)
    parser.add_argument("--name", default="mixed_pair")
    args = parser.parse_args()
    torch.set_num_threads(1)
    pilot = Pilot(args.checkpoint)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout
    report = {
        "checkpoint": args.checkpoint,
        "commit": commit.strip(),
        "mixed_pair": MIXED,
        "seen_pairs": list(SEEN),
        "episodes": args.episodes,
        "stall_step": args.stall_step,
        "cloud_swap_successes": cloud_swap(pilot, args.episodes),
    }
    rows = state_swap(pilot, args.episodes, args.stall_step)
    report["state_swap_travel_cm"] = mean_travel(rows)
    report["state_swap_travel_cm_stalled"] = mean_travel([row for row in rows if row["stalled"]])
    report["stalled_episodes"] = sum(row["stalled"] for row in rows)
    report["state_swap_episodes"] = rows
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{args.name}.json").write_text(json.dumps(report, indent=2) + "\n")
    plot(report, RESULTS / f"{args.name}.png")
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
