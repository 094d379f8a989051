"""The README is for a newcomer: short, the two set-up commands first, and how to install and run it
outside this repository."""

from __future__ import annotations

import re
from pathlib import Path

README = (Path(__file__).parents[1] / "README.md").read_text()


def test_readme_is_short_and_opens_with_the_two_setup_commands():
    assert len(README.splitlines()) < 250
    first_block = re.search(r"```bash\n(.*?)```", README, re.S).group(1)
    assert [line.split("#")[0].strip() for line in first_block.strip().splitlines()] == [
        "make demo",
        "make test",
    ]


def test_readme_says_how_to_install_and_run_it_anywhere():
    for needed in (
        "pip install",  # into an existing LeRobot environment
        "lerobot_policy_opfa",  # the distribution's real name
        "download.pytorch.org/whl/cpu",  # a CPU-only torch
        "--policy.device=cuda",  # a GPU
        "galr list",  # the packaged checkpoints by name
        "(B, dof)",  # what `galr embed` takes
    ):
        assert needed in README, needed
