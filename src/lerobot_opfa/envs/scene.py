"""The MuJoCo scene shared by every task: a table, cameras, and a floating 6-DoF wrist (three slides and
three hinges with position servos, gravity-compensated) carrying any registered hand in its tool frame;
two of them, named `left/...` and `right/...`, for two hands."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from lerobot_opfa.envs.toolframe import ToolFrame, tool_frame
from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.mujoco_model import hand_mjspec

TIMESTEP = 0.002
TABLE_HALF = (0.45, 0.40, 0.025)  # table top at z = 0
WRIST_JOINTS = ("wrist_x", "wrist_y", "wrist_z", "wrist_yaw", "wrist_pitch", "wrist_roll")
WRIST_RANGE = np.array([[-0.4, 0.4], [-0.4, 0.4], [0.0, 0.6], [-np.pi, np.pi], [-1.2, 1.2], [-1.2, 1.2]])
# Wrist servos: the carriage plus the heaviest hand is about 1.5 kg and 0.02 kg m^2; these gains give a
# response in tens of milliseconds, damped close to critically.
WRIST_KP = (3000.0, 3000.0, 3000.0, 150.0, 150.0, 150.0)
WRIST_KV = (150.0, 150.0, 150.0, 6.0, 6.0, 6.0)
WRIST_FORCE = (150.0, 150.0, 150.0, 20.0, 20.0, 20.0)
HOME = np.array([-0.05, 0.0, 0.30, 0.0, 0.0, 0.0])
OBJECT_FRICTION = (1.5, 0.02, 0.002)
# Depth cameras by name (each added to the model as `depth_<name>`); envs use `front` unless told otherwise.
DEPTH_CAMERAS = {"front": (-0.50, 0.0, 0.60), "left": (-0.40, 0.38, 0.50), "right": (-0.40, -0.38, 0.50)}
# Depth cameras frame the table top (48 deg); 128x96 pixels then put as many on the objects as 160x120 at
# 60 deg, for two thirds of the render cost under software GL.
DEPTH_FOVY = 48.0
COLLISION_GROUP = 3  # geom group MuJoCo does not draw by default (as in MuJoCo Menagerie models)
# Drawn in pictures only (`OpfaSimEnv.render`): the floor lies below the table, outside every crop, and
# depth cameras skip drawing it (a sixth to a third of a depth render under software GL).
SCENERY_GROUP = 5
# A blind env's task objects (`hide_objects`): they collide and are weighed as before, but no camera, depth
# sensor or geometry cloud sees them (a group MuJoCo hides by default and no view of ours turns on).
HIDDEN_GROUP = 4
RENDER_CAMERA = ("view", (-0.80, -0.35, 0.62))
LOOK_AT = (0.02, 0.0, 0.06)


@dataclass
class Arm:
    """The addresses an env needs to read and drive one arm (a wrist and its hand) of a compiled scene."""

    hand: HandModel
    tool: ToolFrame
    wrist_qpos: np.ndarray  # qpos addresses of the six wrist joints
    wrist_qvel: np.ndarray  # their qvel addresses
    hand_qpos: np.ndarray  # qpos addresses of the hand's actuated joints, in spec order
    chain_qpos: np.ndarray  # qpos addresses of every hand joint, in `hand.chain_joint_names` order
    hand_geoms: np.ndarray  # geom ids of the hand
    ctrl: np.ndarray  # actuator ids of the wrist's six joints, then the hand's, in spec order


@dataclass
class Scene:
    """A compiled scene of one arm (side None) or two (`left`, `right`), and what tasks read of the whole."""

    model: mujoco.MjModel
    arms: dict[str | None, Arm]

    @property
    def hand_geoms(self) -> np.ndarray:
        return np.concatenate([arm.hand_geoms for arm in self.arms.values()])

    @property
    def wrist_qpos(self) -> np.ndarray:
        """Each arm's six wrist joints' qpos addresses, arm by arm."""
        return np.concatenate([arm.wrist_qpos for arm in self.arms.values()])


def look_at(pos: tuple[float, float, float], target: tuple[float, float, float]) -> list[float]:
    """Quaternion of a MuJoCo camera at `pos` looking at `target` (cameras look along -z, y up)."""
    back = np.asarray(pos, float) - np.asarray(target, float)
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.stack([right, up, back], axis=1).ravel())
    return quat.tolist()


def _add_carriage(spec: mujoco.MjSpec, prefix: str = "") -> mujoco.MjsBody:
    """Six nested bodies, one joint each; returns the last (the tool frame, approach axis pointing down)."""
    parent = spec.worldbody
    axes = np.eye(3)
    for i, joint in enumerate(WRIST_JOINTS):
        name = f"{prefix}{joint}"
        body = parent.add_body(name=name, mass=0.05, inertia=[1e-4, 1e-4, 1e-4], gravcomp=1.0)
        kind = mujoco.mjtJoint.mjJNT_SLIDE if i < 3 else mujoco.mjtJoint.mjJNT_HINGE
        # yaw about z, then pitch about y, then roll about x: R = Rz Ry Rx
        axis = axes[i] if i < 3 else axes[(2, 1, 0)[i - 3]]
        body.add_joint(
            name=name,
            type=kind,
            axis=axis.tolist(),
            range=WRIST_RANGE[i].tolist(),
            armature=0.01,
            damping=0.0,
        )
        actuator = spec.add_actuator(
            name=f"{prefix}act_{joint}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT
        )
        actuator.set_to_position(kp=WRIST_KP[i], kv=WRIST_KV[i])
        actuator.ctrlrange = WRIST_RANGE[i].tolist()
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuator.forcerange = [-WRIST_FORCE[i], WRIST_FORCE[i]]
        actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        parent = body
    # the tool's approach axis (+z) points down at zero angles: a half turn about x
    return parent.add_body(name=f"{prefix}tool", quat=[0.0, 1.0, 0.0, 0.0], gravcomp=1.0)


def base_spec() -> mujoco.MjSpec:
    """World, table, lights and cameras; tasks add their objects and `build_scene` the arms."""
    spec = mujoco.MjSpec()
    spec.compiler.degree = False  # joint ranges below are in radians
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    spec.visual.global_.offwidth, spec.visual.global_.offheight = 640, 480
    spec.visual.headlight.ambient = [0.4, 0.4, 0.4]
    world = spec.worldbody
    world.add_light(
        name="sun", pos=[0.0, 0.0, 1.5], dir=[0.2, 0.1, -1.0], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
    )
    world.add_geom(
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1], pos=[0, 0, -0.75],
        rgba=[0.3, 0.33, 0.36, 1], contype=0, conaffinity=0, group=SCENERY_GROUP,
    )  # fmt: skip
    world.add_geom(
        name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(TABLE_HALF), pos=[0, 0, -TABLE_HALF[2]],
        rgba=[0.62, 0.5, 0.38, 1], friction=[1.0, 0.01, 0.001],
    )  # fmt: skip
    for name, pos in DEPTH_CAMERAS.items():
        world.add_camera(name=f"depth_{name}", pos=list(pos), quat=look_at(pos, LOOK_AT), fovy=DEPTH_FOVY)
    world.add_camera(
        name=RENDER_CAMERA[0], pos=list(RENDER_CAMERA[1]), quat=look_at(RENDER_CAMERA[1], LOOK_AT)
    )
    return spec


def build_scene(spec: mujoco.MjSpec, hands: dict[str | None, HandModel]) -> Scene:
    """Mount each side's hand on a wrist carriage of its own (named `<side>/...`; one arm, side None:
    unprefixed), compile, and index the result."""
    prefixes = {side: f"{side}/" if side else "" for side in hands}
    tools = {side: mount_hand(spec, hand, prefixes[side]) for side, hand in hands.items()}
    model = spec.compile()
    return Scene(
        model, {side: index_arm(model, hand, tools[side], prefixes[side]) for side, hand in hands.items()}
    )


def mount_hand(spec: mujoco.MjSpec, hand: HandModel, prefix: str = "") -> ToolFrame:
    """Add a wrist carriage named `prefix...` and the hand on it, in its tool frame (`prefix` + `hand/`)."""
    tool = tool_frame(hand)
    rot, pos = tool.hand_in_tool()
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rot).ravel())
    frame = _add_carriage(spec, prefix).add_frame(pos=pos.tolist(), quat=quat.tolist())
    child = hand_mjspec(hand)
    child.option.integrator = spec.option.integrator  # the scene's options win; say so to avoid a warning
    spec.attach(child, frame=frame, prefix=f"{prefix}hand/")
    hand_bodies = [body for body in spec.bodies if body.name.startswith(f"{prefix}hand/")]
    for body in hand_bodies:
        body.gravcomp = 1.0
    # A hand with visual geoms is seen through them (by cameras and depth sensors alike); its collision
    # geoms go to the group MuJoCo hides by default, so renders do not draw the hand twice.
    geoms = [geom for body in hand_bodies for geom in body.geoms]
    if any(not (geom.contype or geom.conaffinity) for geom in geoms):
        for geom in geoms:
            if geom.contype or geom.conaffinity:
                geom.group = COLLISION_GROUP
    for key in list(spec.keys):  # the hand's keyframes cover only its own joints
        spec.delete(key)
    return tool


def index_arm(model: mujoco.MjModel, hand: HandModel, tool: ToolFrame, prefix: str = "") -> Arm:
    """The addresses of the arm `mount_hand` added under `prefix`, in the compiled `model`."""
    hand_bodies = {i for i in range(model.nbody) if model.body(i).name.startswith(f"{prefix}hand/")}

    def qpos(joints: list[str]) -> np.ndarray:
        return np.array([model.jnt_qposadr[model.joint(j).id] for j in joints])

    wrist = [f"{prefix}{j}" for j in WRIST_JOINTS]

    return Arm(
        hand=hand,
        tool=tool,
        wrist_qpos=qpos(wrist),
        wrist_qvel=np.array([model.jnt_dofadr[model.joint(j).id] for j in wrist]),
        hand_qpos=qpos([f"{prefix}hand/{j}" for j in hand.joint_names]),
        chain_qpos=qpos([f"{prefix}hand/{j}" for j in hand.chain_joint_names]),
        hand_geoms=np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] in hand_bodies]),
        ctrl=np.array(
            [model.actuator(f"{prefix}act_{j}").id for j in WRIST_JOINTS]
            + [model.actuator(f"{prefix}hand/act_{j}").id for j in hand.joint_names]
        ),
    )


def hide_objects(scene: Scene) -> None:
    """Move every geom of the task's objects (all but the hands', the table's and the scenery's) to
    `HIDDEN_GROUP`: the control condition of a policy blind to the object, on the same scene and physics."""
    model = scene.model
    keep = {*scene.hand_geoms.tolist(), model.geom("table").id, model.geom("floor").id}
    for geom in range(model.ngeom):
        if geom not in keep:
            model.geom_group[geom] = HIDDEN_GROUP


def tool_to_world(vector: np.ndarray, yaw: float) -> np.ndarray:
    """A tool-frame vector in the world frame, for the wrist at `yaw` (pitch and roll zero)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ (vector * [1.0, -1.0, -1.0])
