"""Feature keys lerobot-opfa adds to LeRobot's, on the ground floor: the simulator, the datasets and the
policy all name them, and none of them should import another for a string."""

OBS_POINTCLOUD = "observation.pointcloud"
OBS_EMBODIMENT = "observation.embodiment"
"""A merged dataset's per-frame hand index (its feature names list the hands)."""
OBS_HAND = "observation.hand"
"""Name of the hand an env observation comes from (set by the `opfa` env's processor; not a tensor)."""


def batch_embodiments(ids):
    """(B,) embodiment ids of a batch's `OBS_EMBODIMENT` of shape (B,), (B, 1) or (B, n_obs_steps): the
    latest frame's (a history never mixes hands)."""
    return ids.reshape(len(ids), -1)[:, -1].long()
