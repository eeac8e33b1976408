"""Where a person's stature error comes from when the camera height is given: the world's tilt, or
the track's own evidence (its contacts against its body). Each person is sized twice: as the world
found it, and on the true floor (the true camera height and tilt, `floor_stature_m`). What is left
on the true floor is the track's own; the rest is the world's tilt.

Synthetic takes (`mocapdb eval --world`'s scenarios; per role, signed medians):

    .venv/bin/python tools/stature_sources.py --db eval.db --world ../shared/data/cmu_bvh/007_*.bvh

A calibrated real take, each camera alone (its longest track against the triangulation's stature):

    .venv/bin/python tools/stature_sources.py --db demo/sample.db --fps 60 \\
        --calibration ../shared/data/pose2sim_balancing/calibration.toml \\
        --trc ../shared/data/pose2sim_balancing/triangulated_4cam.trc cam_01=kp/cam01 cam_02=kp/cam02
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel, read_calibration_toml
from mocapdb.core.errors import MocapdbError
from mocapdb.core.formats.database_reader import MotionDatabase, load_database
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.core.formats.trc import read_trc, trc_keypoints
from mocapdb.core.outputs import TrackRecording
from mocapdb.core.skeleton import bone_lengths_m, stature_m
from mocapdb.evaluation.heldout import load_heldout
from mocapdb.evaluation.real_take import focal_px
from mocapdb.evaluation.world import track_fit
from mocapdb.evaluation.world_camera import VIEW_FROM_OPENCV, true_camera
from mocapdb.evaluation.world_scores import match_tracks
from mocapdb.evaluation.world_takes import WorldConfig, build_take
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.take import fit_take
from mocapdb.runtime.world.fuse import (
    TrackEvidence,
    World,
    estimate_world,
    floor_stature_m,
    place_in_world,
    track_evidence,
)


def sized_in_world(db: MotionDatabase, frames: list[KeypointFrame], config: EngineConfig
                   ) -> tuple[list[tuple[TrackRecording, TrackRecording]], list[TrackEvidence], World]:
    """The frames through the engine and the whole take with the camera height given
    (``config.camera_height_m``): the fitted tracks (placed in the world), their evidence and the world."""
    engine = Engine(db, config.for_track_files())
    for frame in frames:
        engine.step(frame)
    recordings = engine.finish()
    fits = [fit_take(rec, config.fps) for rec in recordings]
    evidence = [track_evidence(rec, result, config.fps) for rec, result in fits]
    world = estimate_world(evidence, config.camera_height_m)
    placed = [(rec, place_in_world(fitted, world, config.fps)) for rec, (fitted, _) in zip(recordings, fits)]
    return placed, evidence, world


def synthetic_rows(db: MotionDatabase, heldout: list[Path], config: WorldConfig) -> list[tuple[str, float, float]]:
    """Per person of every take with a grounded track (camera height given): role, stature error (%)
    as the world found it and on the true floor."""
    truths = load_heldout(heldout, config.fps)
    rows = []
    for i, scenario in enumerate(config.scenarios):
        for r in range(config.repeats):
            take = build_take(truths, scenario, i, r, config)
            engine = replace(config.engine, fps=config.fps, focal_px=config.focal_px, image_size=config.image_size,
                             camera_height_m=take.camera.height_m)
            placed, evidence, world = sized_in_world(db, take.frames, engine)
            fits = [track_fit(rec, fitted, config.fps) for rec, fitted in placed]
            for e, owner in zip(evidence, match_tracks(fits, take.people, config.focal_px, config.image_size)):
                if owner is None or not len(e.contacts_m):
                    continue
                person = take.people[owner]
                on_truth = floor_stature_m(e, take.camera.up_view(), take.camera.height_m - person.spec.support_m)
                rows.append((person.spec.role, 100 * (world.people[e.track].stature_m / person.stature_m - 1),
                             100 * (on_truth / person.stature_m - 1)))
    return rows


def synthetic_table(rows: list[tuple[str, float, float]]) -> list[str]:
    """The per-role medians of :func:`synthetic_rows` as a Markdown table."""
    lines = ["| role | people | found: signed / absolute median | on the true floor: signed / absolute median |",
             "|---|---|---|---|"]
    for role in dict.fromkeys([r for r, _, _ in rows] + ["all"]):
        found = np.array([f for r, f, _ in rows if role in (r, "all")])
        truth = np.array([t for r, _, t in rows if role in (r, "all")])
        truth = truth[np.isfinite(truth)]
        lines.append(f"| {role} | {len(found)} | {np.median(found):+.1f} / {np.median(np.abs(found)):.1f} % | "
                     f"{np.median(truth):+.1f} / {np.median(np.abs(truth)):.1f} % |")
    return lines


def real_lines(db: MotionDatabase, cams: dict[str, CameraModel], trc_path: Path, fps: float, cameras: list[str]
               ) -> list[str]:
    """Per camera ``NAME=FOLDER``: its longest track's stature error (%) as the world found it and on
    the true floor (the calibration's), against the triangulation's median stature."""
    true_stature = float(np.median(stature_m(bone_lengths_m(trc_keypoints(read_trc(trc_path))))))
    lines = [f"Triangulated stature {true_stature:.3f} m.", "",
             "| camera | found: stature, error | world pitch / truth | on the true floor: stature, error |",
             "|---|---|---|---|"]
    for spec in cameras:
        name, _, folder = spec.partition("=")
        cam = cams[name]
        truth = true_camera(cam)
        config = EngineConfig(fps=fps, focal_px=focal_px(cam), image_size=(cam.size[0], cam.size[1]),
                              camera_height_m=truth["height_m"])
        normal = cam.R[:, 2] * VIEW_FROM_OPENCV
        placed, evidence, world = sized_in_world(db, list(read_openpose_folder(Path(folder), fps=fps)), config)
        main = max(range(len(placed)), key=lambda k: len(placed[k][0]))
        found = world.people[evidence[main].track].stature_m
        on_truth = floor_stature_m(evidence[main], normal, truth["height_m"])
        lines.append(f"| {name} | {found:.3f} m, {100 * (found / true_stature - 1):+.1f} % | "
                     f"{world.pitch_deg:.1f}° / {truth['pitch_deg']:.1f}° | "
                     f"{on_truth:.3f} m, {100 * (on_truth / true_stature - 1):+.1f} % |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", required=True, help="the motion database (Parquet folder)")
    parser.add_argument("--world", nargs="+", type=Path, metavar="HELDOUT", help="held-out BVH clips: synthetic takes")
    parser.add_argument("--repeats", type=int, default=10, help="synthetic takes per scenario (default 10)")
    parser.add_argument("--calibration", type=Path, help="a Pose2Sim calibration.toml (z up, metres)")
    parser.add_argument("--trc", type=Path, help="the take's triangulation (its stature is the truth)")
    parser.add_argument("--fps", type=float, help="the keypoints' frame rate (Hz)")
    parser.add_argument("cameras", nargs="*", metavar="NAME=FOLDER", help="a calibration camera and its keypoints")
    args = parser.parse_args()
    if not args.world and not args.cameras:
        parser.error("give --world HELDOUT… or NAME=FOLDER cameras (with --calibration, --trc, --fps)")
    if args.cameras and not (args.calibration and args.trc and args.fps):
        parser.error("cameras need --calibration, --trc and --fps")
    try:
        cams = read_calibration_toml(args.calibration) if args.cameras else {}
        for spec in args.cameras:
            name, _, folder = spec.partition("=")
            if name not in cams or not folder:
                parser.error(f"{spec}: expected NAME=FOLDER with NAME one of {', '.join(sorted(cams))}")
        db = load_database(args.db)
        if args.world:
            print("\n".join(synthetic_table(synthetic_rows(db, args.world, WorldConfig(repeats=args.repeats)))))
        if args.cameras:
            print("\n".join(real_lines(db, cams, args.trc, args.fps, args.cameras)))
    except MocapdbError as exc:   # an unreadable database, clip, calibration, TRC or keypoint folder
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
