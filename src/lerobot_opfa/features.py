"""Feature keys lerobot-opfa adds to LeRobot's, on the ground floor: the simulator, the datasets and the
policy all name them, and none of them should import another for a string."""

OBS_POINTCLOUD = "observation.pointcloud"
OBS_EMBODIMENT = "observation.embodiment"
"""A merged dataset's per-frame hand index (its feature names list the hands)."""
ROBOT_TYPE = "robot_type"
"""LeRobot's name for a robot's type in an observation batch (`prepare_observation_for_inference`): the
complementary data that says which robot a frame comes from (`policy/robot_type.py`)."""


def frame_embodiments(ids, slots: int = 1):
    """(B, slots) embodiment ids of a batch's latest frame, from `OBS_EMBODIMENT` of shape (B,), (B, slots),
    (B, n_obs_steps) (a one-slot history) or (B, n_obs_steps, slots). A row whose one-slot history names
    several hands is two hands per frame, or a history that mixes hands: refused, not read as its last."""
    rows = ids.reshape(len(ids), -1, slots)
    if (rows != rows[:, -1:]).any():
        raise ValueError(
            f"{OBS_EMBODIMENT} of shape {tuple(ids.shape)} names several hands in one row: this policy has "
            f"{slots} hand slot(s) per frame, and a frame's history never changes hands"
        )
    return rows[:, -1].long()


def column_embodiments(ids, blocks: list[int]):
    """(B, D) embodiment of each entry of a policy vector, from (B, slots) ids: `blocks` = [body width, then
    one width per hand slot]. The body's entries are the first slot's (its robot's), a slot's entries its
    own hand's. Empty `blocks` (a step saved before slots): every entry the first slot's."""
    if not blocks:
        return ids[:, :1]
    if ids.dim() != 2 or ids.shape[-1] != len(blocks) - 1:
        raise ValueError(
            f"{OBS_EMBODIMENT} holds {tuple(ids.shape)} ids: this policy acts for {len(blocks) - 1} hand(s) "
            "per frame"
        )
    owners = [0, *range(len(blocks) - 1)]
    return ids[:, [owner for owner, width in zip(owners, blocks, strict=True) for _ in range(width)]]
