"""A tool frame for every hand, computed from its geometry: where its grasp closes (origin: between the
thumb's tip and the other fingertips in the grasp pose), from which side it approaches (+z: from the
wrist towards that point) and along which axis it squeezes (+x: thumb against fingers; a held bar lies
along +y). The wrist is controlled in this frame, so one wrist
trajectory brings any hand's grasp onto an object and scripted experts need no per-hand tuning.
A dexterous thumb swings round while the fingers curl, so it closes on them along a direction that
differs from +x (`squeeze_angle`): experts lay elongated objects across that direction.
The origin is where the grasp pose brings the tips together, closer than most objects are wide: an object
goes where the thumb and the other fingertips meet it at once (`grasp_centre`), or the first to arrive
pushes it away (example-robot-data's Allegro, whose grasp pose is tighter than the built-in's, knocked the
can over in 14 of 20 lifts at the origin)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
import torch

from lerobot_opfa.hands.model import HandModel

N_CLOUD = 3000
N_TIP = 10  # points that make up a fingertip: the ones of a finger farthest from the wrist
PRESS_BAND = 0.005  # m: points this close to the foremost one make up the press point
# Hand poses from open (0) through grasp (1) and on past it (experts squeeze past it) whose reach is tabled.
CLOSURES = np.linspace(0.0, 1.5, 16)
SQUEEZE_CLOSURE = 0.5  # `squeeze_angle` is read halfway through closing, where thumb and fingers meet objects


@dataclass(frozen=True)
class ToolFrame:
    """Tool frame in the hand's base frame, plus the reach of the hand beyond it along the approach axis."""

    rotation: np.ndarray  # (3, 3), columns: tool x (squeeze), y, z (approach) in the hand frame
    origin: np.ndarray  # (3,), grasp centre in the hand frame
    reach: np.ndarray  # how far the hand reaches past the origin along the approach axis, at `CLOSURES`
    press_point: np.ndarray  # (3,) in the tool frame: the closed hand's foremost point along the approach
    squeeze_angle: float  # rad about +z from +x to the direction from the other fingertips to the thumb's
    tip_gap: np.ndarray  # distance from the thumb's tip to the other fingertips' mean, at `CLOSURES`
    tip_middle: np.ndarray  # (len(CLOSURES), 3) in the tool frame: the point halfway between them

    def reach_at(self, closure: float) -> float:
        """Reach of the hand `closure` of the way from its open to its grasp pose (past 1: beyond it)."""
        return float(np.interp(closure, CLOSURES, self.reach))

    def grasp_centre(self, width: float) -> np.ndarray:
        """Where an object `width` across goes in the tool frame: halfway between the thumb's tip and the
        other fingertips at the first closure that brings them `width` apart (the narrowest closure if
        none does), so that both sides reach it together."""
        narrower = np.flatnonzero(self.tip_gap <= width)
        k = int(narrower[0]) if len(narrower) else int(np.argmin(self.tip_gap))
        if k == 0 or not len(narrower):
            return self.tip_middle[k].copy()
        s = (self.tip_gap[k - 1] - width) / (self.tip_gap[k - 1] - self.tip_gap[k])
        return self.tip_middle[k - 1] + s * (self.tip_middle[k] - self.tip_middle[k - 1])

    def hand_in_tool(self) -> tuple[np.ndarray, np.ndarray]:
        """(rotation, translation) of the hand's base frame in the tool frame (for attaching the hand)."""
        rot = self.rotation.T
        return rot, -rot @ self.origin


def _fingertips(points: np.ndarray, fingers: np.ndarray) -> dict[int, np.ndarray]:
    tips = {}
    for finger in sorted(set(fingers.tolist()) - {0}):
        pts = points[fingers == finger]
        tips[finger] = pts[np.argsort(np.linalg.norm(pts, axis=1))[-N_TIP:]].mean(0)
    return tips


@cache
def _tool_frame_cached(hand: HandModel) -> ToolFrame:
    q_open, q_grasp = hand.pose("open"), hand.pose("grasp")
    closures = torch.as_tensor(CLOSURES, dtype=q_open.dtype, device=q_open.device)[:, None]
    q_closing = torch.clamp(q_open + closures * (q_grasp - q_open), hand.lower, hand.upper)
    cloud = hand.point_cloud(q_closing, N_CLOUD)
    points = cloud.points.double().cpu().numpy()
    fingers = cloud.labels[0, :, 0].cpu().numpy()
    grasp = int(np.argmin(np.abs(CLOSURES - 1.0)))
    open_tips, grasp_tips = _fingertips(points[0], fingers), _fingertips(points[grasp], fingers)
    thumb = min(grasp_tips)  # finger index 1 (thumb, or a gripper's first jaw)
    others = [u for u in grasp_tips if u != thumb]
    if not others:
        raise ValueError(f"hand '{hand.name}' needs at least two fingers for a tool frame")
    origin = 0.5 * (grasp_tips[thumb] + np.mean([grasp_tips[u] for u in others], axis=0))
    z = origin / np.linalg.norm(origin)
    x = open_tips[thumb] - np.mean([open_tips[u] for u in others], axis=0)
    x -= x.dot(z) * z
    x /= np.linalg.norm(x)
    rotation = np.stack([x, np.cross(z, x), z], axis=1)
    depth = points @ z - origin @ z
    tip = points[grasp][depth[grasp] >= depth[grasp].max() - PRESS_BAND]
    q_half = q_open + SQUEEZE_CLOSURE * (q_grasp - q_open)
    tips = (hand.fingertip_positions(q_half[None])[0].double().cpu().numpy() - origin) @ rotation
    squeeze = tips[0] - tips[1:].mean(0)  # one tip per finger, the thumb (or first jaw) first
    closing = (hand.fingertip_positions(q_closing).double().cpu().numpy() - origin) @ rotation
    thumb_tip, other_tips = closing[:, 0], closing[:, 1:].mean(1)
    return ToolFrame(
        rotation,
        origin,
        depth.max(axis=1),
        rotation.T @ (tip.mean(0) - origin),
        float(np.arctan2(squeeze[1], squeeze[0])),
        np.linalg.norm(thumb_tip - other_tips, axis=1),
        0.5 * (thumb_tip + other_tips),
    )


def tool_frame(hand: HandModel) -> ToolFrame:
    """The hand's tool frame (cached per hand model)."""
    return _tool_frame_cached(hand)
