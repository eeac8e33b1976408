"""A real take before and after the whole-take fit: re-projection, side view on the floor, the feet.

    python tools/take_figure.py data/sample_keypoints/pose2sim_cam01 --db demo/sample.db \\
        --fps 60 --focal 1681 --image-size 1088x1920 --png docs/take_before_after.png

Runs the engine over an OpenPose folder, takes its longest moving track, and draws (the input's
keypoints stand in for the video frame, which the bundled sample does not hold):

* top: three frames, the input keypoints (grey) and the per-frame output (the stream, red) and the
  whole take (what `reconstruct` writes as track files, blue) projected back;
* middle: the same frames from the side, on the floor the whole take found (y = 0);
* bottom: each ankle's horizontal position (distance travelled from its start) and height over the
  take, per frame and whole take: a planted foot should stay flat.

Prints the mean joint acceleration and the ankles' horizontal speed while the whole take holds them
planted, for both.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.core import domains as D  # noqa: E402
from mocapdb.core.formats.database_reader import load_database  # noqa: E402
from mocapdb.core.formats.openpose import read_openpose_folder  # noqa: E402
from mocapdb.core.skeleton import DRAWING_LINES, N_POINTS, swing_matrices  # noqa: E402
from mocapdb.evaluation.heldout import project  # noqa: E402
from mocapdb.runtime.engine import Engine  # noqa: E402
from mocapdb.runtime.engine_config import EngineConfig  # noqa: E402
from mocapdb.runtime.foot_contacts import ANKLES  # noqa: E402
from mocapdb.runtime.take import fit_take, take_joints  # noqa: E402


def run(args: argparse.Namespace) -> dict:
    """Per-frame and whole-take joints (camera-aligned) of the longest moving track, the input, the floor."""
    frames = list(read_openpose_folder(args.keypoints))
    size = args.image_size
    engine = Engine(load_database(args.db), EngineConfig(fps=args.fps, focal_px=args.focal, image_size=size,
                                                         keep_take=True))
    per_frame: dict[int, np.ndarray] = {}
    for i, frame in enumerate(frames):
        for pose in engine.step(frame):
            per_frame.setdefault(pose.track, np.full((len(frames), N_POINTS, 3), np.nan))[i] = pose.joints_m
    recordings = {r.track: r for r in engine.finish() if not r.static}
    track = max(recordings, key=lambda t: len(recordings[t].quaternions))
    fitted, result = fit_take(recordings[track], args.fps)
    index, joints, _ = take_joints(fitted, args.fps)
    whole = np.full((len(frames), N_POINTS, 3), np.nan)
    whole[index] = joints
    people = [f.people for f in frames]
    return {"per_frame": per_frame[track], "whole": whole, "people": people, "size": size,
            "normal": fitted.up_view, "offset": fitted.floor_offset_m, "planted": result.planted,
            "first": recordings[track].first_frame}


def _on_floor(joints: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Camera-aligned joints → the floor's frame (y up from the floor, x across, z in depth)."""
    view = joints * [1.0, 1.0, -1.0]
    level = swing_matrices(normal / np.linalg.norm(normal), np.array([0.0, 1.0, 0.0]))
    return view @ level.T - [0.0, offset, 0.0]


def draw(data: dict, args: argparse.Namespace) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [int(round(x)) for x in np.linspace(0.1, 0.9, 3) * (len(data["whole"]) - 1)]
    fig = plt.figure(figsize=(12, 13))
    outputs = (("per frame (stream)", data["per_frame"], "tab:red"), ("whole take (track files)", data["whole"],
                                                                       "tab:blue"))
    for col, i in enumerate(shown):
        ax = fig.add_subplot(3, 3, col + 1)
        for person in data["people"][i]:
            seen = person.confidence > 0.3
            ax.scatter(*person.points_px[seen].T, s=10, c="0.6")
        for label, joints, colour in outputs:
            px = project(joints[i], args.focal, data["size"])
            for a, b in DRAWING_LINES:
                ax.plot(*px[[a, b]].T, c=colour, lw=1.5, label=label if (a, b) == DRAWING_LINES[0] else None)
        ax.set_xlim(0, data["size"][0])
        ax.set_ylim(data["size"][1], 0)
        ax.set_aspect("equal")
        ax.set_title(f"frame {i}: keypoints (grey), re-projected")
        if col == 0:
            ax.legend(loc="lower left", fontsize=8)
        side = fig.add_subplot(3, 3, col + 4)
        for label, joints, colour in outputs:
            floor = _on_floor(joints[i], data["normal"], data["offset"])
            for a, b in DRAWING_LINES:
                side.plot(floor[[a, b], 2], floor[[a, b], 1], c=colour, lw=1.5)
        side.axhline(0.0, c="k", lw=1)
        side.set_aspect("equal")
        side.set_xlabel("depth (m)")
        side.set_ylabel("height above the floor (m)")
        side.set_title(f"frame {i}: side view on the floor")
    t = np.arange(len(data["whole"])) / args.fps
    for k, name in enumerate(("right", "left")):
        ax = fig.add_subplot(3, 2, 5 + k)
        for label, joints, colour in outputs:
            ankle = _on_floor(joints[:, ANKLES[k]], data["normal"], data["offset"])
            start = ankle[np.flatnonzero(np.isfinite(ankle[:, 0]))[0]]
            ax.plot(t, np.linalg.norm(ankle[:, [0, 2]] - start[[0, 2]], axis=-1), c=colour, label=f"{label}: travel")
            ax.plot(t, ankle[:, 1], c=colour, ls="--", label=f"{label}: height")
        planted = np.zeros(len(t), dtype=bool)
        planted[data["first"]:data["first"] + len(data["planted"])] = data["planted"][:, k]
        ax.fill_between(t, 0, 1, where=planted, transform=ax.get_xaxis_transform(), color="0.9")
        ax.set_xlabel("time (s); grey: planted (whole take)")
        ax.set_ylabel("metres")
        ax.set_title(f"{name} ankle: horizontal travel and height")
        ax.legend(fontsize=7)
    fig.subplots_adjust(left=0.07, right=0.98, top=0.96, bottom=0.05, hspace=0.35, wspace=0.3)
    fig.savefig(args.png, dpi=80)


def report(data: dict, fps: float) -> None:
    planted = np.zeros((len(data["whole"]), 2), dtype=bool)
    planted[data["first"]:data["first"] + len(data["planted"])] = data["planted"]
    for label in ("per_frame", "whole"):
        joints = data[label]
        accel = np.nanmean(np.linalg.norm(np.diff(joints, 2, axis=0), axis=-1)) * 1000
        ankles = _on_floor(joints[:, ANKLES], data["normal"], data["offset"])
        speed = np.linalg.norm(np.gradient(ankles[..., [0, 2]], axis=0), axis=-1) * fps
        print(f"{label:>9}: mean joint acceleration {accel:.1f} mm/frame², planted-ankle horizontal speed "
              f"{100 * np.nanmean(speed[planted]):.1f} cm/s (median {100 * np.nanmedian(speed[planted]):.1f})")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("keypoints", help="folder of OpenPose JSON frames")
    ap.add_argument("--db", required=True)
    ap.add_argument("--fps", type=float, required=True)
    ap.add_argument("--focal", type=float, required=True, help="pixels")
    ap.add_argument("--image-size", type=D.IMAGE_SIZE, required=True, metavar="WxH")
    ap.add_argument("--png", default="take_before_after.png")
    args = ap.parse_args()
    data = run(args)
    report(data, args.fps)
    draw(data, args)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
