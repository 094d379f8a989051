"""GaLR: geometry-aware latent representation of end-effector states (stage 1 of OPFA)."""
