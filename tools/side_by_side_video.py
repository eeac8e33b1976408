"""Several real videos side by side in one frame: a many-people video for the detector benchmarks.

    python tools/side_by_side_video.py OUT.mp4 VIDEO [VIDEO ...] [--size 1920x1080] [--crop-left PX ...]

Each input is scaled to the output's height and placed left to right (centred, black around);
``--crop-left`` cuts that many pixels off each input's left side first (a bystander at the edge).
The output has as many frames as the shortest input, at the first input's frame rate (MPEG-4).
Used for `tools/bench_video.py`'s three-person figure (docs/detectors.md).
"""
from __future__ import annotations

import argparse

import cv2
import numpy as np


def compose(frames: list[np.ndarray], size_wh: tuple[int, int], crops: list[int]) -> np.ndarray:
    """The frames scaled to the height of ``size_wh`` and laid side by side, centred on black."""
    width, height = size_wh
    parts = []
    for frame, crop in zip(frames, crops):
        frame = frame[:, crop:]
        scale = height / frame.shape[0]
        parts.append(cv2.resize(frame, (round(frame.shape[1] * scale), height), interpolation=cv2.INTER_AREA))
    row = np.hstack(parts)[:, :width]
    canvas = np.zeros((height, width, 3), dtype=np.uint8)
    x0 = (width - row.shape[1]) // 2
    canvas[:, x0:x0 + row.shape[1]] = row
    return canvas


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("videos", nargs="+")
    ap.add_argument("--size", default="1920x1080", help="output WxH, pixels (default 1920x1080)")
    ap.add_argument("--crop-left", type=int, nargs="*", default=[], help="pixels cut off each input's left side")
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.lower().split("x"))
    crops = args.crop_left + [0] * (len(args.videos) - len(args.crop_left))
    captures = [cv2.VideoCapture(v) for v in args.videos]
    fps = captures[0].get(cv2.CAP_PROP_FPS) or 30.0
    writer = cv2.VideoWriter(args.out, cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    written = 0
    while True:
        reads = [c.read() for c in captures]
        if not all(ok for ok, _ in reads):
            break
        writer.write(compose([f for _, f in reads], size, crops))
        written += 1
    writer.release()
    print(f"wrote {args.out}: {written} frames, {size[0]}x{size[1]} at {fps:g} fps")
    return 0 if written else 1


if __name__ == "__main__":
    raise SystemExit(main())
