"""Writes the tiny `opfa` checkpoints in this folder and the actions they gave when they were made (run at
commit 62a5b26, before the action spaces became classes): `test_policy.py` checks that today's code loads
them and gives the same actions. Run from the repository root: `python tests/data/checkpoints_v1/make.py`."""

import sys
from pathlib import Path

from safetensors.torch import save_file

sys.path.insert(0, str(Path(__file__).parents[1].parent))
from test_policy import HANDS, make_policy, rollout, save_galr  # noqa: E402

from lerobot_opfa import cli  # noqa: E402
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset  # noqa: E402
from lerobot_opfa.features import OBS_POINTCLOUD  # noqa: E402

HERE = Path(__file__).parent
CASES = {"galr": ("merged", HANDS), "per_embodiment": ("merged", HANDS), "raw": ("inspire", ["inspire"])}


def main(work: Path) -> None:
    save_galr(work / "galr", HANDS)
    for seed, hand in enumerate(HANDS):
        write_synthetic_dataset(work / hand, hand, episodes=2, frames=12, n_points=32, seed=seed)
    inputs = [str(work / h) for h in HANDS]
    assert cli.main(["dataset", "merge", "--inputs", *inputs, "--output", str(work / "merged"), "--galr",
                     str(work / "galr")]) == 0  # fmt: skip
    expected = {}
    for space, (dataset, hands) in CASES.items():
        policy, pre, post, ds = make_policy(work, dataset, action_space=space)
        policy.eval()
        for obj in (policy, pre, post):
            obj.save_pretrained(HERE / space)
        cloud = ds[0][OBS_POINTCLOUD][-1]
        expected[f"{space}/cloud"] = cloud
        for hand in hands:
            expected[f"{space}/{hand}"] = rollout(policy, pre, post, hand, cloud)
        del pre, post
    save_file(expected, HERE / "actions.safetensors")


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        main(Path(tmp))
