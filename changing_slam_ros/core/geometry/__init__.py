"""Rigid-body geometry: SE(3) helpers, the pinhole camera, motion-only pose optimisation, trajectories."""
