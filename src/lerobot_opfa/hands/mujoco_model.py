"""A hand as a MuJoCo model ready to simulate: position actuators on the actuated joints and joint
equalities for the couplings and fixed joints (the spec is the authority; mimic tags and the model's own
actuators, joint equalities, tendons and contact pairs are replaced so that simulation and `HandModel` FK
agree), the bodies placed so that MuJoCo's world frame is the documented hand frame, keyframes for the
spec's poses, and no self-collision."""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.universal import UNIVERSAL_INDEX, UNIVERSAL_JOINTS

# Position-servo stiffness per joint kind (N m / rad and N / m); damping is 10 % of it.
DEFAULT_KP = {"revolute": 2.0, "prismatic": 400.0}
# Rotor inertia added to every joint whose model gives none: finger links weigh grams, and without it
# the servos' damping makes their dynamics too stiff for a 2 ms step.
DEFAULT_ARMATURE = 1e-3
# Joint limits as stiff as a 2 ms step allows (MuJoCo's safe minimum time constant is two steps): at its
# default 0.02 s a drawer's handle pushed Shadow's thumb 11 % and SVH's 10 % of their range past their
# stops, readings no real hand gives and training refuses; at 0.004 s no expert goes 1 % past.
LIMIT_SOLREF = [0.004, 1.0]
# Contact bits: hand geoms touch everything with the default bits (tables, objects) but not each other;
# primitive links overlap at their joints, and real hands' mechanics keep fingers apart.
HAND_CONTYPE, HAND_CONAFFINITY = 2, 1


def hand_mjspec(hand: HandModel, kp: dict[str, float] | None = None) -> mujoco.MjSpec:
    """The hand's model as an `MjSpec` (edit it further, attach it to a scene, or `.compile()` it)."""
    kp = {**DEFAULT_KP, **(kp or {})}
    spec = mujoco.MjSpec.from_string(hand.model_file.mujoco_xml, assets=hand.model_file.mujoco_assets)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    for joint in spec.joints:
        joint.armature = joint.armature or DEFAULT_ARMATURE
        joint.solref_limit = LIMIT_SOLREF
        # The servos below bring their own damping; a vendor's joint damping and friction are tuned for its
        # own actuators (example-robot-data's Allegro: 10 N m of friction) and would stall them.
        joint.damping, joint.frictionloss = [0.0, 0.0, 0.0], 0.0
    for actuator in list(spec.actuators):
        spec.delete(actuator)
    for equality in list(spec.equalities):
        if equality.type == mujoco.mjtEq.mjEQ_JOINT:
            spec.delete(equality)
    for element in [*spec.tendons, *spec.pairs]:  # vendor tendon couplings and explicit self-contacts
        spec.delete(element)
    for size in ("njmax", "nconmax", "nstack", *(a for a in dir(spec) if a.startswith("nuser_"))):
        setattr(spec, size, -1)  # sizes are the scene's to set (MuJoCo's default -1: as needed)
    for i, joint in enumerate(hand.joint_names):
        kind = UNIVERSAL_JOINTS[UNIVERSAL_INDEX[hand.universal_names[i]]].kind
        actuator = spec.add_actuator(name=f"act_{joint}", target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        actuator.set_to_position(kp=kp[kind], kv=0.1 * kp[kind])
        actuator.ctrlrange = [float(hand.lower[i]), float(hand.upper[i])]
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    _place_in_hand_frame(spec, hand)
    for joint, value in hand.spec.fixed.items():
        spec.add_equality(
            name=f"fix_{joint}",
            type=mujoco.mjtEq.mjEQ_JOINT,
            objtype=mujoco.mjtObj.mjOBJ_JOINT,
            name1=joint,
            data=[value] + [0.0] * (mujoco.mjNEQDATA - 1),  # no joint2: joint1 = data[0]
        )
    for coupling in hand.spec.couplings.values():
        spec.add_equality(
            name=f"couple_{coupling.joint}",
            type=mujoco.mjtEq.mjEQ_JOINT,
            objtype=mujoco.mjtObj.mjOBJ_JOINT,
            name1=coupling.joint,
            name2=coupling.source,
            # joint1 = data[0] + data[1] * joint2 (MuJoCo's polynomial coupling)
            data=[coupling.offset, coupling.scale] + [0.0] * (mujoco.mjNEQDATA - 2),
        )
    # Keyframes for the named poses, coupled joints included: a simulation started from qpos = 0 would
    # begin with couplings (and limits that exclude 0) violated.
    model = spec.compile()
    for pose in hand.spec.poses:
        q_pose = hand.pose(pose)
        q_all = hand.expand(q_pose[None])[0].double().cpu().numpy()
        qpos = model.qpos0.copy()
        for name, value in zip(hand.chain_joint_names, q_all, strict=True):
            qpos[model.jnt_qposadr[model.joint(name).id]] = value
        spec.add_key(name=pose, qpos=qpos.tolist(), ctrl=q_pose.double().cpu().tolist())
    for geom in spec.geoms:
        if geom.contype or geom.conaffinity:
            geom.contype, geom.conaffinity = HAND_CONTYPE, HAND_CONAFFINITY
    return spec


def _place_in_hand_frame(spec: mujoco.MjSpec, hand: HandModel) -> None:
    """Re-pose the model's top-level bodies by the spec's `base`, so MuJoCo's world is the hand frame."""
    if hand.base_transform is None:
        return
    transform = hand.base_transform.numpy()
    compiled = spec.compile()
    rotation = np.zeros(4)
    mujoco.mju_mat2Quat(rotation, transform[:3, :3].flatten())
    top_level = [i for i in range(1, compiled.nbody) if compiled.body_parentid[i] == 0]  # in spec order
    for body, index in zip(spec.worldbody.bodies, top_level, strict=True):
        quat = np.zeros(4)
        mujoco.mju_mulQuat(quat, rotation, compiled.body_quat[index])
        body.pos = transform[:3, :3] @ compiled.body_pos[index] + transform[:3, 3]
        body.quat = quat
        body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
