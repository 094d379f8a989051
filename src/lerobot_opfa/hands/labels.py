"""Link labels from the kinematic tree, so that a vendor's model with dozens of anonymous links needs no
hand-written `links` table.

A finger is the subtree below its root: the spec's `fingers` entry (a joint or link), else the child link
of the topmost moving joint whose subtree moves only that finger's joints, as their universal names say (a
coupled joint counts as its source's). A link's segment is the number of moving joints (actuated or
coupled) between its finger's root and it; links in no finger are the palm (0, 0). The spec's `links`
overrides any label; a link that moves but lies in no finger is an error, since only the spec can say
which finger it is (a gripper's jaws, whose joints are the palm's).
"""

from __future__ import annotations

import pytorch_kinematics as pk

from lerobot_opfa.hands.spec import HandSpec, HandSpecError
from lerobot_opfa.hands.universal import FINGERS, UNIVERSAL_INDEX, UNIVERSAL_JOINTS


def tree_labels(spec: HandSpec, chain: pk.Chain, geometry_links: set[str]) -> dict[str, tuple[int, int]]:
    """[finger, segment] of each link with geometry that the spec's `links` leaves out (null included),
    in the model's order; needs a spec whose joints match the model (`HandSpec.check_joints`)."""
    names = [chain.idx_to_frame[f] for f in range(len(chain.parents_indices))]
    paths = [[int(a) for a in path] for path in chain.parents_indices]  # root ... frame, parents first
    chain_joints = chain.get_joint_parameter_names()
    joint_frames = {chain_joints[j]: f for f, j in enumerate(chain.joint_indices.tolist()) if j >= 0}
    # The joint into each frame where it moves with the actuated joints (not fixed, not held), else None.
    moving = {f: joint for joint, f in joint_frames.items() if joint not in spec.fixed}
    joint_fingers = _joint_fingers(spec)
    below: list[set[int]] = [set() for _ in names]  # fingers whose joints move within each frame's subtree
    for f, path in enumerate(paths):
        if moving.get(f) in joint_fingers:
            for a in path:
                below[a].add(joint_fingers[moving[f]])

    given = _given_roots(spec, names, joint_frames)
    misplaced = [
        f"'{moving[f]}' ({FINGERS[joint_fingers[moving[f]]]}) below the {FINGERS[given[a]]}'s root"
        for f, path in enumerate(paths)
        if moving.get(f) in joint_fingers
        for a in path
        if given.get(a, joint_fingers[moving[f]]) != joint_fingers[moving[f]]
    ]
    if misplaced:
        raise HandSpecError(
            spec.path, "fingers", f"joint(s) {', '.join(misplaced)}: check each finger's root"
        )
    roots = dict(given)
    for f, path in enumerate(paths):
        only = next(iter(below[f])) if f in moving and len(below[f]) == 1 else None
        if only is not None and only not in given.values() and not any(roots.get(a) == only for a in path):
            roots[f] = only

    labels, unplaced = {}, {}
    for f, path in enumerate(paths):
        if names[f] not in geometry_links or names[f] in spec.links or names[f] in spec.ignored_links:
            continue
        root = next((a for a in reversed(path) if a in roots), None)
        if root is None and any(a in moving for a in path):
            unplaced[names[f]] = [moving[a] for a in path if a in moving]
        elif root is None:
            labels[names[f]] = (0, 0)
        else:
            labels[names[f]] = (roots[root], sum(a in moving for a in path[path.index(root) + 1 :]))
    if unplaced:
        joints = sorted({j for js in unplaced.values() for j in js}, key=chain_joints.index)
        raise HandSpecError(
            spec.path,
            "links",
            f"link(s) {sorted(unplaced)} carry geometry but have no [finger, segment] label, and the "
            f"kinematic tree does not tell their finger: joint(s) {joints} move them, and no single finger's "
            "universal joints lie below; name each finger's first joint or link in `fingers` (finger: name), "
            "or label the links in `links` (null: not the hand)",
        )
    return labels


def _joint_fingers(spec: HandSpec) -> dict[str, int]:
    """Model joint -> the finger (u >= 1) its universal name says; a coupled joint is its source's. Palm and
    gripper joints say none."""
    fingers = {joint: UNIVERSAL_JOINTS[UNIVERSAL_INDEX[u]].finger for joint, u in spec.joints.items()}
    for joint, coupling in spec.couplings.items():  # sources come first
        fingers[joint] = fingers.get(coupling.source, 0)
    return {joint: u for joint, u in fingers.items() if u > 0}


def _given_roots(spec: HandSpec, names: list[str], joint_frames: dict[str, int]) -> dict[int, int]:
    """The spec's `fingers` as frame -> finger: a link is its own frame, a joint the frame of its child."""
    roots = {}
    for finger, root in spec.finger_roots.items():
        frame = names.index(root) if root in names else joint_frames.get(root)
        if frame is None:
            raise HandSpecError(
                spec.path,
                f"fingers.{FINGERS[finger]}",
                f"'{root}' is neither a movable joint nor a link of the model; its movable joints are "
                f"{list(joint_frames)}",
            )
        roots[frame] = finger
    return roots
