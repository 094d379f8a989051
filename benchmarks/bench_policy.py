"""The opfa policy's speed on the CPU next to LeRobot's stock diffusion policy, in the same run:
training steps per second (GaLR space with cached latents, raw joints, GaLR encoded on the fly, stock
diffusion) and latency per action chunk at batch 1 (horizon 16, 2 observation steps, 8 action steps,
10 DDIM steps for both), split into preprocessor, `select_action` and postprocessor (opfa: GaLR decode),
plus opfa's point encoder / U-Net loop / GaLR decode on their own; preprocessor and `select_action` per
chunk of a batch-1 rollout (the preprocessor encodes every hand state); and opfa's same weights sampled
through float32 weights
(`cpu_float16_weights=False`, with its largest action difference) and through the plain U-Net that
training runs (`cpu_fast_sampling=False`).

    .venv/bin/python benchmarks/bench_policy.py [--galr outputs/galr_default] [--steps 10]

Data: synthetic per-hand datasets (umi, inspire, leap) merged with the GaLR. Without --galr a GaLR of the
default architecture with untrained weights is used (same compute). Writes benchmarks/results/policy.json
and policy.png.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402
from lerobot.configs.types import FeatureType  # noqa: E402
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata  # noqa: E402
from lerobot.datasets.factory import resolve_delta_timestamps  # noqa: E402
from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402
from lerobot.policies.factory import make_policy, make_pre_post_processors  # noqa: E402
from lerobot.utils.feature_utils import dataset_to_policy_features  # noqa: E402

import lerobot_policy_opfa  # noqa: E402, F401  (the plugin, as LeRobot loads it: steps, robot_type)
from lerobot_opfa.datasets.merge import merge_datasets  # noqa: E402
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset  # noqa: E402
from lerobot_opfa.features import OBS_POINTCLOUD, ROBOT_TYPE  # noqa: E402
from lerobot_opfa.galr.model import Galr, GalrConfig, hand_record  # noqa: E402
from lerobot_opfa.hands import load_hand  # noqa: E402
from lerobot_opfa.policy.configuration_opfa import OpfaConfig  # noqa: E402
from lerobot_opfa.policy.joint_steps import OpfaDecodeJointsStep  # noqa: E402
from lerobot_opfa.policy.stock import latent_dataset  # noqa: E402

RESULTS = Path(__file__).parent / "results"
HANDS = ["umi", "inspire", "leap"]
MATCHED = dict(horizon=16, n_obs_steps=2, n_action_steps=8, down_dims=OpfaConfig.down_dims, device="cpu")


def build_data(root: Path, galr_path: str | None, n_points: int) -> str:
    if galr_path is None:
        galr_path = str(root / "galr")
        torch.manual_seed(0)
        Galr(GalrConfig(hands=[hand_record(load_hand(h)) for h in HANDS])).save_pretrained(galr_path)
    for seed, hand in enumerate(HANDS):
        write_synthetic_dataset(root / hand, hand, episodes=3, frames=40, n_points=n_points, seed=seed)
    merge_datasets([root / h for h in HANDS], root / "merged", galr_path=galr_path)
    latent_dataset(root / "merged", root / "latent", galr_path)
    return galr_path


def build(config, root: Path, name: str):
    meta = LeRobotDatasetMetadata(f"local/{name}", root=root / name)
    features = dataset_to_policy_features(meta.features)
    config.output_features = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config.input_features = {k: f for k, f in features.items() if k not in config.output_features}
    torch.manual_seed(0)
    policy = make_policy(config, ds_meta=meta)
    kwargs = {"dataset_stats": meta.stats} | ({"dataset_meta": meta} if config.type == "opfa" else {})
    pre, post = make_pre_post_processors(config, **kwargs)
    dataset = LeRobotDataset(
        f"local/{name}", root=root / name, delta_timestamps=resolve_delta_timestamps(config, meta)
    )
    return policy, pre, post, dataset


class TrainTimer:
    """One optimiser step (preprocessor + forward + backward + update) on a fixed batch, timed per call."""

    def __init__(self, policy, pre, dataset, batch_size: int):
        rows = range(0, 7 * batch_size, 7)
        self.batch = torch.utils.data.default_collate([dataset[i % len(dataset)] for i in rows])
        self.policy, self.pre = policy.train(), pre
        self.optimizer = torch.optim.Adam(policy.parameters(), lr=1e-4)

    def __call__(self) -> float:
        start = time.perf_counter()
        loss, _ = self.policy.forward(self.pre(dict(self.batch)))
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        return time.perf_counter() - start


def observation(dataset, hand: str, latent: bool) -> dict:
    """A batch-1 observation: the hand's joints for opfa, the dataset's own wrist + z for the stock policy
    (it was trained on the latent dataset and gets z from there, so it pays no GaLR encode here)."""
    item = dataset[0]
    state = torch.cat([torch.tensor([0.0, 0.0, 0.3, 0.0, 0.0, 0.0]), load_hand(hand).pose("open").float()])
    if latent:
        state = item["observation.state"][-1]
    obs = {"observation.state": state, OBS_POINTCLOUD: item[OBS_POINTCLOUD][-1], "task": "lift"}
    if not latent:
        obs[ROBOT_TYPE] = hand  # which of the policy's robots the frames come from, as LeRobot says it
    if "observation.environment_state" in item:
        obs["observation.environment_state"] = item["observation.environment_state"][-1]
    return obs


def chunk_times(policy, pre, post, obs: dict) -> tuple[float, float, float]:
    """Seconds of the preprocessor (opfa: GaLR encode of the hand state, computed here although the
    preprocessor defers it, so that `select_action` times the policy alone), `select_action` and the
    postprocessor (opfa: GaLR decode) for a call that samples a new chunk (batch 1)."""
    policy.reset()
    with torch.no_grad():
        t0 = time.perf_counter()
        batch = pre(dict(obs))
        batch["observation.state"] = batch["observation.state"].clone()
        t1 = time.perf_counter()
        action = policy.select_action(batch)
        t2 = time.perf_counter()
        post(action)
        return t1 - t0, t2 - t1, time.perf_counter() - t2


def history(pre, obs: dict) -> dict:
    """The preprocessed observation repeated over both observation steps, as the policy's queues hold it."""
    batch = pre(dict(obs))
    stacked = ("observation.state", OBS_POINTCLOUD)
    return {k: v.unsqueeze(1).expand(-1, 2, *v.shape[1:]) if k in stacked else v
            for k, v in batch.items() if isinstance(v, torch.Tensor)}  # fmt: skip


def chunk_difference(policy, reference, pre, obs: dict) -> float:
    """Largest difference between two policies' action chunks (normalised units) for one observation and
    one noise draw."""
    batch = history(pre, obs)
    noise = torch.randn(1, policy.config.horizon, policy.unet.action_dim)
    chunks = []
    for p in (policy, reference):
        p.reset()
        chunks.append(p.predict_action_chunk(batch, noise=noise))
    return (chunks[0] - chunks[1]).abs().max().item()


def opfa_breakdown_ms(policy, pre, post, obs: dict, repeats: int) -> dict[str, float]:
    """The three stages of a chunk timed on their own: point encoder, 10-step U-Net loop, GaLR decode."""
    batch = history(pre, obs)
    parts = {"point_encoder": [], "unet_loop": [], "galr_decode": []}
    decode = next(step for step in post.steps if isinstance(step, OpfaDecodeJointsStep))
    with torch.inference_mode():
        for _ in range(repeats + 2):
            start = time.perf_counter()
            cond = policy.encode_observation(batch)
            mid = time.perf_counter()
            noise = torch.randn(1, policy.config.horizon, policy.unet.action_dim)
            actions = policy.sample(cond, None, noise)
            end = time.perf_counter()
            z = actions[:, 0, decode.wrist_dim :]
            start_decode = time.perf_counter()
            decode.galr.decode(z, "leap")
            parts["point_encoder"].append(mid - start)
            parts["unet_loop"].append(end - mid)
            parts["galr_decode"].append(time.perf_counter() - start_decode)
    return {k: 1000 * statistics.median(v[2:]) for k, v in parts.items()}


def rollout_chunk_ms(policy, pre, obs: dict, chunks: int) -> tuple[float, float]:
    """Milliseconds per chunk of a batch-1 rollout, medians over `chunks` chunks: the preprocessor over the
    chunk's `n_action_steps` observations (a new hand state each) and `select_action` over them (the call
    that samples the chunk included)."""
    per_chunk = policy.config.n_action_steps
    pre_ms, select_ms = [], []
    policy.reset()
    with torch.no_grad():
        for step in range((chunks + 1) * per_chunk):
            observation = dict(obs)
            observation["observation.state"] = obs["observation.state"].clone()
            observation["observation.state"][6:] += 1e-3 * (step % 50)
            t0 = time.perf_counter()
            batch = pre(observation)
            t1 = time.perf_counter()
            policy.select_action(batch)
            t2 = time.perf_counter()
            if step % per_chunk == 0:
                pre_ms.append(0.0)
                select_ms.append(0.0)
            pre_ms[-1] += 1000 * (t1 - t0)
            select_ms[-1] += 1000 * (t2 - t1)
    return statistics.median(pre_ms[1:]), statistics.median(select_ms[1:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--galr", help="GaLR checkpoint (default: untrained default architecture)")
    parser.add_argument("--steps", type=int, default=10, help="timed training steps per variant")
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=20, help="timed select_action chunks")
    parser.add_argument("--n-points", type=int, default=512)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--note", help="stored in the JSON, e.g. what else ran on the machine")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        galr_path = build_data(root, args.galr, args.n_points)
        variants = {
            "opfa galr (cached z)": (OpfaConfig(galr_path=galr_path, **MATCHED), "merged"),
            "opfa raw joints (leap)": (OpfaConfig(action_space="raw", **MATCHED), "leap"),
            "opfa galr, z encoded per step": (OpfaConfig(galr_path=galr_path, **MATCHED), "leap"),
            "stock diffusion (wrist + z)": (
                DiffusionConfig(noise_scheduler_type="DDIM", num_inference_steps=10, **MATCHED),
                "latent",
            ),
        }
        built = {name: build(config, root, dataset_name) for name, (config, dataset_name) in variants.items()}
        # The same weights, sampled through float32 weights (what `cpu_float16_weights` saves and changes)
        # and through the plain U-Net (what `cpu_fast_sampling` saves).
        float32 = "opfa galr (cached z), float32 weights"
        plain = "opfa galr (cached z), plain sampling"
        same_weights = {
            float32: OpfaConfig(galr_path=galr_path, cpu_float16_weights=False, **MATCHED),
            plain: OpfaConfig(galr_path=galr_path, cpu_fast_sampling=False, **MATCHED),
        }
        for name, config in same_weights.items():
            variants[name] = (config, "merged")
            built[name] = build(config, root, "merged")
        # Round-robin over the variants, so load from other processes hits them all alike.
        online = "opfa galr, z encoded per step"  # a GaLR forward per frame: a few steps suffice
        timers = {
            name: TrainTimer(p, pre, ds, args.batch_size)
            for name, (p, pre, _, ds) in built.items()
            if name not in same_weights  # train exactly as the float16 one
        }
        steps = {name: [] for name in built}
        for round_ in range(args.steps + 2):
            for name, timer in timers.items():
                if name != online or round_ < 4:
                    steps[name].append(timer())
        for name in same_weights:
            built[name][0].load_state_dict(built["opfa galr (cached z)"][0].state_dict())
        latency = {name: [] for name in built if name != online}
        for _ in range(args.repeats + 2):
            for name in latency:
                policy, pre, post, dataset = built[name]
                policy.eval()
                obs = observation(dataset, "leap", latent=variants[name][1] == "latent")
                latency[name].append(chunk_times(policy, pre, post, obs))
        rows = []
        for name, (_, dataset_name) in variants.items():
            row = {"variant": name, "dataset": dataset_name}
            if name in timers:
                row["train_steps_per_s"] = 1.0 / statistics.median(steps[name][2:])
            if name in latency:
                for i, part in enumerate(("preprocessor_ms", "select_action_ms", "postprocessor_ms")):
                    row[part] = 1000 * statistics.median(t[i] for t in latency[name][2:])
                row["pipeline_ms"] = (
                    row["preprocessor_ms"] + row["select_action_ms"] + row["postprocessor_ms"]
                )
            rows.append(row)
            print({k: round(v, 2) if isinstance(v, float) else v for k, v in row.items()})
        policy, pre, post, dataset = built["opfa galr (cached z)"]
        obs = observation(dataset, "leap", False)
        breakdown = opfa_breakdown_ms(policy, pre, post, obs, args.repeats)
        print("opfa breakdown (ms):", {k: round(v, 2) for k, v in breakdown.items()})
        float16_error = chunk_difference(policy, built[float32][0], pre, obs)
        print(f"float16 vs float32 weights, largest action difference: {float16_error:.2e}")
        chunk_pre, chunk_select = rollout_chunk_ms(policy, pre, obs, args.repeats)
        print(f"per chunk: preprocessor {chunk_pre:.2f} ms, select_action {chunk_select:.2f} ms")

    by = {r["variant"]: r for r in rows}
    opfa, raw, stock = (
        by["opfa galr (cached z)"],
        by["opfa raw joints (leap)"],
        by["stock diffusion (wrist + z)"],
    )
    result = {
        "benchmark": "opfa policy: training steps/s and select_action latency vs stock diffusion",
        "command": "python benchmarks/bench_policy.py" + (f" --galr {args.galr}" if args.galr else ""),
        "settings": {
            **{k: list(v) if isinstance(v, tuple) else v for k, v in MATCHED.items()},
            "num_inference_steps": 10,
            "batch_size": args.batch_size,
            "n_points": args.n_points,
            "galr": args.galr or "default architecture, untrained weights",
            "torch_threads": torch.get_num_threads(),
        },
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "python": platform.python_version(),
            "torch": torch.__version__,
            "cpu_count": os.cpu_count(),
            "load_average_1_5_15_min": os.getloadavg(),  # other processes compete for the cores
        },
        "note": args.note,
        "variants": rows,
        "opfa_select_action_breakdown_ms": breakdown,
        "galr_step_time_vs_raw": raw["train_steps_per_s"] / opfa["train_steps_per_s"],
        "opfa_vs_stock_select_action_speedup": stock["select_action_ms"] / opfa["select_action_ms"],
        "float16_vs_float32_weights_select_action_speedup": by[float32]["select_action_ms"]
        / opfa["select_action_ms"],
        "float16_vs_float32_weights_max_action_difference": float16_error,
        "fast_vs_plain_sampling_select_action_speedup": by[plain]["select_action_ms"]
        / opfa["select_action_ms"],
        "preprocessor_ms_per_chunk": chunk_pre,
        "select_action_ms_per_chunk": chunk_select,
        "preprocessor_vs_select_action_per_chunk": chunk_pre / chunk_select,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "policy.json").write_text(json.dumps(result, indent=2))

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5))
    trained = [r for r in rows if "train_steps_per_s" in r]
    left.barh(
        [r["variant"] for r in trained],
        [r["train_steps_per_s"] for r in trained],
        color=["C0", "C1", "C2", "C3"],
    )
    left.set_xlabel(f"training steps per second (batch {args.batch_size})")
    left.invert_yaxis()
    timed = [r for r in rows if "select_action_ms" in r]
    offsets = [0.0] * len(timed)
    for i, part in enumerate(("preprocessor_ms", "select_action_ms", "postprocessor_ms")):
        values = [r[part] for r in timed]
        right.barh([r["variant"] for r in timed], values, left=offsets, color=f"C{i + 4}", label=part[:-3])
        offsets = [o + v for o, v in zip(offsets, values, strict=True)]
    right.axvline(50, color="k", ls="--", lw=0.8, label="50 ms target (select_action)")
    right.set_xlabel("ms per action chunk, batch 1 (stacked)")
    right.invert_yaxis()
    right.legend(fontsize=8)
    fig.suptitle(
        f"opfa vs stock diffusion, CPU ({torch.get_num_threads()} threads), horizon 16, 10 DDIM steps"
    )
    fig.tight_layout()
    fig.savefig(RESULTS / "policy.png", dpi=110)
    print(f"wrote {RESULTS}/policy.json and .png")


if __name__ == "__main__":
    main()
