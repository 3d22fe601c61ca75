"""Dynamic scenes (Changing-SLAM sec. 3.1-3.3): the COCO detector, keypoint classification dynamic / movable /
static, short-term association, object EKFs, the dynamic filter, late detections and their refinement."""
