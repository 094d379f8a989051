"""Writes the tiny KPConv GaLR in this folder and the latents it gave when it was made (run at commit
f2f57dc, before the stem's link neighbourhoods and the encoder's speed work): `test_galr.py` checks that
today's code loads it and encodes the same joints to the same latents. Run from the repository root:
`python tests/data/galr_v1/make.py`."""

import sys
from pathlib import Path

import torch
from safetensors.torch import save_file

sys.path.insert(0, str(Path(__file__).parents[1].parent))
from test_galr import HANDS, tiny_galr  # noqa: E402

from lerobot_opfa.hands import load_hand  # noqa: E402

HERE = Path(__file__).parent


def main() -> None:
    galr = tiny_galr()
    galr.save_pretrained(HERE / "galr")
    expected = {}
    for hand in HANDS:
        joints = load_hand(hand).sample_joints(4, torch.Generator().manual_seed(3))
        expected[f"{hand}/joints"] = joints
        with torch.no_grad():
            expected[f"{hand}/latents"] = galr.encode_joints(hand, joints)
    save_file(expected, HERE / "latents.safetensors")


if __name__ == "__main__":
    main()
