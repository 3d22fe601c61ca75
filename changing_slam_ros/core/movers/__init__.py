"""Class-agnostic moving objects (Dai et al. 2021): point correlation, its optimiser, the Delaunay graph,
object tracking by object-level BA, mover tracking, volume-overlap merging and keyframe segmentation."""
