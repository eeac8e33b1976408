"""A turning camera against a known path on real images (issue 51, item 4): a calibrated video
warped by ``K R(t) K⁻¹`` (mocapdb/evaluation/moving_camera.py), detected and reconstructed as the
still video is, and scored: the camera's rotation per frame, the roots (pelvis) in one world against
the still video's, the feet's height above the floor against the still video's, the world's pitch
and roll. The turned video is reconstructed twice: with its camera path (what `reconstruct` does
with `detect`'s output) and without it (its ``camera_path.json`` left out: as before the path).

    .venv/bin/python tools/eval_moving_camera.py real --db demo/sample.db \\
        --video ../shared/data/videos/pose2sim_balancing/cam01.mp4 \\
        --calibration ../shared/data/pose2sim_balancing/calibration.toml --camera cam_01 --work /tmp/turned

BlazePose (full) detects the people, its keypoints carry the detector's 3D, the focal is the
calibration's (``--focal``) for the engine and for the background's rotation; the rotation is also
measured as `detect` does with no focal given (the 26 mm default, then the focal the turn shows), and
as `live` does (the path known so far; measured on every frame and on every ``LIVE_EVERY``-th, the
frames between extrapolated), on the video and on every 3rd of its frames (a turn 3 times as fast).

Synthetic takes with the truth per frame (eval --world's scenarios, the held-out clips given, nothing
given to the world), filmed by a camera that pans, tilts and rolls, then also walks:

    .venv/bin/python tools/eval_moving_camera.py synthetic --db demo/sample.db ../shared/data/cmu_bvh/006_*.bvh
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.core.cameras import read_calibration_toml  # noqa: E402
from mocapdb.core.formats.camera_path import CAMERA_PATH_FILE, rotation_angle_deg  # noqa: E402
from mocapdb.core.formats.database_reader import load_database  # noqa: E402
from mocapdb.detect.camera_motion import LIVE_EVERY, BackgroundMotion  # noqa: E402
from mocapdb.detect.detectors import open_detector  # noqa: E402
from mocapdb.detect.openpose_out import detect_video  # noqa: E402
from mocapdb.detect.options import DEFAULT_BLAZEPOSE, DEFAULT_CONF, DEFAULT_INPUT_SIZE, DEFAULT_IOU  # noqa: E402
from mocapdb.detect.tracked import FastPath  # noqa: E402
from mocapdb.detect.video import VideoReader  # noqa: E402
from mocapdb.evaluation.heldout import load_heldout  # noqa: E402
from mocapdb.evaluation.moving_camera import (  # noqa: E402
    TARGET_FEET_CM,
    TARGET_ROOT_M,
    TARGET_TURN_DEG,
    compare_tracks,
    ease,
    moving_take,
    rotation_errors_deg,
    score_moving,
    seen_from_reference,
    true_path,
    turn_path,
    warp_video,
)
from mocapdb.evaluation.world_takes import WorldConfig, build_take  # noqa: E402


def detect(video: Path, out: Path, focal_px: float | None) -> BackgroundMotion:
    """`mocapdb detect`'s run (BlazePose, every frame) with the camera path measured at ``focal_px``."""
    model = open_detector(None, DEFAULT_BLAZEPOSE, conf=DEFAULT_CONF, iou=DEFAULT_IOU, max_people=None,
                          input_size=DEFAULT_INPUT_SIZE, fast=FastPath(crops=False))
    motion = BackgroundMotion(focal_px)
    reader = VideoReader(str(video))
    try:
        detect_video(reader, model, out, watchers=[motion])
    finally:
        reader.close()
    return motion


def frames_with_people(video: Path, keypoint_folder: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """The video's frames (BGR) with their people as detected into ``keypoint_folder`` (``[P, K, 3]``)."""
    from mocapdb.core.formats.openpose import read_raw_folder

    out = []
    capture = cv2.VideoCapture(str(video))
    for persons in read_raw_folder(keypoint_folder):
        ok, image = capture.read()
        if not ok:
            break
        out.append((image, np.array([p.raw for p in persons]).reshape(len(persons), -1, 3)))
    capture.release()
    return out


def path_at_default_focal(frames: list[tuple[np.ndarray, np.ndarray]]) -> BackgroundMotion:
    """The background's rotation as `detect` measures it, no focal given (the 26 mm default, then
    the focal the turn shows), the people masked as detected."""
    motion = BackgroundMotion()
    for number, (image, people) in enumerate(frames):
        motion.see(number, image, people)
    return motion


def live_errors_deg(frames: list[tuple[np.ndarray, np.ndarray]], truth: np.ndarray, focal_px: float, every: int,
                    step: int) -> np.ndarray:
    """``[N]`` the angle (degrees) between the true rotation and the one `live` uses on each frame (the
    path known so far, measured every ``every``-th frame), on every ``step``-th frame of the video (a
    turn ``step`` times as fast per frame)."""
    motion = BackgroundMotion(focal_px, history=False, every=every)
    errors = []
    for number, at in enumerate(range(0, len(frames), step)):
        motion.see(number, *frames[at])
        errors.append(float(rotation_angle_deg(motion.rotations[-1] @ truth[at].T)))
    return np.array(errors)


def reconstruct(db: str, keypoints: Path, out: Path, focal_px: float, fps: float) -> dict:
    """`mocapdb reconstruct` into ``out`` (BVH and CSV on the floor); its world.json."""
    subprocess.run([sys.executable, "-m", "mocapdb", "reconstruct", str(keypoints), "--db", db, "--out", str(out),
                    "--focal", f"{focal_px:.3f}", "--fps", f"{fps:g}", "--format", "bvh,csv"],
                   check=True, stdout=subprocess.DEVNULL)
    return json.loads((out / "world.json").read_text())


def real(args: argparse.Namespace) -> int:
    """The calibrated video warped (module docstring): its table."""
    cam = read_calibration_toml(args.calibration)[args.camera]
    focal = float((cam.K[0, 0] + cam.K[1, 1]) / 2.0)
    frames = int(cv2.VideoCapture(str(args.video)).get(cv2.CAP_PROP_FRAME_COUNT))
    fps = float(cv2.VideoCapture(str(args.video)).get(cv2.CAP_PROP_FPS))
    truth = turn_path(frames, *args.turn)
    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    turned = work / "turned.mp4"
    warp_video(args.video, turned, cam.K, truth)
    still_motion = detect(args.video, work / "kp_still", focal)
    turned_motion = detect(turned, work / "kp_turned", focal)
    turned_frames = frames_with_people(turned, work / "kp_turned")
    default_motion = path_at_default_focal(turned_frames)
    without = work / "kp_turned_without_path"
    shutil.rmtree(without, ignore_errors=True)
    shutil.copytree(work / "kp_turned", without, ignore=shutil.ignore_patterns(CAMERA_PATH_FILE))
    worlds = {"still video": reconstruct(args.db, work / "kp_still", work / "out_still", focal, fps),
              "turned, without its path": reconstruct(args.db, without, work / "out_nopath", focal, fps),
              "turned, camera path": reconstruct(args.db, work / "kp_turned", work / "out_path", focal, fps)}
    outs = {"turned, without its path": work / "out_nopath", "turned, camera path": work / "out_path"}
    still_path = still_motion.path()
    print(f"{args.video.name} ({args.camera}, {frames} frames, focal {focal:.0f} px), turned pan/tilt/roll "
          f"{args.turn[0]:g}/{args.turn[1]:g}/{args.turn[2]:g} deg (largest {rotation_angle_deg(truth).max():.2f} deg)")
    print(f"still video's path: still={still_path.still}, largest turn {still_path.turn_deg().max():.3f} deg")
    for name, motion in (("calibrated focal", turned_motion), ("no focal given", default_motion)):
        errors = rotation_errors_deg(motion.path(), truth)
        path = motion.path()
        print(f"turned video's rotation per frame ({name}, {path.focal_px:.0f} px): error median "
              f"{np.median(errors):.3f}"
              f" / max {errors.max():.3f} deg (target {TARGET_TURN_DEG:g}); residual median "
              f"{np.nanmedian(path.residual_px):.2f} px; frames flagged moved {int(path.moved.sum())}")
    for step in (1, 3):
        for every in sorted({1, LIVE_EVERY}):
            errors = live_errors_deg(turned_frames, truth, focal, every, step)
            print(f"live's rotation per frame (calibrated focal), measured every {every} frame(s), every {step} "
                  f"frame(s) of the video taken: error median {np.median(errors):.3f} / max {errors.max():.3f} deg")
    print()
    print("| run | pitch / roll (deg) | root vs still: median / max (m) | lower ankle vs still: median / p95 (cm) |")
    print("|---|---|---|---|")
    for name, world in worlds.items():
        camera = world["camera"]
        cells = "| |"
        if name in outs:
            c = compare_tracks(outs[name], work / "out_still")
            cells = (f"| {c['root_median_m']:.3f} / {c['root_max_m']:.3f} | {c['feet_median_cm']:.1f} / "
                     f"{c['feet_p95_cm']:.1f} |") if c["tracks"] else "| no common track | |"
        print(f"| {name} | {camera['pitch_deg']:.1f} / {camera['roll_deg']:.1f} {cells}")
    print(f"\ntargets: roots within {TARGET_ROOT_M:g} m, feet within {TARGET_FEET_CM:g} cm, rotation within "
          f"{TARGET_TURN_DEG:g} deg")
    return 0




def synthetic(args: argparse.Namespace) -> int:
    """eval --world's takes filmed by a turning (and walking) camera: roots, feet and the world's tilt
    against the truth, without the path, with the true path, and with a walk the path cannot undo."""
    db = load_database(args.db)
    config = WorldConfig(repeats=args.repeats)
    truths = load_heldout(args.bvh, config.fps)
    runs: dict[str, dict[str, list[float]]] = {}
    for index, scenario in enumerate(config.scenarios):
        for repeat in range(config.repeats):
            take = build_take(truths, scenario, index, repeat, config)
            n = len(take.frames)
            turns = turn_path(n, *args.turn)
            walk = ease(n)[:, None] * [args.walk, 0.0, 0.0]
            path = true_path(turns, config)
            turned = moving_take(take, turns, np.zeros((n, 3)), config, index)
            walked = moving_take(take, turns, walk, config, index)
            for name, run in (("still camera", take), ("turned, without its path", turned),
                              ("turned, its true path", seen_from_reference(turned, path)),
                              (f"turned and walked {args.walk:g} m, its true path", seen_from_reference(walked, path))):
                for given in (False, True):
                    scores = score_moving(db, run, take, config, take.camera.height_m if given else None)
                    row = f"{name}, {'camera height given' if given else 'nothing given'}"
                    for key, values in scores.items():
                        runs.setdefault(row, {}).setdefault(key, []).extend(values)
    print(f"{len(config.scenarios) * config.repeats} takes (eval --world's scenarios, {config.frames} frames at "
          f"{config.fps:g} fps, focal {config.focal_px:g} px), turn pan/tilt/roll {args.turn[0]:g}/{args.turn[1]:g}/"
          f"{args.turn[2]:g} deg\n")
    print("| run | root error median / worst (m) | feet off their surface median / worst (cm) | pitch / roll off, "
          "median (deg) |")
    print("|---|---|---|---|")
    for name, r in runs.items():
        root, feet = np.array(r["root_m"]), np.array(r["feet_cm"])
        print(f"| {name} | {np.nanmedian(root):.2f} / {np.nanmax(root):.2f} | {np.nanmedian(feet):.1f} / "
              f"{np.nanmax(feet):.1f} | {np.median(r['pitch_deg']):.1f} / {np.median(r['roll_deg']):.1f} |")
    print(f"\ntargets: roots within {TARGET_ROOT_M:g} m, feet within {TARGET_FEET_CM:g} cm")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("real", help="a calibrated video warped by a known turn")
    p.add_argument("--db", required=True)
    p.add_argument("--video", required=True, type=Path)
    p.add_argument("--calibration", required=True, type=Path)
    p.add_argument("--camera", required=True, help="the video's camera in the calibration")
    p.add_argument("--work", required=True, type=Path, help="a folder for the videos, keypoints and outputs")
    p.add_argument("--turn", nargs=3, type=float, default=(6.0, 3.0, 3.0), metavar=("PAN", "TILT", "ROLL"),
                   help="the turn's pan, tilt and roll (degrees; default 6 3 3)")
    p.set_defaults(run=real)
    p = sub.add_parser("synthetic", help="eval --world's takes filmed by a turning, walking camera")
    p.add_argument("--db", required=True)
    p.add_argument("bvh", nargs="+", type=Path, help="held-out BVH clips (e.g. ../shared/data/cmu_bvh/007_*.bvh)")
    p.add_argument("--repeats", type=int, default=2, help="takes per scenario (default 2)")
    p.add_argument("--turn", nargs=3, type=float, default=(15.0, 5.0, 5.0), metavar=("PAN", "TILT", "ROLL"),
                   help="the turn's pan, tilt and roll (degrees; default 15 5 5)")
    p.add_argument("--walk", type=float, default=0.5, help="the camera's walk to its right (metres; default 0.5)")
    p.set_defaults(run=synthetic)
    args = parser.parse_args()
    return args.run(args)


if __name__ == "__main__":
    raise SystemExit(main())
