"""Cross-embodiment LeRobotDatasets: reading hand layouts, merging per-hand datasets, latent caches."""
