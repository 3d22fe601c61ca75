"""The SLAM threads (ORB-SLAM3's Tracking, LocalMapping, LoopClosing): tracking, local mapping, triangulation,
place recognition, geometric verification, loop closing, map merging and fusion, provisional points."""
