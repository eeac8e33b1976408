"""``mocapdb render``'s frame loop: every frame of a result drawn (:func:`render_result`) into PNG
frames or one MP4 (:mod:`mocapdb.render.video_io`), each composed by :mod:`mocapdb.render.frame_layout`;
the inputs read and checked first (:func:`prepare`), the track files drawn on their floor unless
the per-frame stream is asked for (:func:`choose_scene`, :func:`as_drawn`).
"""
from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapdb.core import domains as D
from mocapdb.core.cameras import CameraModel
from mocapdb.core.outputs import check_output_file, check_output_folder
from mocapdb.core.progress import progress as progress_bar
from mocapdb.core.skeleton import PELVIS
from mocapdb.render import draw
from mocapdb.render.frame_layout import Layout, compose_frame, image_camera
from mocapdb.render.results import RenderError, ResultFrame, ResultStream, TrackPose, overlap, read_cameras, read_result
from mocapdb.render.tracks import FileScene, file_scene, people_at
from mocapdb.render.video_io import FRAME_FILES, MP4_FILE, VideoFrames, frame_sink, mp4_path

DEFAULT_FOCAL = D.RENDER_FOCAL_PX.default   # a result whose header records no focal length
DEFAULT_IMAGE_SIZE = (1920, 1080)


@dataclass
class RenderSummary:
    frames: int
    tracks: list[int]
    out: Path
    seconds: float
    warnings: list[str] = field(default_factory=list)
    drawn: str = "the per-frame stream"   # or the track files (FileScene.describe)

    def report(self) -> str:
        tracks = ", ".join(f"#{t}" for t in self.tracks) or "none"
        warn = f"; {len(self.warnings)} warning(s)" if self.warnings else ""
        return (f"rendered {self.frames} frame(s) of {self.drawn}, tracks {tracks}, to {self.out} in "
                f"{self.seconds:.1f} s{warn}")


def _check_keypoint_extent(keypoints: list, camera: CameraModel, warn: Callable[[str], None]) -> None:
    seen = [p.points_px[p.confidence > 0] for k in keypoints for p in k.people]
    pts = np.concatenate(seen) if seen else np.zeros((0, 2))
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts):
        hi = np.percentile(pts, 99, axis=0)
        w, h = camera.size
        if hi[0] > 1.1 * w or hi[1] > 1.1 * h:
            warn(f"keypoints reach x = {hi[0]:.0f} px, y = {hi[1]:.0f} px, beyond the image of {w}×{h} px: "
                 "give --image-size (and --focal) as given to reconstruct")


def prepare(result: str | Path, keypoints: str | Path | list | None, camera: CameraModel | None,
            video: VideoFrames | None, view: str, scale: float, margin: float, warn: Callable[[str], None],
            files: bool = True, note: Callable[[str], None] | None = None):
    """Read and check the inputs: (stream, frame pairs, layout). With ``files`` the layout draws a
    reconstruction's track files (:func:`choose_scene`; ``note`` says why not when it falls back to
    the stream), its 3D view on their floor at a scale that shows the people
    (:func:`~mocapdb.render.draw.people_view`); else the stream, its 3D view up from the bodies."""
    stream = read_result(result)
    cams = read_cameras(stream.path.parent)
    if camera is None:
        if cams is not None:   # a stereo result: camera 1's own intrinsics
            c = cams.cameras[0]
            camera = image_camera(float(c.K[0, 0]), c.size, (float(c.K[0, 2]), float(c.K[1, 2])))
        else:
            camera = image_camera(DEFAULT_FOCAL, video.size if video is not None else DEFAULT_IMAGE_SIZE)
    if video is not None and tuple(video.size) != tuple(camera.size):
        warn(f"the video is {video.size[0]}×{video.size[1]} px, the image size {camera.size[0]}×{camera.size[1]} px: "
             "the video is stretched to the image size")
    if keypoints is not None and not isinstance(keypoints, list):
        from mocapdb.render.results import load_keypoints

        keypoints = load_keypoints(keypoints)
    if keypoints is not None:
        _check_keypoint_extent(keypoints, camera, warn)
    pairs = overlap(stream, keypoints, video.count if video is not None else None, warn)
    scene = choose_scene(stream, note) if files and cams is None else None
    if scene is None:
        return stream, pairs, Layout(camera, view, draw.fit_view(stream.all_joints()), scale, margin)
    view3d = draw.people_view({t.track: t.scene for t in scene.tracks}, scene.main_track,
                              np.eye(3) if scene.on_floor else None, 0.0 if scene.on_floor else None,
                              scene.camera_scene)
    return stream, pairs, Layout(camera, view, view3d, scale, margin, scene)


def choose_scene(stream: ResultStream, note: Callable[[str], None] | None = None) -> FileScene | None:
    """The track files beside a stream (:func:`~mocapdb.render.tracks.file_scene`), or None when
    there are none to draw, ``note`` told why (the stream is drawn instead)."""
    scene, why = file_scene(stream.path.parent, stream)
    if scene is None and note is not None:
        note(f"drawing the per-frame stream ({stream.path.name}): {why}")
    return scene


def as_drawn(layout: Layout, frame: ResultFrame) -> tuple[ResultFrame, list[TrackPose] | None]:
    """A result frame as the layout draws it: with the track files' people (camera-aligned) and
    theirs on the floor for the 3D view; the stream's frame itself (the 3D view the same people)."""
    if layout.scene is None:
        return frame, None
    image, floor = people_at(layout.scene, frame)
    return ResultFrame(frame.index, frame.time_s, image), floor


def render_result(result: str | Path, out: str | Path, keypoints: str | Path | None = None,
                  video: str | Path | None = None, mp4: bool = False, camera: CameraModel | None = None,
                  view: str = "both", scale: float = 1.0, margin: float = 0.06, progress: bool = True,
                  warn: Callable[[str], None] | None = None, stream: bool = False,
                  note: Callable[[str], None] | None = None) -> RenderSummary:
    """Draw every frame of a result (folder or ``result.jsonl``): PNG frames ``out/frame_NNNNNN.png``
    (NNNNNN: the frame number) in a folder that replaces ``out`` whole once complete, or with
    ``mp4`` one video (:func:`mp4_path`) at the stream's frame rate; an existing ``out`` that is not
    an earlier render of the same kind is refused before any drawing (see :mod:`mocapdb.render.video_io`).

    ``keypoints``: the 2D input (drawn thin grey; only frames both have are drawn, with a warning);
    ``video``: drawn under the skeletons (else a dark background); ``camera``: focal and image size
    as given to reconstruct (None: a stereo result's camera 1, else reconstruct's defaults);
    ``view``: ``both`` (image and 3D panels), ``image`` or ``3d``; ``scale``: output pixels per
    input pixel. ``warn`` receives each warning (they are also in the summary).

    A reconstruction's track files are drawn (the whole take; on their floor in the 3D view: see
    :func:`prepare`) unless ``stream`` (the per-frame stream, result.jsonl) or there are none to
    draw (then ``note`` says why and the stream is drawn).
    """
    start = time.perf_counter()
    warnings: list[str] = []

    def _warn(text: str) -> None:
        warnings.append(text)
        if warn is not None:
            warn(text)

    if not (math.isfinite(scale) and 0.05 <= scale <= 4):
        raise RenderError(f"scale {scale:g} is outside 0.05–4")
    if mp4:  # before any work
        check_output_file(mp4_path(out), MP4_FILE)
    else:
        check_output_folder(out, FRAME_FILES)
    frames_in = VideoFrames(video) if video is not None else None
    try:
        result_stream, pairs, layout = prepare(result, keypoints, camera, frames_in, view, scale, margin, _warn,
                                               not stream, note)
        trails: dict[int, deque] = {}
        tracks: set[int] = set()
        with frame_sink(Path(out), mp4, result_stream.fps, layout.size) as write:
            for rframe, kframe in (progress_bar(pairs, desc="render", unit="frame") if progress else pairs):
                frame, people_3d = as_drawn(layout, rframe)
                _follow(trails, frame.people if people_3d is None else people_3d, int(result_stream.fps))
                tracks.update(p.track for p in frame.people)
                background = frames_in.get(rframe.index) if frames_in is not None else None
                write(rframe.index, compose_frame(layout, frame, kframe, background, trails, people_3d=people_3d))
        written = mp4_path(out) if mp4 else Path(out)
    finally:
        if frames_in is not None:
            frames_in.close()
    return RenderSummary(len(pairs), sorted(tracks), written, time.perf_counter() - start, warnings,
                         "the per-frame stream" if layout.scene is None else layout.scene.describe())


def _follow(trails: dict[int, deque], people: list[TrackPose], length: int) -> None:
    """Add each person's pelvis to its track's trail (at most ``length`` points); drop the trails of
    tracks not in ``people``."""
    for p in people:
        trails.setdefault(p.track, deque(maxlen=max(2, length))).append(p.joints[PELVIS])
    seen = {p.track for p in people}
    for gone in [t for t in trails if t not in seen]:
        del trails[gone]
