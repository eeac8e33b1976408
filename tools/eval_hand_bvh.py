"""Finger bend angles from the humanoid BVH against the hand points they were measured from.

    python tools/eval_hand_bvh.py [PHOTO_OR_FOLDER ...] [--hand-model full|lite]     (default: data/sample_hands, full)
    python tools/eval_hand_bvh.py --bvh TRACK.bvh             (a humanoid track file's hands over time)

Per hand (each hand found in the photos, and MediaPipe's own landmarks of its four test photos): the
gesture of its points and of the hand the BVH's forward kinematics gives back
(:func:`mocapdb.evaluation.hand_bvh.bvh_hand_points`), then per finger the flexion at its three joints
(degrees; :func:`mocapdb.core.fingers.flexion_deg`) from the points' 2D + z and from the BVH; last, the
median and largest differences per joint over all hands. Needs ``mocapdb models fetch hands``.
With ``--bvh``: per hand, how far its ``…Hand`` joint and its 15 finger joints turn from one frame to the
next (largest, 99th percentile, median; degrees) and from rest (median).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_fingers import SAMPLE, add_hand_model_option, photos  # noqa: E402

from mocapdb.core.fingers import FINGERS, flexion_deg  # noqa: E402
from mocapdb.core.formats.bvh import local_transforms, read_bvh  # noqa: E402
from mocapdb.core.geometry import matrix_to_quat  # noqa: E402
from mocapdb.core.hand_rig import SIDE_NAMES, finger_joint_names  # noqa: E402
from mocapdb.detect.model_store import blazepose_paths, hand_landmark_path  # noqa: E402
from mocapdb.evaluation.gestures import classify, photo_hands  # noqa: E402
from mocapdb.evaluation.hand_bvh import bvh_hand_points, side_of  # noqa: E402


def hands(paths: list[str], hand_model: str) -> list[tuple[str, str, np.ndarray]]:
    """(name, side, points [21, 3]) of every hand the ``hand_model`` landmark model finds in the photos, and of
    MediaPipe's landmarks."""
    pose, hand = blazepose_paths("full"), hand_landmark_path(hand_model)
    found = []
    for path in photos(paths):
        for label, points, _ in photo_hands(cv2.imread(str(path)), pose, hand):
            side = {"right": "Right", "left": "Left"}.get(label.rsplit("_", 1)[-1]) or side_of(points)
            found.append((f"{path.name} {label}", side, points))
    landmarks = json.loads((SAMPLE / "mediapipe_world_landmarks.json").read_text())["hands"]
    found += [(f"mediapipe {name}", side_of(np.array(p)), np.array(p)) for name, p in landmarks.items()]
    return found


def turn_deg(rotations: np.ndarray) -> np.ndarray:
    """The angles (degrees) of rotation matrices ``[..., 3, 3]``."""
    return np.degrees(2.0 * np.arccos(np.clip(np.abs(matrix_to_quat(rotations)[..., 0]), 0.0, 1.0)))


def track_turns(path: str) -> None:
    """Print how the hands and fingers of a humanoid BVH turn (module docstring)."""
    bvh = read_bvh(path)
    for side in SIDE_NAMES:
        for what, names in (("hand", [f"{side}Hand"]), ("fingers", finger_joint_names(side))):
            if not set(names) <= set(bvh.names):
                print(f"{side} {what}: not in the file")
                continue
            local = local_transforms(bvh, np.array([bvh.index(n) for n in names]))[0]
            step = turn_deg(np.swapaxes(local[:-1], -1, -2) @ local[1:])
            print(f"{side} {what}: a frame's turn max {step.max():.1f}, 99th percentile {np.percentile(step, 99):.1f}, "
                  f"median {np.median(step):.2f} deg; from rest median {np.median(turn_deg(local)):.1f} deg")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("photos", nargs="*", help="photos or folders of photos (default data/sample_hands)")
    parser.add_argument("--bvh", metavar="TRACK.bvh", help="a humanoid track file's hands over time instead")
    add_hand_model_option(parser)
    args = parser.parse_args()
    if args.bvh:
        track_turns(args.bvh)
        return 0
    differences = []
    for name, side, points in hands(args.photos, args.hand_model):
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
