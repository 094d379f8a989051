"""`opfa_depth_to_pointcloud`: a rig's depth frames (LeRobot depth-map features, `observation.images.<cam>`)
-> the policy's `observation.pointcloud`, first in the preprocessor, so that training batches and a live
robot's observations become clouds through one path (and the simulator's code, `pointclouds`). The
cameras' calibration is saved in the step's config: a checkpoint deploys with nothing else."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from lerobot.configs.types import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry

from lerobot_opfa.features import OBS_POINTCLOUD
from lerobot_opfa.pointclouds import DepthRig


@ProcessorStepRegistry.register("opfa_depth_to_pointcloud")
@dataclass
class DepthToPointCloudStep(ObservationProcessorStep):
    """Each frame's depth images (any leading batch/history dims, then (1, H, W) or (H, W)) -> one fused
    cloud (..., n_points * 3); the depth entries leave the observation. An observation that already carries
    a cloud and no depth (the opfa gym env's, made by the same code) passes as it is."""

    rig: dict[str, Any] = field(default_factory=dict)
    """`DepthRig.to_dict()`: cameras by feature key, depth unit, workspace."""
    n_points: int = 1024
    seed: int = 0

    def __post_init__(self):
        self.depth_rig = DepthRig.from_dict(self.rig, "the checkpoint's camera calibration")
        self.rng = np.random.default_rng(self.seed)

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        keys = list(self.depth_rig.cameras)
        if OBS_POINTCLOUD in observation and not any(k in observation for k in keys):
            return observation
        missing = [k for k in keys if k not in observation]
        if missing:
            raise ValueError(
                f"the observation has no depth frames {missing} (it has {', '.join(observation)}); this "
                "policy makes its cloud from the cameras it was trained with"
            )
        depths = {k: observation.pop(k) for k in keys}
        observation[OBS_POINTCLOUD] = torch.from_numpy(self.depth_rig.clouds(depths, self.n_points, self.rng))
        return observation

    def get_config(self) -> dict[str, Any]:
        return {"rig": self.rig, "n_points": self.n_points, "seed": self.seed}

    def reset(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    def transform_features(self, features):
        observation = dict(features.get(PipelineFeatureType.OBSERVATION, {}))
        for key in self.depth_rig.cameras:
            observation.pop(key, None)
        observation[OBS_POINTCLOUD] = PolicyFeature(FeatureType.STATE, (3 * self.n_points,))
        return {**features, PipelineFeatureType.OBSERVATION: observation}
