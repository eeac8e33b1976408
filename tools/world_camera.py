"""The world's camera against a calibration on any keypoint folders (e.g. BlazePose's from `mocapdb
detect`), each camera run alone: the table and summary `mocapdb eval --real-take` prints for the
take's own OpenPose keypoints (`mocapdb/evaluation/world_camera.py`).

    for c in 01 02 03 04; do
        .venv/bin/mocapdb detect ../shared/data/videos/pose2sim_balancing/cam$c.mp4 --out kp/cam$c; done
    .venv/bin/python tools/world_camera.py --db demo/sample.db \\
        --calibration ../shared/data/pose2sim_balancing/calibration.toml --fps 60 \\
        cam_01=kp/cam01 cam_02=kp/cam02 cam_03=kp/cam03 cam_04=kp/cam04

With ``--scene`` each folder's ``scene.json`` (the room's lines, which `detect` writes) is scored
too (issue 51): the tilt of the people alone, of the scene's lines alone (no people: the vertical
looked for about the image's up) and of both fused (`reconstruct`'s), and the focal length the
scene's orthogonal vanishing points give against the calibration's. ``--focal scene`` runs the
people and the fused world at that focal (where the scene gives one; else the 26 mm guess), as
`reconstruct` does when nothing gives a focal; ``--focal guess`` at the 26 mm guess.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from mocapdb.cli.scene_evidence import DEFAULT_FOCAL_SD
from mocapdb.core.cameras import read_calibration_toml
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.core.formats.scene import read_scene
from mocapdb.core.formats.take import default_focal_px
from mocapdb.evaluation.real_take import focal_px
from mocapdb.evaluation.world_camera import (
    camera_checks,
    format_rows,
    scene_world,
    score_camera,
    summary_lines,
    tilt_lines,
    tracks_of_frames,
    world_of_tracks,
)
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.world.scene_lines import SceneEvidence, vanishing_points


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", required=True, help="the motion database (Parquet folder)")
    parser.add_argument("--calibration", required=True, type=Path, help="a Pose2Sim calibration.toml (z up, metres)")
    parser.add_argument("--fps", type=float, required=True, help="the keypoints' frame rate (Hz)")
    parser.add_argument("--scene", action="store_true", help="also score each folder's scene.json (module docstring)")
    parser.add_argument("--focal", choices=("calibration", "scene", "guess"), default="calibration",
                        help="the focal the engine and the world run at (default: the calibration's)")
    parser.add_argument("cameras", nargs="+", metavar="NAME=FOLDER", help="a calibration camera and its keypoints")
    args = parser.parse_args()
    cams = read_calibration_toml(args.calibration)
    db = load_database(args.db)
    people, alone, fused, focal_lines = {}, {}, {}, []
    for spec in args.cameras:
        name, _, folder = spec.partition("=")
        if name not in cams or not folder:
            parser.error(f"{spec}: expected NAME=FOLDER with NAME one of {', '.join(sorted(cams))}")
        cam = cams[name]
        size = (int(cam.size[0]), int(cam.size[1]))
        lines = read_scene(folder) if args.scene or args.focal == "scene" else None
        points = None if lines is None else vanishing_points(lines)
        found = None if points is None else points.focal()
        focal, focal_sd = focal_px(cam), 0.0
        if args.focal == "guess" or args.focal == "scene" and found is None:
            focal = default_focal_px(size)
            focal_sd = DEFAULT_FOCAL_SD * focal
        elif args.focal == "scene" and found is not None:
            focal, focal_sd = found.focal_px, found.sd_px
        config = EngineConfig(fps=args.fps, focal_px=focal, image_size=size)
        tracks = tracks_of_frames(db, list(read_openpose_folder(Path(folder), fps=args.fps)), config)
        people[name] = score_camera(world_of_tracks(tracks, config), cam)
        if points is None:
            continue
        evidence = SceneEvidence(points, focal, focal_sd)
        tilt = evidence.tilt(None)
        alone[name] = None if tilt is None else score_camera(scene_world(tilt), cam)
        fused[name] = score_camera(world_of_tracks(tracks, config, evidence), cam)
        truth = focal_px(cam)
        said = "none (no three orthogonal vanishing points)" if found is None else (
            f"{found.focal_px:.0f} px ± {found.sd_px:.0f} / calibration {truth:.0f} px: "
            f"{100 * (found.focal_px / truth - 1):+.1f} %")
        focal_lines.append(f"{name}: scene's focal {said}")
    out = ["People only:"] + format_rows(people) + [""] + summary_lines(people) + camera_checks(people)
    if fused:
        out += ["", "Fused (people and the scene's lines):"] + format_rows(fused) + [""] + summary_lines(fused)
        out += camera_checks(fused) + [""] + tilt_lines("people only", {k: people[k] for k in fused})
        out += tilt_lines("scene alone", alone) + tilt_lines("fused", fused) + [""] + focal_lines
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
