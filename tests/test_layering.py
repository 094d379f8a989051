"""The package's layers: hand models and GaLR load without LeRobot or gymnasium, and the simulator knows
nothing of the learner."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest
from subprocesses import run_command

SRC = Path(__file__).parents[1] / "src" / "lerobot_opfa"


def test_hands_and_galr_import_without_lerobot_or_gymnasium():
    code = (
        "import lerobot_opfa.hands, lerobot_opfa.galr.model, sys; "
        "print([m for m in sys.modules if m.startswith(('lerobot.', 'gymnasium'))])"
    )
    result = run_command([sys.executable, "-c", code], timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    return {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module} | {
        alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names
    }


@pytest.mark.parametrize("layer", ["envs", "datasets"])
def test_no_simulator_or_dataset_module_imports_the_policy(layer):
    """The simulator knows nothing of the learner, and datasets sit below the policy (docs/design.md)."""
    offenders = {
        str(path.relative_to(SRC)): sorted(m for m in _imports(path) if m.startswith("lerobot_opfa.policy"))
        for path in sorted((SRC / layer).glob("*.py"))
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_the_plugin_module_registers_the_policy_env_and_processor_steps():
    code = (
        "import lerobot_policy_opfa; from lerobot.configs import PreTrainedConfig; "
        "from lerobot.envs.configs import EnvConfig; from lerobot.processor import ProcessorStepRegistry; "
        "print(PreTrainedConfig.get_choice_class('opfa').__name__, "
        "EnvConfig.get_choice_class('opfa').__name__, "
        "all(n in ProcessorStepRegistry.list() for n in ('opfa_encode_joints', 'opfa_decode_joints', "
        "'opfa_normalize')))"
    )
    result = run_command([sys.executable, "-c", code], timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split() == ["OpfaConfig", "OpfaEnvConfig", "True"]
