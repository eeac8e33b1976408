"""The feet's yaw on the balancing take, each camera alone, against the 4 cameras' triangulation of BlazePose's
own heels, foot tips, hips and shoulders (issue 49, item 3; mocapdb/evaluation/foot_yaw.py).

    .venv/bin/python tools/eval_foot_yaw.py [--work /tmp/footeval] [--db demo/sample.db]

BlazePose runs as for the head (tools/eval_head.py: its folders in ``--work`` are reused), then ``mocapdb
reconstruct --rig humanoid --people main --view-frame`` per camera. Prints two Markdown tables
(docs/benchmarks.md): each foot's yaw against the hips, and the feet's and the hips' own headings as the camera
sees them.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np
from eval_head import CALIBRATION, CAMERAS, detected

from mocapdb.core.cameras import read_calibration_toml
from mocapdb.evaluation.foot_yaw import (
    REFERENCE_POINTS,
    azimuths,
    bvh_points,
    foot_yaws,
    format_table,
    score,
    view_points,
)
from mocapdb.evaluation.head_turn import triangulated_points
from mocapdb.evaluation.real_take import focal_px

WORLD_UP = np.array([0.0, 0.0, 1.0])   # the calibration's world: z up


def view_frame_bvh(folder: Path, out: Path, db: Path, focal: float) -> Path:
    """The main person's humanoid BVH, in the camera's view frame, of ``mocapdb reconstruct`` on one camera's folder."""
    subprocess.run([sys.executable, "-m", "mocapdb", "reconstruct", str(folder), "--db", str(db), "--out", str(out),
                    "--format", "bvh", "--rig", "humanoid", "--people", "main", "--view-frame",
                    "--focal", f"{focal:.2f}", "-q"], check=True, stdout=subprocess.DEVNULL)
    return next(iter(sorted(out.glob("track_*.bvh"))))


def aligned(values: np.ndarray, frames: int) -> np.ndarray:
    """A BVH's per-frame ``values`` on the input's ``frames`` (BVH frame k is input frame k - 1; NaN past its end)."""
    out = np.full((frames,) + values.shape[1:], np.nan)
    out[:len(values) - 1] = values[1:frames + 1]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/footeval"), help="detections and reconstructions")
    parser.add_argument("--db", type=Path, default=Path("demo/sample.db"))
    args = parser.parse_args()
    cams = read_calibration_toml(CALIBRATION)
    folders = [detected(args.work, name) for name in CAMERAS]
    reference = triangulated_points(folders, [cams[n] for n in CAMERAS], REFERENCE_POINTS)
    yaws, headings = {}, {}
    for name, folder in zip(CAMERAS, folders):
        points = aligned(bvh_points(view_frame_bvh(folder, args.work / f"out_{name}", args.db,
                                                   focal_px(cams[name]))), len(reference))
        yaws[name] = score(foot_yaws(points), foot_yaws(reference))
        up = view_points(WORLD_UP, cams[name]) - view_points(np.zeros(3), cams[name])
        headings[name] = score(azimuths(points, up), azimuths(view_points(reference, cams[name]), up),
                               ("right foot", "left foot", "hips"))
    print(format_table(yaws, "foot yaw against the hips"))
    print()
    print(format_table(headings, "heading as the camera sees it"))


if __name__ == "__main__":
    main()
