"""Running the package's and LeRobot's commands from tests so that none can hang the suite: each runs in
its own process group, and on its timeout the whole group (a torchrun's ranks too, which hold the output
pipes open) is killed and the test fails with the command's last output. LeRobot's entry points can also
run in the test's process, where what is tested is not the process itself."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
from collections.abc import Sequence

import pytest

TAIL = 3000


def run_command(command: Sequence[str], timeout: float, **kwargs) -> subprocess.CompletedProcess:
    """`subprocess.run(command, capture_output=True, text=True, timeout=timeout, **kwargs)`, killing the
    command's whole process group when it runs past `timeout`."""
    command = [str(part) for part in command]
    with subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, **kwargs
    ) as process:
        try:
            out, err = process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            out, err = process.communicate()
            pytest.fail(
                f"{' '.join(command)[:300]} ran past {timeout:.0f} s and was killed; its last output:\n"
                f"{out[-TAIL:]}\n{err[-TAIL:]}"
            )
    return subprocess.CompletedProcess(command, process.returncode, out, err)


def run_lerobot_here(script: str, argv: Sequence[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """LeRobot's entry point `lerobot.scripts.<script>` run in this process on `argv` (it reads its flags
    from sys.argv), where a subprocess would add only its start-up (about 6 s of imports)."""
    import importlib
    import sys

    monkeypatch.setattr(sys, "argv", [script.replace("_", "-"), *map(str, argv)])
    importlib.import_module(f"lerobot.scripts.{script}").main()
