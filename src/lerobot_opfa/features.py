"""Feature keys lerobot-opfa adds to LeRobot's, on the ground floor: the simulator, the datasets and the
policy all name them, and none of them should import another for a string."""

OBS_POINTCLOUD = "observation.pointcloud"
OBS_EMBODIMENT = "observation.embodiment"
"""A merged dataset's per-frame hand index (its feature names list the hands)."""
OBS_HAND = "observation.hand"
"""Name of the hand an env observation comes from (set by the `opfa` env's processor; not a tensor)."""


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


def single_slot(ids):
    """(B,) embodiments of frames with one hand slot, from (B, slots) ids: a policy with one hand slot does
    not read a second hand's frames as its first."""
    if ids.dim() != 2 or ids.shape[-1] != 1:
        raise ValueError(
            f"{OBS_EMBODIMENT} holds {tuple(ids.shape)} ids: this policy acts for one hand per frame"
        )
    return ids[:, 0]
