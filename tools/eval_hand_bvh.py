"""Finger bend angles from the humanoid BVH against the hand points they were measured from.

    python tools/eval_hand_bvh.py [PHOTO_OR_FOLDER ...]     (default: data/sample_hands)

Per hand (each hand found in the photos, and MediaPipe's own landmarks of its four test photos): the
gesture of its points and of the hand the BVH's forward kinematics gives back
(:func:`mocapdb.evaluation.hand_bvh.bvh_hand_points`), then per finger the flexion at its three joints
(degrees; :func:`mocapdb.core.fingers.flexion_deg`) from the points' 2D + z and from the BVH; last, the
median and largest differences per joint over all hands. Needs ``mocapdb models fetch hands``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_fingers import SAMPLE, photos  # noqa: E402

from mocapdb.core.fingers import FINGERS, flexion_deg  # noqa: E402
from mocapdb.detect.model_store import blazepose_paths, hand_landmark_path  # noqa: E402
from mocapdb.evaluation.gestures import classify, photo_hands  # noqa: E402
from mocapdb.evaluation.hand_bvh import bvh_hand_points, side_of  # noqa: E402


def hands(paths: list[str]) -> list[tuple[str, str, np.ndarray]]:
    """(name, side, points [21, 3]) of every hand found in the photos and of MediaPipe's landmarks."""
    pose, hand = blazepose_paths("full"), hand_landmark_path()
    found = []
    for path in photos(paths):
        for label, points, _ in photo_hands(cv2.imread(str(path)), pose, hand):
            side = {"right": "Right", "left": "Left"}.get(label.rsplit("_", 1)[-1]) or side_of(points)
            found.append((f"{path.name} {label}", side, points))
    landmarks = json.loads((SAMPLE / "mediapipe_world_landmarks.json").read_text())["hands"]
    found += [(f"mediapipe {name}", side_of(np.array(p)), np.array(p)) for name, p in landmarks.items()]
    return found


def main() -> int:
    differences = []
    for name, side, points in hands(sys.argv[1:]):
        rebuilt = bvh_hand_points(side, points)
        measured, from_bvh = flexion_deg(points), flexion_deg(rebuilt)
        differences.append(from_bvh - measured)
        print(f"{name} ({side}): gesture {classify(points)} -> BVH {classify(rebuilt)}")
        for f, finger in enumerate(FINGERS):
            print(f"  {finger:6s} points {np.round(measured[f]).astype(int)}  BVH {np.round(from_bvh[f]).astype(int)}")
    error = np.abs(np.array(differences))
    print(f"{len(error)} hands; |BVH - points| flexion, degrees, joints 1/2/3 (thumb CMC/MCP/IP; others MCP/PIP/DIP):")
    for f, finger in enumerate(FINGERS):
        median, largest = np.round(np.median(error[:, f], axis=0), 1), np.round(error[:, f].max(axis=0), 1)
        print(f"  {finger:6s} median {median}  max {largest}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
