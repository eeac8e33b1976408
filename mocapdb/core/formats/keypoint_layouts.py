"""Keypoint layouts: each input layout's point order and the points it gives the universal 14.

Orders, index tables and the mapping rules: ``data_specs/keypoint_formats.md``.
"""
from __future__ import annotations

_COCO17 = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip",
    "left_knee", "right_knee", "left_ankle", "right_ankle")
_FEET = ("left_big_toe", "left_small_toe", "left_heel", "right_big_toe", "right_small_toe", "right_heel")
_OPENPOSE_BODY = (
    "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist")
_OPENPOSE_FEET = ("LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel")
_OPENPOSE_FACE = ("REye", "LEye", "REar", "LEar")
_OPENPOSE_LEGS = ("RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle")
_MEDIAPIPE33 = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right") + tuple(
    f"{side}_{part}" for part in ("shoulder", "elbow", "wrist", "pinky", "index", "thumb", "hip", "knee",
                                  "ankle", "heel", "foot_index") for side in ("left", "right"))

# Keypoint names of each input layout, in the layout's index order.
LAYOUTS: dict[str, tuple[str, ...]] = {
    "body25": _OPENPOSE_BODY + ("MidHip",) + _OPENPOSE_LEGS + _OPENPOSE_FACE + _OPENPOSE_FEET,
    "body25b": _COCO17 + ("upper_neck", "head_top") + _FEET,
    "coco18": _OPENPOSE_BODY + _OPENPOSE_LEGS + _OPENPOSE_FACE,
    "coco17": _COCO17,
    "halpe26": _COCO17 + ("head", "neck", "hip", "left_big_toe", "right_big_toe", "left_small_toe",
                          "right_small_toe", "left_heel", "right_heel"),
    "wholebody133": _COCO17 + _FEET + tuple(f"face_{i}" for i in range(68))
    + tuple(f"{side}_hand_{i}" for side in ("left", "right") for i in range(21)),
    "mediapipe33": _MEDIAPIPE33,
}
# The layout keypoint giving each universal keypoint (KEYPOINTS[:14] order); None: no such point
# (the neck then comes from the shoulders only; BODY_25B's "upper_neck" is not the mid-shoulder).
_OPENPOSE_SOURCES = _OPENPOSE_BODY + _OPENPOSE_LEGS
_COCO_SOURCES = (
    "nose", None, "right_shoulder", "right_elbow", "right_wrist", "left_shoulder", "left_elbow",
    "left_wrist", "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle")
_SOURCES: dict[str, tuple[str | None, ...]] = {
    "body25": _OPENPOSE_SOURCES, "body25b": _COCO_SOURCES, "coco18": _OPENPOSE_SOURCES,
    "coco17": _COCO_SOURCES, "halpe26": ("nose", "neck") + _COCO_SOURCES[2:],
    "wholebody133": _COCO_SOURCES, "mediapipe33": _COCO_SOURCES}
# Per layout, the index of the source of each universal keypoint; -1: none. Plain tuples: the
# command-line parsers read this module, which therefore imports nothing heavy.
SOURCE_INDEX: dict[str, tuple[int, ...]] = {
    name: tuple(LAYOUTS[name].index(s) if s else -1 for s in sources) for name, sources in _SOURCES.items()}
# The points beyond the universal 14 that drive the feet, hands and head (``data_specs/keypoint_formats.md``,
# "Feet and hands"; ``data_specs/head.md``): per foot the heel and the big toe, per hand the index and
# pinky knuckles, then the face's eyes, ears and mouth corners (the subject's own sides).
EXTREMITIES: tuple[str, ...] = (
    "r_heel", "r_big_toe", "l_heel", "l_big_toe", "r_index", "r_pinky", "l_index", "l_pinky",
    "r_eye", "l_eye", "r_ear", "l_ear", "r_mouth", "l_mouth")
N_FEET_HANDS = 8  # the first rows of EXTREMITIES: the feet's and hands' points; then the face's
_COCO_FEET_SOURCES = ("right_heel", "right_big_toe", "left_heel", "left_big_toe")
_COCO_FACE = ("right_eye", "left_eye", "right_ear", "left_ear", None, None)
_OPENPOSE_FACE_SOURCES = ("REye", "LEye", "REar", "LEar", None, None)
# COCO-WholeBody's face points are the 68 of iBUG 300-W: 48 and 54 the mouth's corners (the subject's right, left)
_EXTREMITY_SOURCES: dict[str, tuple[str | None, ...]] = {
    "body25": ("RHeel", "RBigToe", "LHeel", "LBigToe", None, None, None, None) + _OPENPOSE_FACE_SOURCES,
    "coco18": (None,) * 8 + _OPENPOSE_FACE_SOURCES, "coco17": (None,) * 8 + _COCO_FACE,
    "body25b": _COCO_FEET_SOURCES + (None,) * 4 + _COCO_FACE, "halpe26": _COCO_FEET_SOURCES + (None,) * 4 + _COCO_FACE,
    "wholebody133": _COCO_FEET_SOURCES + ("right_hand_5", "right_hand_17", "left_hand_5", "left_hand_17")
    + _COCO_FACE[:4] + ("face_48", "face_54"),
    "mediapipe33": ("right_heel", "right_foot_index", "left_heel", "left_foot_index",
                    "right_index", "right_pinky", "left_index", "left_pinky",
                    "right_eye", "left_eye", "right_ear", "left_ear", "mouth_right", "mouth_left")}
# Per layout with any of them, the index of the source of each of EXTREMITIES; -1: none.
EXTREMITY_INDEX: dict[str, tuple[int, ...]] = {
    name: tuple(LAYOUTS[name].index(s) if s else -1 for s in sources) for name, sources in _EXTREMITY_SOURCES.items()}
# The layout of each keypoint count that only one layout has (25 is BODY_25 or BODY_25B).
LAYOUT_OF_COUNT: dict[int, str] = {
    len(LAYOUTS[name]): name for name in ("coco17", "coco18", "halpe26", "mediapipe33", "wholebody133")}
