"""The map (ORB-SLAM3's Atlas): keyframes, map points, the multi-map SlamMap and the keyframe database."""
