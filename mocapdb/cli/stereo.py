"""`mocapdb stereo`: two uncalibrated views → cameras, 3D motion and BVH (ElliPose)."""
from __future__ import annotations

import argparse
import logging
from typing import TYPE_CHECKING

from mocapdb.cli import paths as P
from mocapdb.core import domains as D
from mocapdb.core.formats.keypoint_layouts import LAYOUTS

if TYPE_CHECKING:
    from mocapdb.core.cameras import CameraModel
    from mocapdb.core.formats.take import CameraSettings

LOG = logging.getLogger("mocapdb.cli")


def views_from_args(args: argparse.Namespace) -> tuple[CameraModel, CameraModel, float | None]:
    """The two cameras' intrinsics and the views' frame rate (Hz; None: nothing gives one): from
    ``--calibration``/``--cameras`` or ``--focal``/``--image-size``/``--center``, and ``--fps``, each
    view folder's ``take.json`` giving what is not given (:func:`view_takes`, :func:`views_fps`);
    StereoError, CalibrationError or UsageError naming the option or the file when they cannot be
    cameras or contradict each other."""
    from mocapdb.stereo import StereoError

    manual = [flag for flag, value in (("--focal", args.focal), ("--image-size", args.image_size),
                                       ("--center", args.center)) if value is not None]
    if args.calibration and manual:
        raise StereoError(f"--calibration gives the intrinsics: leave out {', '.join(manual)}")
    if args.cameras and not args.calibration:
        raise StereoError("--cameras names cameras of --calibration FILE: give the file too")
    cams = calibrated_cameras(args) if args.calibration else None
    takes = view_takes(args, cams)
    cam1, cam2 = cams or manual_cameras(args, takes)
    return cam1, cam2, views_fps(takes, (args.view1, args.view2))


def calibrated_cameras(args: argparse.Namespace) -> tuple[CameraModel, CameraModel]:
    """The intrinsics and distortion of the two ``--cameras`` of ``--calibration`` (either when it
    holds only two); StereoError naming the file and the cameras it has."""
    from mocapdb.core.cameras import intrinsics_only, read_calibration
    from mocapdb.stereo import StereoError

    cams = read_calibration(args.calibration)
    names = args.cameras or (list(cams) if len(cams) == 2 else None)
    if names is None:
        raise StereoError(f"{args.calibration} holds {len(cams)} cameras ({', '.join(cams)}): "
                          "name two with --cameras")
    missing = [n for n in names if n not in cams]
    if missing:
        raise StereoError(f"{args.calibration} has no camera {', '.join(missing)} (it has {', '.join(cams)})")
    return intrinsics_only(cams[names[0]]), intrinsics_only(cams[names[1]])


def view_takes(args: argparse.Namespace, cams: tuple[CameraModel, CameraModel] | None) -> list[CameraSettings]:
    """Each view's frame rate, image size and focal length (:func:`mocapdb.core.formats.take.resolve_camera`):
    ``--fps``, and the calibration's image sizes or ``--image-size``/``--focal``, where given, else
    the view folder's ``take.json``, else the defaults; a given value that contradicts a take
    description is an error naming both. (A calibration's focal length is not compared: a take
    description's is an estimate at best.)"""
    from pathlib import Path

    from mocapdb.core.formats.take import TAKE_FILE, read_take, resolve_camera

    settings = []
    for k, folder in enumerate((args.view1, args.view2)):
        cam = cams[k] if cams else None
        size, focal = (cam.size, None) if cam else (args.image_size, args.focal)
        given_as = {"image_size": f"the image size of {cam.name} in {args.calibration}"} if cam else None
        settings.append(resolve_camera(read_take(folder), str(Path(folder) / TAKE_FILE), args.fps, size, focal,
                                       given_as))
    return settings


def manual_cameras(args: argparse.Namespace, takes: list[CameraSettings]) -> tuple[CameraModel, CameraModel]:
    """Distortion-free cameras of each view's focal length and image size (``--center`` or the image
    centre); StereoError when an option and the view's ``take.json`` leave one unknown."""
    from mocapdb.core.cameras import camera_from_intrinsics
    from mocapdb.stereo import StereoError

    unknown = sorted({option for take in takes for option, name in (("--focal PX", "focal_px"),
                                                                    ("--image-size WxH", "image_size"))
                      if take.sources[name] == "default"})
    if unknown:
        raise StereoError(f"give the intrinsics: --calibration FILE --cameras NAME1 NAME2, or --focal PX "
                          f"--image-size WxH [--center CX CY]; neither the options nor the view folders' "
                          f"take.json give {' and '.join(unknown)}")
    return tuple(camera_from_intrinsics(take.focal_px, tuple(args.center) if args.center else
                                        (take.image_size[0] / 2, take.image_size[1] / 2), take.image_size)
                 for take in takes)  # type: ignore[return-value]


def views_fps(takes: list[CameraSettings], views: tuple[str, str]) -> float | None:
    """The frame rate (Hz) both views share: ``--fps`` or their take descriptions', which must agree
    (StereoError naming both); None when nothing gives one."""
    from mocapdb.core.formats.take import TAKE_FILE
    from mocapdb.stereo import StereoError

    known = [(take.fps, view) for take, view in zip(takes, views) if take.sources["fps"] != "default"]
    if not known:
        return None
    if len(known) == 2 and abs(known[0][0] - known[1][0]) > 1e-3 * known[0][0]:
        (fps1, view1), (fps2, view2) = known
        raise StereoError(f"{view1}/{TAKE_FILE} says {fps1:g} Hz, {view2}/{TAKE_FILE} says {fps2:g} Hz: the views "
                          "must be synchronised frame by frame (one frame rate); re-detect one at the other's rate")
    return float(known[0][0])


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
                    "used, never their extrinsics. A view folder's take.json (written by `mocapdb detect`) gives "
                    "the frame rate, image size and focal length that no option gives.")
    p.add_argument("view1", type=P.INPUT_DIR,
                   help="folder of OpenPose JSON frames from camera 1 (the output's reference)")
    p.add_argument("view2", type=P.INPUT_DIR,
                   help="folder of OpenPose JSON frames from camera 2 (same frames, same rate)")
    p.add_argument("--out", required=True, type=P.OUTPUT_DIR, help="output folder")
    p.add_argument("--calibration", type=P.INPUT_FILE, metavar="FILE",
                   help="Pose2Sim calibration: its TOML or a Qualisys .qca.txt (data_specs/stereo.md); the "
                        "intrinsics and distortion of --cameras")
    p.add_argument("--cameras", nargs=2, type=P.TextArg("a camera name"), metavar=("NAME1", "NAME2"),
                   help="names of the two cameras in --calibration (TOML sections, QCA serials), e.g. cam_01 cam_02")
    p.add_argument("--focal", type=D.FOCAL_PX, metavar="PX",
                   help="focal length in pixels (both cameras, no distortion; default: the view folders' take.json)")
    p.add_argument("--center", type=D.PIXEL_COORDINATE, nargs=2, metavar=("CX", "CY"),
                   help="principal point in pixels (default: the image centre)")
    p.add_argument("--image-size", type=D.IMAGE_SIZE, metavar="WxH",
                   help="input image WIDTHxHEIGHT in pixels (both cameras; default: the view folders' take.json)")
    p.add_argument("--camera-distance", type=D.BASELINE_M, metavar="METRES",
                   help="distance between the cameras in metres, for metric output (default: metres from the "
                        "universal skeleton's leg length)")
    p.add_argument("--fps", type=D.FPS_HZ,
                   help="frame rate of both views in Hz (default: the view folders' take.json, else 30, with a "
                        "warning)")
    p.add_argument("--keypoints", choices=tuple(LAYOUTS), help="keypoint layout of the JSON (default: detected)")
    p.add_argument("--trim", action="store_true",
                   help="when the views' frame counts differ, cut both to the shorter (they must start together)")
    p.set_defaults(run=run_stereo_command)


def run_stereo_command(args: argparse.Namespace) -> int:
    """``mocapdb stereo``: run and print the summary (user errors are reported by the CLI, exit 2)."""
    from mocapdb.core.formats.take import DEFAULTS
    from mocapdb.stereo import StereoConfig, run_stereo

    cam1, cam2, fps = views_from_args(args)
    config = StereoConfig(camera_distance_m=args.camera_distance)
    summary = run_stereo(args.view1, args.view2, cam1, cam2, config, fps or DEFAULTS["fps"], args.out,
                         args.keypoints, args.trim)
    if fps is None:  # after the run: an error says what it is alone
        LOG.warning("no frame rate given: the views were taken as %g Hz (the BVH frame time); give --fps FPS (Hz)",
                    DEFAULTS["fps"])
    print(summary.report())
    return 0
