"""The universal keypoints' order: 14 image keypoints, then the pelvis (a leaf: geometry and skeleton
both read it). The skeleton built on them: :mod:`mocapdb.core.skeleton`, ``data_specs/skeleton.md``."""
from __future__ import annotations

# The 14 keypoints in OpenPose COCO-18 order (its first 14), then the pelvis (mid-hip).
KEYPOINTS: tuple[str, ...] = (
    "head", "neck", "r_shoulder", "r_elbow", "r_wrist", "l_shoulder", "l_elbow", "l_wrist",
    "r_hip", "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "pelvis")
N_KEYPOINTS_2D = 14
KP = {name: i for i, name in enumerate(KEYPOINTS)}
