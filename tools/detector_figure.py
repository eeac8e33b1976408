"""Two (or more) detectors' keypoints drawn on the same video frames, one row per detector.

    python tools/detector_figure.py VIDEO --frames 33 50 66 --detector NAME DIR [--detector NAME DIR ...]
                                    [--out docs/detectors_blazepose_yolo.png]

Each DIR is `mocapdb detect`'s output for VIDEO (any layout the keypoint readers know); the limbs
and, where the layout has them, the feet (heel, toes) and hands are drawn for every person, points
below confidence 0.3 left out.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.core.formats.keypoint_layouts import LAYOUT_OF_COUNT, LAYOUTS  # noqa: E402
from mocapdb.core.formats.openpose import read_raw_folder  # noqa: E402

MIN_CONFIDENCE = 0.3
# Limbs by their COCO-17 / MediaPipe names; OpenPose's COCO-18 spelling is mapped below.
LIMBS = [("left_shoulder", "right_shoulder"), ("left_hip", "right_hip")] + [
    (f"{side}_{a}", f"{side}_{b}") for side in ("left", "right") for a, b in (
        ("shoulder", "elbow"), ("elbow", "wrist"), ("shoulder", "hip"), ("hip", "knee"), ("knee", "ankle"),
        ("ankle", "heel"), ("heel", "foot_index"), ("ankle", "foot_index"), ("wrist", "index"), ("wrist", "pinky"))]
COLOURS = {"left": (255, 140, 0), "right": (0, 90, 255), "mid": (40, 200, 40)}   # BGR


def _index(layout: str, name: str) -> int | None:
    names = LAYOUTS[layout]
    if name in names:
        return names.index(name)
    side, _, part = name.partition("_")
    openpose = ("L" if side == "left" else "R") + part.capitalize()
    return names.index(openpose) if openpose in names else None


def draw(image: np.ndarray, people: list[np.ndarray], layout: str) -> np.ndarray:
    """``image`` with each person's limbs and points; thickness scaled to the image."""
    out = image.copy()
    thick = max(2, round(image.shape[0] / 300))
    for raw in people:
        for a, b in LIMBS:
            ia, ib = _index(layout, a), _index(layout, b)
            if ia is None or ib is None or min(raw[ia, 2], raw[ib, 2]) < MIN_CONFIDENCE:
                continue
            side = a.split("_")[0] if a.split("_")[0] == b.split("_")[0] else "mid"
            cv2.line(out, tuple(np.round(raw[ia, :2]).astype(int)), tuple(np.round(raw[ib, :2]).astype(int)),
                     COLOURS[side], thick, cv2.LINE_AA)
        for x, y, c in raw:
            if c >= MIN_CONFIDENCE:
                cv2.circle(out, (round(x), round(y)), thick + 1, (255, 255, 255), -1, cv2.LINE_AA)
    return out


def frames_of(video: str, wanted: list[int]) -> dict[int, np.ndarray]:
    capture, out = cv2.VideoCapture(video), {}
    for index in range(max(wanted) + 1):
        ok, image = capture.read()
        if not ok:
            raise SystemExit(f"{video}: no frame {index}")
        if index in wanted:
            out[index] = image
    capture.release()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("video")
    ap.add_argument("--frames", type=int, nargs="+", required=True)
    ap.add_argument("--detector", nargs=2, action="append", metavar=("NAME", "DIR"), required=True)
    ap.add_argument("--out", default=str(ROOT / "docs" / "detectors_blazepose_yolo.png"))
    args = ap.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    images = frames_of(args.video, args.frames)
    fig, axes = plt.subplots(len(args.detector), len(args.frames), squeeze=False,
                             figsize=(2.6 * len(args.frames), 4.4 * len(args.detector)), dpi=110)
    for row, (name, folder) in enumerate(args.detector):
        frames = read_raw_folder(folder)
        for col, index in enumerate(args.frames):
            people = frames[index]
            layout = (people[0].layout or LAYOUT_OF_COUNT.get(len(people[0].raw))) if people else None
            axes[row, col].imshow(draw(images[index], [p.raw for p in people], layout or "coco18")[..., ::-1])
            axes[row, col].set_title(f"{name}, frame {index}", fontsize=8)
            axes[row, col].axis("off")
    fig.tight_layout()
    fig.savefig(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
