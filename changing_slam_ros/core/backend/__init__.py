"""Back-end optimisation with gtsam: local bundle adjustment (local_ba) and pose graphs (pose_graph)."""
