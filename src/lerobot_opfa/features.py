"""Feature keys lerobot-opfa adds to LeRobot's, on the ground floor: the simulator, the datasets and the
policy all name them, and none of them should import another for a string."""

OBS_POINTCLOUD = "observation.pointcloud"
OBS_EMBODIMENT = "observation.embodiment"
"""A merged dataset's per-frame hand index (its feature names list the hands)."""
OBS_HAND = "observation.hand"
"""Name of the hand an env observation comes from (set by the `opfa` env's processor; not a tensor)."""


def frame_embodiments(ids, slots: int = 1):
    """(B, slots) embodiment ids of a batch's latest frame, from `OBS_EMBODIMENT` of shape (B,), (B, slots)
    or (B, n_obs_steps, slots) (a history never mixes hands). A policy has one hand slot per frame today."""
    rows = ids.reshape(len(ids), -1)
    if rows.shape[-1] % slots or (ids.dim() == 3 and ids.shape[-1] != slots):
        raise ValueError(f"{OBS_EMBODIMENT} of shape {tuple(ids.shape)} does not hold {slots} hand slot(s)")
    return rows[:, -slots:].long()


def single_slot(ids):
    """(B,) embodiments of frames with one hand slot, from (B, slots) ids: a policy with one hand slot does
    not read a second hand's frames as its first."""
    if ids.dim() != 2 or ids.shape[-1] != 1:
        raise ValueError(
            f"{OBS_EMBODIMENT} holds {tuple(ids.shape)} ids: this policy acts for one hand per frame"
        )
    return ids[:, 0]
