"""Finger angles and gestures on real hand photos: the hand landmark model through mocapdb's pipeline.

    python tools/eval_fingers.py [PHOTO_OR_FOLDER ...] [--hand-model full|lite]     (default: data/sample_hands, full)

Per photo and hand found: the curl of each finger and the thumb's three flexions (degrees), the
gesture they give (:mod:`mocapdb.evaluation.gestures`) and, where the photo's name starts with a
gesture (``pointing_2.jpg``), whether a hand shows it. Needs ``mocapdb models fetch hands``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mocapdb.core.fingers import curl_deg, flexion_deg  # noqa: E402
from mocapdb.detect.model_store import blazepose_paths, hand_landmark_path  # noqa: E402
from mocapdb.detect.options import DEFAULT_HAND_MODEL, HAND_MODELS  # noqa: E402
from mocapdb.evaluation.gestures import GESTURES, classify, photo_hands  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "sample_hands"
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png")


def expected_gesture(path: Path) -> str | None:
    """The gesture a photo's name starts with (``thumb_up_1.jpg`` → ``thumb_up``), else None."""
    return next((g for g in sorted(GESTURES, key=len, reverse=True) if path.stem.startswith(g)), None)


def add_hand_model_option(parser: argparse.ArgumentParser) -> None:
    """``--hand-model full|lite``: the hand landmark model the tool runs (``detect``/``live --hand-model``)."""
    parser.add_argument("--hand-model", choices=HAND_MODELS, default=DEFAULT_HAND_MODEL,
                        help="hand landmark model (default %(default)s)")


def photos(paths: list[str]) -> list[Path]:
    found: list[Path] = []
    for given in map(Path, paths or [str(SAMPLE)]):
        found += sorted(p for p in given.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES) if given.is_dir() else [given]
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("photos", nargs="*", help="photos or folders of photos (default data/sample_hands)")
    add_hand_model_option(parser)
    args = parser.parse_args()
    pose, hand = blazepose_paths("full"), hand_landmark_path(args.hand_model)
    right = total = 0
    print("photo | hand | presence | curl thumb, index, middle, ring, pinky | thumb CMC, MCP, IP | gesture")
    for path in photos(args.photos):
        image = cv2.imread(str(path))
        if image is None:
            print(f"{path}: not an image OpenCV reads", file=sys.stderr)
            return 2
        hands = photo_hands(image, pose, hand)
        gestures = [classify(points) for _, points, _ in hands]
        for (label, points, presence), gesture in zip(hands, gestures):
            flexion = flexion_deg(points)
            curls = ", ".join(f"{c:.0f}" for c in curl_deg(flexion))
            thumb = ", ".join(f"{a:.0f}" for a in flexion[0])
            print(f"{path.name} | {label} | {presence:.2f} | {curls} | {thumb} | {gesture}")
        expected = expected_gesture(path)
        if expected is not None:
            total += 1
            right += expected in gestures
            print(f"{path.name}: expected {expected}, {'found' if expected in gestures else 'NOT found'}"
                  + ("" if hands else " (no hand found)"))
    if total:
        print(f"gestures recognised: {right} of {total} photos")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
