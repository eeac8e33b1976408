"""`mocapdb stereo`: two uncalibrated views → cameras, 3D motion and BVH (ElliPose)."""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from mocapdb.cli import paths as P
from mocapdb.core import domains as D
from mocapdb.core.formats.keypoint_layouts import LAYOUTS

if TYPE_CHECKING:
    from mocapdb.core.cameras import CameraModel


def cameras_from_args(args: argparse.Namespace) -> tuple[CameraModel, CameraModel]:
    """The two cameras' intrinsics from ``--calibration``/``--cameras`` or ``--focal``/``--size``;
    StereoError or CalibrationError naming the option or the file when they cannot be cameras."""
    from mocapdb.core.cameras import camera_from_intrinsics, intrinsics_only, read_calibration_toml
    from mocapdb.stereo import StereoError

    manual = [flag for flag, value in (("--focal", args.focal), ("--size", args.size), ("--center", args.center))
              if value is not None]
    if args.calibration:
        if manual:
            raise StereoError(f"--calibration gives the intrinsics: leave out {', '.join(manual)}")
        cams = read_calibration_toml(args.calibration)
        names = args.cameras or (list(cams) if len(cams) == 2 else None)
        if names is None:
            raise StereoError(f"{args.calibration} holds {len(cams)} cameras ({', '.join(cams)}): "
                              "name two with --cameras")
        missing = [n for n in names if n not in cams]
        if missing:
            raise StereoError(f"{args.calibration} has no camera {', '.join(missing)} (it has {', '.join(cams)})")
        return intrinsics_only(cams[names[0]]), intrinsics_only(cams[names[1]])
    if args.cameras:
        raise StereoError("--cameras names sections of --calibration FILE.toml: give the file too")
    if args.focal is None or args.size is None:
        raise StereoError("give the intrinsics: --calibration FILE.toml --cameras NAME1 NAME2, "
                          "or --focal F --size W H [--center CX CY]")
    size = (int(args.size[0]), int(args.size[1]))
    center = tuple(args.center) if args.center else (size[0] / 2, size[1] / 2)
    return tuple(camera_from_intrinsics(args.focal, center, size) for _ in range(2))  # type: ignore[return-value]


def add_stereo_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``stereo`` subcommand (``run`` returns the exit code)."""
    p = sub.add_parser(
        "stereo", help="two uncalibrated cameras' 2D keypoints → 3D motion (ElliPose), JSON lines and BVH",
        description="Reconstruct everyone filmed by two synchronised cameras whose relative pose is unknown: "
                    "people are matched across the views by epipolar consistency over time, and the camera pose "
                    "is estimated from their bodies (ElliPose: triangulation, ellipsoid correction, "
                    "bone-length consistency). Writes OUT/result.jsonl (camera-aligned frame of camera 1, one "
                    "track per person), OUT/cameras.json (both cameras, the estimated relative pose, the people) "
                    "and one BVH per person: OUT/stereo.bvh for the main person (track 0), "
                    "OUT/stereo_track_<id>.bvh for the others (universal rig, one y-up world). Intrinsics are "
                    "needed; with --calibration only the intrinsics and distortion of the two named cameras are "
                    "used, never their extrinsics.")
    p.add_argument("view1", type=P.INPUT_DIR,
                   help="folder of OpenPose JSON frames from camera 1 (the output's reference)")
    p.add_argument("view2", type=P.INPUT_DIR,
                   help="folder of OpenPose JSON frames from camera 2 (same frames, same rate)")
    p.add_argument("--out", required=True, type=P.OUTPUT_DIR, help="output folder")
    p.add_argument("--calibration", type=P.INPUT_FILE,
                   help="Pose2Sim calibration TOML: intrinsics and distortion of --cameras")
    p.add_argument("--cameras", nargs=2, type=P.TextArg("a camera name"), metavar=("NAME1", "NAME2"),
                   help="section names of the two cameras in --calibration, e.g. cam_01 cam_02")
    p.add_argument("--focal", type=D.FOCAL_PX, help="focal length in pixels (both cameras, no distortion)")
    p.add_argument("--center", type=D.PIXEL_COORDINATE, nargs=2, metavar=("CX", "CY"),
                   help="principal point in pixels (default: the image centre)")
    p.add_argument("--size", type=D.IMAGE_SIDE_PX, nargs=2, metavar=("W", "H"), help="image size in pixels")
    p.add_argument("--camera-distance", type=D.BASELINE_M, metavar="M",
                   help="distance between the cameras in metres, for metric output (default: metres from the "
                        "universal skeleton's leg length)")
    p.add_argument("--fps", type=D.FPS_HZ, default=30.0, help="frame rate of both views in Hz (default 30)")
    p.add_argument("--keypoints", choices=tuple(LAYOUTS), help="keypoint layout of the JSON (default: detected)")
    p.add_argument("--trim", action="store_true",
                   help="when the views' frame counts differ, cut both to the shorter (they must start together)")
    p.set_defaults(run=run_stereo_command)


def run_stereo_command(args: argparse.Namespace) -> int:
    """``mocapdb stereo``: run and print the summary (user errors are reported by the CLI, exit 2)."""
    from mocapdb.stereo import StereoConfig, run_stereo

    cam1, cam2 = cameras_from_args(args)
    config = StereoConfig(camera_distance_m=args.camera_distance)
    summary = run_stereo(args.view1, args.view2, cam1, cam2, config, args.fps, args.out, args.keypoints, args.trim)
    print(summary.report())
    return 0
