"""Arm specs: how lerobot-opfa reads an arm model as its vendor ships it (URDF or MJCF), where the arm
stands in the workspace and how a hand sits on its flange.

An arm spec is YAML (`docs/usage.md`, "Arm specs"): `model` (a path beside the spec, or
`package://<package>/<path>` for a model installed by a PyPI package that lays its files out under
`cmeel.prefix/share/<package>`, as `example-robot-data` does), `flange` (the link the hand is mounted on),
`joints` (the arm's joints, base to flange, as the model names them), `base` (the model's root in the
workspace frame: `xyz` in metres, `rpy` in radians), `mount` (the hand's wrist frame in the flange frame, the
same form) and `home` (joint values). The built-in arms are `arm_models/<name>.yaml`.
"""

from __future__ import annotations

import sysconfig
from dataclasses import dataclass
from pathlib import Path

import torch

from lerobot_opfa.arms.ik import ArmChain
from lerobot_opfa.hands.frame import rpy_matrix
from lerobot_opfa.resources import builtin_or_path, resource_dir
from lerobot_opfa.yaml_files import read_yaml

FIELDS = ("name", "description", "model", "flange", "joints", "base", "mount", "home")
PACKAGE_SCHEME = "package://"
INSTALL_HINT = {"example-robot-data": "pip install 'lerobot-opfa[arms]'"}
"""How to install the package a built-in arm's model comes from."""


class ArmSpecError(ValueError):
    """An arm spec that cannot describe its model; the message names the file and the field."""

    def __init__(self, path: Path | str, field_name: str, message: str):
        super().__init__(f"{path}: field '{field_name}': {message}")


def arm_models_dir() -> Path:
    return resource_dir("arm_models")


def builtin_arms() -> dict[str, Path]:
    """Built-in arm name -> spec path."""
    return {p.stem: p for p in sorted(arm_models_dir().glob("*.yaml"))}


def package_share(package: str) -> Path:
    """Where a cmeel-packaged PyPI package (`example-robot-data`) installs its shared files."""
    return Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / package


def transform(xyz, rpy) -> torch.Tensor:
    """(4, 4) float64: translation `xyz`, rotation `rpy` (URDF roll, pitch, yaw: `frame.rpy_matrix`)."""
    out = torch.eye(4, dtype=torch.float64)
    out[:3, :3] = torch.from_numpy(rpy_matrix(tuple(float(a) for a in rpy)))
    out[:3, 3] = torch.tensor([float(v) for v in xyz], dtype=torch.float64)
    return out


@dataclass(frozen=True)
class ArmSpec:
    path: Path
    name: str
    description: str
    model: str
    """As the spec writes it: a path relative to the spec, or `package://<package>/<path>`."""
    flange: str
    joints: tuple[str, ...]
    base: torch.Tensor
    """(4, 4): the model's root frame in the workspace frame."""
    mount: torch.Tensor
    """(4, 4): the hand's wrist frame in the flange frame."""
    home: tuple[float, ...]

    @classmethod
    def load(cls, path: Path | str) -> ArmSpec:
        path = Path(path)
        raw = read_yaml(path, "arm spec")
        if not isinstance(raw, dict):
            raise ArmSpecError(path, "(top)", "an arm spec is a mapping of fields")
        unknown = sorted(set(raw) - set(FIELDS))
        if unknown:
            raise ArmSpecError(path, unknown[0], f"unknown field; the fields are {', '.join(FIELDS)}")
        for name in ("name", "model", "flange", "joints"):
            if not raw.get(name):
                raise ArmSpecError(path, name, "missing")
        joints = raw["joints"]
        if not isinstance(joints, list) or not all(isinstance(j, str) for j in joints):
            raise ArmSpecError(path, "joints", "a list of the model's joint names, base to flange")
        home = raw.get("home", [0.0] * len(joints))
        if not isinstance(home, list) or len(home) != len(joints):
            raise ArmSpecError(path, "home", f"one value per joint ({len(joints)}), got {home!r}")
        return cls(
            path=path.resolve(),
            name=str(raw["name"]),
            description=str(raw.get("description", "")),
            model=str(raw["model"]),
            flange=str(raw["flange"]),
            joints=tuple(joints),
            base=_frame(path, "base", raw.get("base")),
            mount=_frame(path, "mount", raw.get("mount")),
            home=tuple(float(v) for v in home),
        )

    @property
    def model_path(self) -> Path:
        """The model file; a model of a package that is not installed is one line saying how to install
        it."""
        if not self.model.startswith(PACKAGE_SCHEME):
            path = (self.path.parent / self.model).resolve()
            if not path.is_file():
                raise ArmSpecError(self.path, "model", f"{path} not found")
            return path
        package, _, rest = self.model.removeprefix(PACKAGE_SCHEME).partition("/")
        path = package_share(package) / rest
        if not path.is_file():
            hint = INSTALL_HINT.get(package, f"install the PyPI package {package}")
            raise ArmSpecError(
                self.path, "model", f"{self.model} is not installed ({path} not found): {hint}"
            )
        return path

    def chain(self) -> ArmChain:
        """The arm's chain from its root to its flange; joints that are not the spec's are refused."""
        try:
            chain = ArmChain.from_model(self.model_path, self.flange)
        except ValueError as err:
            raise ArmSpecError(self.path, "flange", str(err)) from None
        if tuple(chain.joint_names) != self.joints:
            raise ArmSpecError(
                self.path,
                "joints",
                f"{', '.join(self.joints)}; the model's chain to '{self.flange}' has "
                f"{', '.join(chain.joint_names)}",
            )
        home = torch.tensor(self.home, dtype=torch.float64)
        outside = [
            j
            for j, v, lo, hi in zip(self.joints, home, chain.lower, chain.upper, strict=True)
            if not lo <= v <= hi
        ]
        if outside:
            raise ArmSpecError(self.path, "home", f"{outside[0]} outside its limits")
        return chain

    def wrist_pose(self, chain: ArmChain, q: torch.Tensor) -> torch.Tensor:
        """(B, 4, 4): the hand's wrist frame in the workspace frame, for arm joints `q` (B, dof)."""
        return self.base @ chain.flange_pose(q.to(torch.float64)) @ self.mount

    def flange_target(self, wrist: torch.Tensor) -> torch.Tensor:
        """(B, 4, 4): the flange pose in the arm's base frame that puts the wrist at `wrist` (workspace)."""
        return torch.linalg.inv(self.base) @ wrist @ torch.linalg.inv(self.mount)


def _frame(path: Path, name: str, raw) -> torch.Tensor:
    if raw is None:
        return torch.eye(4, dtype=torch.float64)
    if not isinstance(raw, dict) or set(raw) - {"xyz", "rpy"}:
        raise ArmSpecError(path, name, "a mapping of xyz (m) and rpy (rad), three numbers each")
    values = {key: raw.get(key, [0.0, 0.0, 0.0]) for key in ("xyz", "rpy")}
    for key, value in values.items():
        if not isinstance(value, list) or len(value) != 3:
            raise ArmSpecError(path, f"{name}.{key}", f"three numbers, got {value!r}")
    return transform(values["xyz"], values["rpy"])


def arm_name(arm: str | Path) -> str:
    """The name of the arm `arm` references (a built-in's name, or a spec path: the spec's `name`)."""
    return str(arm) if str(arm) in builtin_arms() else load_arm(arm).name


def load_arm(arm: str | Path) -> ArmSpec:
    """A built-in arm by name, or an arm spec YAML by path."""
    return ArmSpec.load(builtin_or_path("arm", arm, builtin_arms()))
