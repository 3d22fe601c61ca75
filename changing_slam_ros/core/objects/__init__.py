"""Changing scenes (Changing-SLAM sec. 3.4-3.6): MapObjects, the persistence filter, long-term association,
visibility, point weights, box completion, the semantic map and the object layer that runs them."""
