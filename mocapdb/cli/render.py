"""`mocapdb render`: look at a result: skeletons over the input frames, a 3D view, the stereo cameras."""
from __future__ import annotations

import argparse
import sys

from mocapdb.cli import paths as P
from mocapdb.core import domains as D


def add_render_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``render`` subcommand (``run`` returns the exit code)."""
    p = sub.add_parser(
        "render", help="draw a result: skeletons over the input keypoints/video, a 3D view, stereo cameras",
        description="Draw the output of `mocapdb reconstruct` frame by frame: what its track files hold (each "
                    "track's whole-take fit, read from track_<id>.csv, else .bvh; sizes and floor from world.json) "
                    "re-projected through the pinhole camera (--focal, --image-size as given to reconstruct) in "
                    "its own colour, labelled with its id, 'main' and its stature, over the input keypoints (thin "
                    "grey) and the video frame (or a dark background), beside an orthographic 3D view of the "
                    "tracks on their floor (y = 0, the camera drawn at its height) whose grid holds the main track "
                    "and most of the people, not every outlier. --stream draws the per-frame stream "
                    "(result.jsonl) instead; a folder without track files or world.json falls back to it with a "
                    "note. Writes OUT/frame_NNNNNN.png or, with --mp4, one video. For the output of `mocapdb "
                    "stereo` (a folder holding cameras.json) without --keypoints: one picture of the two cameras "
                    "and the motion (top and oblique views).")
    p.add_argument("result", type=P.INPUT_ANY,
                   help="the --out folder of `mocapdb reconstruct` or `mocapdb stereo` (or its result.jsonl)")
    p.add_argument("--out", required=True, type=P.OUTPUT,
                   help="folder for PNG frames; with --mp4 a .mp4 file (or a folder: OUT/render.mp4); for the "
                        "stereo plot a .png file (an existing OUT is replaced only when it is an earlier render's "
                        "output of the same kind, else refused)")
    p.add_argument("--keypoints", metavar="INPUT", type=P.INPUT_ANY,
                   help="the 2D input given to reconstruct (OpenPose folder, .jsonl, MMPose .json, .npy/.npz)")
    p.add_argument("--video", type=P.INPUT_FILE, help="the input video, drawn under the skeletons (OpenCV reads it)")
    p.add_argument("--mp4", action="store_true", help="write one MP4 video (mp4v) instead of PNG frames")
    p.add_argument("--focal", type=D.FOCAL_PX, metavar="PX",
                   help="focal length in pixels as given to reconstruct (default: the one the result's header "
                        f"records; else {D.RENDER_FOCAL_PX.default:g}; stereo: camera 1's)")
    p.add_argument("--image-size", type=D.IMAGE_SIZE, metavar="WxH",
                   help="input image WIDTHxHEIGHT in pixels as given to reconstruct (default: the video's, else "
                        "1920x1080; stereo: camera 1's)")
    p.add_argument("--view", choices=("both", "image", "3d"), default="both",
                   help="image panel, 3D panel, or both side by side (default both)")
    p.add_argument("--scale", type=D.RENDER_SCALE, default=D.RENDER_SCALE.default,
                   help="output pixels per input pixel (default %(default)s)")
    p.add_argument("--contact-sheet", type=D.CONTACT_FRAMES, metavar="N",
                   help="write one PNG (--out) holding N evenly spaced frames instead of every frame")
    p.add_argument("--stream", action="store_true",
                   help="draw the per-frame stream (result.jsonl: causal, camera-aligned, every person at 1.75 m "
                        "unless given) instead of the track files")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(run=run_render)


def run_render(args: argparse.Namespace) -> int:
    """``mocapdb render``: frames, an MP4, a contact sheet or the stereo plot; prints a summary line."""
    from pathlib import Path

    from mocapdb.core.errors import UsageError
    from mocapdb.core.formats.take import resolve_camera
    from mocapdb.render.contact_sheet import contact_sheet
    from mocapdb.render.frame_layout import image_camera
    from mocapdb.render.results import read_cameras, recorded_camera, result_path
    from mocapdb.render.stereo_plot import render_stereo_plot
    from mocapdb.render.video import DEFAULT_FOCAL, DEFAULT_IMAGE_SIZE, render_result

    def warn(text: str) -> None:
        print(f"mocapdb render: warning: {text}", file=sys.stderr)

    def note(text: str) -> None:
        print(f"mocapdb render: note: {text}", file=sys.stderr)

    folder = result_path(args.result).parent
    stereo_cameras = read_cameras(folder)  # None: not a `mocapdb stereo` folder
    stereo = stereo_cameras is not None
    if stereo and args.keypoints is None and args.video is None and args.contact_sheet is None:
        if args.mp4 or Path(args.out).suffix.lower() != ".png":
            raise UsageError(f"{args.result} is a stereo result: its plot is one picture, give --out NAME.png "
                             "(or --keypoints to draw camera 1's frames)")
        print(f"wrote {render_stereo_plot(folder, args.out)} (cameras and motion of {folder})")
        return 0
    camera = None
    recorded = None if stereo else recorded_camera(args.result)
    if recorded is not None:  # the run recorded its camera: nothing to type again, a contradiction named
        settings = resolve_camera(recorded, f"the header of {result_path(args.result)}", None,
                                  args.image_size, args.focal)
        camera = image_camera(settings.focal_px, settings.image_size)
    elif args.focal is not None or args.image_size is not None or not stereo:
        size = args.image_size
        if size is None and args.video is not None:
            from mocapdb.render.video_io import VideoFrames

            v = VideoFrames(args.video)
            size = v.size
            v.close()
        camera = image_camera(args.focal if args.focal is not None else DEFAULT_FOCAL, size or DEFAULT_IMAGE_SIZE)
        if args.focal is None and args.keypoints is not None:
            warn(f"no --focal: assuming {DEFAULT_FOCAL:g} px (reconstruct's default); give the value used there")
    if args.contact_sheet is not None:
        if camera is None:  # only a stereo result's is left unset above: camera 1's
            assert stereo_cameras is not None, "a single-camera result's camera is set above"
            c = stereo_cameras.cameras[0]
            camera = image_camera(float(c.K[0, 0]), c.size)
        out = contact_sheet(args.result, args.keypoints, args.out, args.contact_sheet, focal=float(camera.K[0, 0]),
                            image_size=camera.size, video=args.video, view=args.view, warn=warn, stream=args.stream,
                            note=note)
        print(f"wrote {out} ({args.contact_sheet} frames of {args.result})")
        return 0
    summary = render_result(args.result, args.out, args.keypoints, args.video, args.mp4, camera, args.view,
                            args.scale, progress=not args.no_progress, warn=warn, stream=args.stream, note=note)
    print(summary.report())
    return 0
