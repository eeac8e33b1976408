"""How well reconstructions explain their input: re-projection error per track and a picture.

    python tools/reprojection_figure.py data/sample_keypoints/pose2sim_cam01 \
        --result demo/reconstruction/result.jsonl --result demo/published/result.jsonl \
        --label refined --label "published (--no-refine)" \
        --focal 1681 --image-size 1088x1920 --frames 10,50,90 --png docs/reprojection_pose2sim.png

For every output person of every frame, the 14 camera-aligned joints are projected through the
pinhole camera (``--focal``, principal point at the centre of ``--image-size``) and compared with
the input person they lie nearest to, over that person's confident keypoints (≥ 0.3). The error
is the mean distance in pixels divided by the height of those keypoints' box (%). Prints mean and
median per result and track; draws the chosen frames (input keypoints grey, re-projected
skeletons in colour, one colour per track). Needs matplotlib (the ``tools`` extra).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.core.formats.keypoints import CONFIDENCE_THRESHOLD  # noqa: E402
from mocapdb.core.formats.openpose import read_openpose_folder  # noqa: E402
from mocapdb.core.skeleton import DRAWING_LINES, N_KEYPOINTS_2D  # noqa: E402
from mocapdb.evaluation.heldout import project  # noqa: E402

COLOURS = ("tab:red", "tab:blue", "tab:green", "tab:orange", "tab:purple")


def read_results(path: Path) -> dict[int, list[dict]]:
    """Frame index → people records of a result stream."""
    frames = {}
    with open(path, encoding="utf-8") as f:
        for line in f:
            record = json.loads(line)
            if "people" in record:
                frames[record["frame"]] = record["people"]
    return frames


def person_errors(joints: np.ndarray, people: list, focal: float, size: tuple[int, int]) -> tuple[float, int]:
    """Error (% of box height) of camera-aligned ``joints [15, 3]`` against the nearest input person."""
    px = project(joints[None, :N_KEYPOINTS_2D], focal, size)[0]
    best, best_i = np.inf, -1
    for i, person in enumerate(people):
        seen = person.confidence >= CONFIDENCE_THRESHOLD
        if seen.sum() < 2:
            continue
        box = np.ptp(person.points_px[seen, 1])
        error = 100.0 * np.linalg.norm(px[seen] - person.points_px[seen], axis=-1).mean() / max(box, 1.0)
        if error < best:
            best, best_i = error, i
    return best, best_i


def table(inputs: dict, results: list[dict], labels: list[str], focal: float, size: tuple[int, int]) -> str:
    lines = [f"{'result':<28} {'track':>5} {'frames':>6} {'mean %':>7} {'median %':>8}"]
    for label, frames in zip(labels, results):
        per_track: dict[int, list[float]] = {}
        for index, people in frames.items():
            for person in people:
                error, _ = person_errors(np.array(person["joints"]), inputs[index].people, focal, size)
                per_track.setdefault(person["track"], []).append(error)
        for track, errors in sorted(per_track.items()):
            lines.append(f"{label:<28} {track:>5} {len(errors):>6} {np.mean(errors):>7.2f} {np.median(errors):>8.2f}")
    return "\n".join(lines)


def draw(inputs: dict, results: list[dict], labels: list[str], frames: list[int], focal: float,
         size: tuple[int, int], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    view = _crop(inputs, frames, size)
    fig, axes = plt.subplots(len(results), len(frames), figsize=(3.4 * len(frames), 3.6 * len(results)),
                             squeeze=False)
    for row, (label, result) in enumerate(zip(labels, results)):
        for col, index in enumerate(frames):
            ax = axes[row, col]
            for person in inputs[index].people:
                seen = person.confidence >= CONFIDENCE_THRESHOLD
                ax.scatter(*person.points_px[seen].T, s=14, c="0.45", zorder=3)
            for person in result.get(index, []):
                joints = np.array(person["joints"])
                px = project(joints[None, :N_KEYPOINTS_2D], focal, size)[0]
                colour = COLOURS[person["track"] % len(COLOURS)]
                for a, b in DRAWING_LINES:
                    ax.plot(px[[a, b], 0], px[[a, b], 1], c=colour, lw=2)
                error, _ = person_errors(joints, inputs[index].people, focal, size)
                ax.text(px[1, 0], px[1, 1] - 40, f"track {person['track']}: {error:.1f} %", color=colour, fontsize=8)
            ax.set_xlim(*view[0])
            ax.set_ylim(view[1][1], view[1][0])
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{label}, frame {index}", fontsize=9)
    fig.suptitle("input keypoints (grey) and the 3D output re-projected (colour, per track)", fontsize=10)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=90)


def _crop(inputs: dict, frames: list[int], size: tuple[int, int], margin: float = 0.15) -> tuple:
    """x and y limits (pixels) around every confident input keypoint of ``frames``, within the image."""
    points = np.concatenate([p.points_px[p.confidence >= CONFIDENCE_THRESHOLD]
                             for i in frames for p in inputs[i].people])
    lo, hi = points.min(axis=0), points.max(axis=0)
    pad = margin * (hi - lo).max()
    return ((max(lo[0] - pad, 0), min(hi[0] + pad, size[0])), (max(lo[1] - pad, 0), min(hi[1] + pad, size[1])))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("keypoints", type=Path, help="the OpenPose JSON folder that was reconstructed")
    ap.add_argument("--result", type=Path, action="append", required=True, help="result.jsonl (repeatable)")
    ap.add_argument("--label", action="append", help="a name per --result")
    ap.add_argument("--focal", type=float, required=True, help="focal length used, pixels")
    ap.add_argument("--image-size", required=True, help="WIDTHxHEIGHT used, pixels")
    ap.add_argument("--frames", default="10,50,90", help="frames to draw (default 10,50,90)")
    ap.add_argument("--png", type=Path, help="write the picture here")
    args = ap.parse_args()
    size = tuple(int(v) for v in args.image_size.lower().split("x"))
    labels = args.label or [p.parent.name for p in args.result]
    inputs = {frame.index: frame for frame in read_openpose_folder(args.keypoints)}
    results = [read_results(p) for p in args.result]
    print(table(inputs, results, labels, args.focal, size))
    if args.png:
        draw(inputs, results, labels, [int(f) for f in args.frames.split(",")], args.focal, size, args.png)
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
