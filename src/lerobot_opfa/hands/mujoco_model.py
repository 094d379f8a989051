"""A hand as a MuJoCo model ready to simulate: position actuators on the actuated joints and joint
equalities for the couplings (the spec is the authority; mimic tags and the model's own actuators and
joint equalities are replaced so that simulation and `HandModel` FK agree), keyframes for the spec's poses,
and no self-collision."""

from __future__ import annotations

import mujoco

from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.universal import UNIVERSAL_INDEX, UNIVERSAL_JOINTS

# Position-servo stiffness per joint kind (N m / rad and N / m); damping is 10 % of it.
DEFAULT_KP = {"revolute": 2.0, "prismatic": 400.0}
# Rotor inertia added to every joint whose model gives none: finger links weigh grams, and without it
# the servos' damping makes their dynamics too stiff for a 2 ms step.
DEFAULT_ARMATURE = 1e-3
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
    for actuator in list(spec.actuators):
        spec.delete(actuator)
    for equality in list(spec.equalities):
        if equality.type == mujoco.mjtEq.mjEQ_JOINT:
            spec.delete(equality)
    for i, joint in enumerate(hand.joint_names):
        kind = UNIVERSAL_JOINTS[UNIVERSAL_INDEX[hand.universal_names[i]]].kind
        actuator = spec.add_actuator(name=f"act_{joint}", target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        actuator.set_to_position(kp=kp[kind], kv=0.1 * kp[kind])
        actuator.ctrlrange = [float(hand.lower[i]), float(hand.upper[i])]
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
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
