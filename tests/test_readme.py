"""The README is for a newcomer: short, the two set-up commands first, and how to install and run it
outside this repository."""

from __future__ import annotations

import re
import sys
from pathlib import Path

from subprocesses import run_command

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


def test_the_tests_run_on_the_python_the_readme_and_makefile_name():
    """The venv the tests run in was made with the Python `make which-python` picks, the one the README
    names."""
    root = Path(__file__).parents[1]
    picked = run_command(["make", "-s", "-C", str(root), "which-python"], timeout=60)
    assert picked.returncode == 0, picked.stderr
    version = run_command(
        [picked.stdout.strip(), "-c", "import sys; print(sys.version_info[:2])"], timeout=60
    )
    assert version.stdout.strip() == str(sys.version_info[:2])
    order = re.search(r"among (.*?) on\nPATH", README).group(1)
    makefile = (root / "Makefile").read_text()
    assert re.findall(r"`(\w[\w.]*)`", order) == re.search(r"for c in (.*?); do", makefile).group(1).split()
