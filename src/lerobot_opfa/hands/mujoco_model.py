"""A hand as a MuJoCo model ready to simulate: position actuators on the actuated joints and joint
equalities for the couplings (the spec is the authority; mimic tags and the model's own actuators and
joint equalities are replaced so that simulation and `HandModel` FK agree), and no contacts between
links that share a joint (MuJoCo skips those only when the parent is not fixed to the world)."""

from __future__ import annotations

import mujoco

from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.universal import UNIVERSAL_INDEX, UNIVERSAL_JOINTS

# Position-servo stiffness per joint kind (N m / rad and N / m); damping is 10 % of it.
DEFAULT_KP = {"revolute": 2.0, "prismatic": 400.0}


def hand_mjspec(hand: HandModel, kp: dict[str, float] | None = None) -> mujoco.MjSpec:
    """The hand's model as an `MjSpec` (edit it further, attach it to a scene, or `.compile()` it)."""
    kp = {**DEFAULT_KP, **(kp or {})}
    spec = mujoco.MjSpec.from_string(hand.model_file.mujoco_xml, assets=hand.model_file.mujoco_assets)
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
    for body in spec.bodies:
        parent = body.parent
        if parent is not None and parent.name and parent.name != "world":
            spec.add_exclude(bodyname1=parent.name, bodyname2=body.name)
    return spec
