"""Arms: the kinematics that carry a hand's wrist to a pose and back."""
