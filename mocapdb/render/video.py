"""Pictures of results: per-frame overlays (PNG frames or one MP4), a contact sheet, a stereo camera plot.

Outputs are written as every command writes them (:mod:`mocapdb.core.outputs`): PNG frames into a
temporary folder that replaces ``--out`` whole once complete (an earlier render's frames folder is
replaced, a folder holding anything else refused); a PNG or MP4 file through a temporary name and a
rename, replacing only a PNG or MP4 file. Both are checked before any drawing.
"""
from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from mocapdb.core import domains as D
from mocapdb.core.cameras import CameraModel, camera_from_intrinsics
from mocapdb.core.outputs import (
    OutputFile,
    OutputFiles,
    check_output_file,
    check_output_folder,
    output_file,
    output_folder,
)
from mocapdb.core.progress import progress as progress_bar
from mocapdb.core.skeleton import PELVIS
from mocapdb.render import draw
from mocapdb.render.results import (
    RenderError,
    ResultFrame,
    ResultStream,
    TrackPose,
    overlap,
    read_cameras,
    read_result,
)
from mocapdb.render.tracks import FileScene, file_scene, people_at

VIEWS = ("both", "image", "3d")
DEFAULT_FOCAL = D.RENDER_FOCAL_PX.default   # a result whose header records no focal length
DEFAULT_IMAGE_SIZE = (1920, 1080)
MP4_NAME = "render.mp4"
FRAME_FILES = OutputFiles("render", ("frame_*.png",), "frame_*.png")
PNG_FILE = OutputFile("render", "a PNG picture", b"\x89PNG\r\n\x1a\n")
MP4_FILE = OutputFile("render", "an MP4 video", b"ftyp", offset=4)
MAX_FRAME_PX = 8192  # an output frame's longest side: bounds memory whatever image size a result names


def image_camera(focal_px: float, size: tuple[int, int], principal_px: tuple[float, float] | None = None
                 ) -> CameraModel:
    """The pinhole camera a result was made with (``--focal``, ``--image-size``; principal point at
    the image centre unless given); RenderError naming the option when it cannot be one."""
    if not (math.isfinite(focal_px) and focal_px > 0):
        raise RenderError(f"focal length {focal_px:g} px is not a positive number (--focal)")
    if len(size) != 2 or min(size) <= 0:
        raise RenderError(f"image size {size} is not a positive width and height (--image-size WxH)")
    size = (int(size[0]), int(size[1]))
    return camera_from_intrinsics(focal_px, principal_px or (size[0] / 2, size[1] / 2), size)


@dataclass
class Layout:
    """Where things go in an output frame: the image panel (input image scaled, with a margin
    showing what falls outside it) and/or the square 3D panel to its right; ``scene``: the track
    files drawn (their camera and legend in the 3D panel), None for the stream."""
    camera: CameraModel
    view: str
    view3d: draw.View3D
    scale: float = 1.0
    margin: float = 0.06
    scene: FileScene | None = None

    def __post_init__(self):
        if self.view not in VIEWS:
            raise RenderError(f"view {self.view!r}: choose one of {', '.join(VIEWS)}")
        w, h = self.camera.size
        self.margin_px = int(round(self.margin * max(w, h) * self.scale))
        self.image_panel = (int(round(w * self.scale)) + 2 * self.margin_px,
                            int(round(h * self.scale)) + 2 * self.margin_px)
        side = self.image_panel[1]
        # the 3D panel: square, but no wider than 1.3 image panels beside a portrait image
        wide = side if self.view == "3d" or w >= h else min(side, int(1.3 * self.image_panel[0]))
        self.panel_3d = (wide, side)
        width = (self.image_panel[0] if self.view != "3d" else 0) + (wide if self.view != "image" else 0)
        self.size = (width + width % 2, side + side % 2)   # even: what video codecs want
        if max(self.size) > MAX_FRAME_PX:
            raise RenderError(f"an image of {w}×{h} px at scale {self.scale:g} makes frames of {self.size[0]}×"
                              f"{self.size[1]} px, more than {MAX_FRAME_PX} px on a side: give a smaller --scale")


def _fresh_background(layout: Layout, video_frame: np.ndarray | None) -> np.ndarray:
    pw, ph = layout.image_panel
    img = np.full((ph, pw, 3), 16, np.uint8)
    m = layout.margin_px
    w, h = pw - 2 * m, ph - 2 * m
    if video_frame is not None:
        img[m:m + h, m:m + w] = cv2.resize(video_frame, (w, h), interpolation=cv2.INTER_AREA)
    else:
        img[m:m + h, m:m + w] = draw.BACKGROUND
    if m:
        cv2.rectangle(img, (m - 1, m - 1), (m + w, m + h), draw.BORDER_COLOUR, 1)
    return img


def compose_frame(layout: Layout, frame: ResultFrame, keypoints=None, video_frame: np.ndarray | None = None,
                  trails: dict[int, deque] | None = None, caption: str | None = None,
                  people_3d: list[TrackPose] | None = None) -> np.ndarray:
    """One output image (BGR) of a result frame: the re-projected skeletons over the input keypoints
    (grey) and the video frame, and/or the 3D panel. ``trails``: per track the recent pelvis
    positions (input coordinates of the 3D view), drawn in the 3D panel; ``people_3d``: who the 3D
    panel draws (default the frame's people)."""
    people = sorted(frame.people, key=lambda p: -float(np.nan_to_num(p.joints[PELVIS, 2], nan=0.0)))
    out = np.zeros((layout.size[1], layout.size[0], 3), np.uint8)
    x0 = 0
    text_scale = 0.35 + layout.size[1] / 1800
    if layout.view != "3d":
        img = image_panel(layout, people, keypoints, video_frame)
        out[:img.shape[0], :img.shape[1]] = img
        x0 = img.shape[1]
    if layout.view != "image":
        panel = panel_3d(layout, people if people_3d is None else people_3d, trails, text_scale)
        out[:panel.shape[0], x0:x0 + panel.shape[1]] = panel
    t = "" if math.isnan(frame.time_s) else f"  {frame.time_s:.2f} s"
    draw.put_text(out, caption or f"frame {frame.index}{t}  people {len(frame.people)}",
                  (8, int(28 * text_scale) + 8 + (int(40 * text_scale) if layout.view == "3d" else 0)),
                  text_scale, draw.TEXT_COLOUR, 1 if text_scale < 1 else 2)
    return out


def image_panel(layout: Layout, people: list[TrackPose], keypoints=None, video_frame: np.ndarray | None = None
                ) -> np.ndarray:
    """The image panel: the video frame (or a dark background), the input keypoints (grey) and each
    person (camera-aligned joints) re-projected through the layout's camera, labelled."""
    cam = layout.camera
    img = _fresh_background(layout, video_frame)
    m = layout.margin_px
    if keypoints is not None:
        for person in keypoints.people:
            draw.draw_keypoints_2d(img, person.points_px, person.confidence, (m, m), layout.scale)
    for p in people:
        px = draw.project_pinhole(p.joints, cam.K[0, 0], (cam.K[0, 2], cam.K[1, 2]))
        edge = draw.at_image_edge(px, cam.size)
        draw.draw_skeleton_px(img, px * layout.scale + m, draw.track_colour(p.track),
                              draw.track_label(p.track, p.distance_2d, edge, p.label))
    return img


def panel_3d(layout: Layout, people: list[TrackPose], trails: dict[int, deque] | None = None,
             text_scale: float = 0.6, legend: bool = True) -> np.ndarray:
    """The 3D panel: the floor grid, the pelvis trails, the people (far ones first), and for the
    track files the camera and (``legend``) a legend of the tracks' sizes above the view."""
    pw, side = layout.panel_3d
    panel = np.full((side, pw, 3), 24, np.uint8)
    scene = layout.scene
    y = int(28 * text_scale) + 8
    caption = int(40 * text_scale) if layout.view == "3d" else 0   # compose_frame's caption under the title
    lines = [(draw.track_colour(t.track), t.legend) for t in scene.tracks] if scene is not None and legend else []
    body = panel[_legend(panel, lines, y + caption + int(34 * text_scale), text_scale):]
    _draw_scene(body, layout, people, trails)
    title = "3D, orthographic" if scene is None else (
        "3D on the floor (y = 0), orthographic" if scene.on_floor else "3D (no floor found), orthographic")
    draw.put_text(panel, title, (8, y), text_scale, (170, 170, 170))
    return panel


def _legend(panel: np.ndarray, lines: list[tuple[tuple[int, int, int], str]], y: int, text_scale: float) -> int:
    """The legend's ``lines`` from baseline ``y`` down, as large as the panel's width allows;
    returns the rows it takes (0: none, when there are no lines or they would take over 40 % of it)."""
    if not lines:
        return 0
    widest = max(cv2.getTextSize(text, draw.FONT, 1.0, 1)[0][0] for _, text in lines)
    scale = max(0.3, min(0.8 * text_scale, (panel.shape[1] - 16) / max(widest, 1)))
    step = int(cv2.getTextSize("Ag", draw.FONT, scale, 1)[0][1] * 1.7) + 1
    bottom = y + step * (len(lines) - 1) + step // 2
    if bottom > 0.4 * panel.shape[0]:
        return 0
    draw.draw_legend(panel, lines, (8, y), scale)
    return bottom


def _draw_scene(img: np.ndarray, layout: Layout, people: list[TrackPose], trails: dict[int, deque] | None) -> None:
    """The 3D view in ``img``: floor grid, pelvis trails, the files' camera, the people (far first)."""
    view, size = layout.view3d, img.shape[1::-1]
    draw.draw_floor(img, view)
    for track, trail in (trails or {}).items():
        if len(trail) > 1:
            flat = view.scene(np.array(trail))
            flat[:, 1] = view.floor
            px, _ = view.project(flat, size, scene=True)
            colour = tuple(int(c * 0.55) for c in draw.track_colour(track))
            cv2.polylines(img, [np.round(px).astype(np.int32)], False, colour, 1, cv2.LINE_AA)
    if layout.scene is not None and layout.scene.camera_scene is not None:
        _draw_camera(img, layout)
    for p in sorted(people, key=lambda p: -float(np.nanmean(view.project(p.joints, size)[1]))):
        draw.draw_skeleton_3d(img, view, p.joints, draw.track_colour(p.track), p.label or f"#{p.track}")


def _draw_camera(panel: np.ndarray, layout: Layout) -> None:
    """The camera of the track files' floor as a small frustum with its height, and a line down
    to the floor under it; only when it falls inside the floor grid."""
    view, scene = layout.view3d, layout.scene
    centre = scene.camera_scene
    if np.max(np.abs(view.scene(centre)[[0, 2]] - view.centre)) > view.half_extent:
        return
    cam = layout.camera
    fov = (cam.size[0] / 2 / cam.K[0, 0], cam.size[1] / 2 / cam.K[1, 1])
    foot = centre * [1.0, 0.0, 1.0] + [0.0, view.floor, 0.0]
    px, _ = view.project(np.array([centre, foot]), panel.shape[1::-1])
    cv2.line(panel, draw._pt(px[0]), draw._pt(px[1]), (150, 150, 150), 1, cv2.LINE_AA)
    draw.draw_camera_3d(panel, view, centre, scene.camera_axes, fov, 0.08 * view.half_extent, (200, 200, 200), "")
    draw.put_text(panel, f"camera {scene.world.height_m:.2f} m up", (int(px[1][0]), int(px[1][1]) + 16),
                  0.3 + panel.shape[0] / 2400, (200, 200, 200), anchor="centre")


class VideoFrames:
    """Frames of a video file by index (sequential reads, a seek when going back or far ahead)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise RenderError(f"{path}: no such video file (--video)")
        self.cap = cv2.VideoCapture(str(self.path))
        if not self.cap.isOpened():
            raise RenderError(f"{path}: OpenCV cannot open this video (--video)")
        count = int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT))
        self.count = count if count > 0 else None
        self.size = (int(self.cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        self.next = 0

    def get(self, index: int) -> np.ndarray | None:
        if index < self.next or index > self.next + 60:
            self.cap.set(cv2.CAP_PROP_POS_FRAMES, index)
            self.next = index
        frame = None
        while self.next <= index:
            ok, frame = self.cap.read()
            self.next += 1
            if not ok:
                return None
        return frame

    def close(self) -> None:
        self.cap.release()


def write_png(path: str | Path, img: np.ndarray) -> Path:
    """Write ``img`` as the PNG file ``path`` atomically, replacing only a PNG (:func:`output_file`)."""
    path = Path(path)
    ok, data = cv2.imencode(".png", img)
    if not ok:
        raise RenderError(f"{path}: OpenCV cannot encode the picture as PNG")
    with output_file(path, PNG_FILE) as tmp:
        tmp.write_bytes(data.tobytes())
    return path


def mp4_path(out: str | Path) -> Path:
    """The video file of ``render --mp4 --out OUT``: OUT if it ends ``.mp4``, else OUT/render.mp4."""
    out = Path(out)
    return out if out.suffix.lower() == ".mp4" else out / MP4_NAME


@contextmanager
def _frame_sink(out: Path, mp4: bool, fps: float, size: tuple[int, int]
                ) -> Iterator[Callable[[int, np.ndarray], None]]:
    """``write(index, image)`` for the frames: PNG files in a folder that replaces ``out`` whole, or
    one MP4 (:func:`mp4_path`) at ``fps`` Hz of frames ``size`` px; either only when the block ends
    normally."""
    if not mp4:
        with output_folder(out, FRAME_FILES) as tmp:
            yield lambda index, img: write_png(tmp / f"frame_{index:06d}.png", img)
        return
    with output_file(mp4_path(out), MP4_FILE) as tmp:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
        try:
            if not writer.isOpened():
                raise RenderError(f"{mp4_path(out)}: OpenCV cannot write an MP4 (mp4v) video here")
            yield lambda index, img: writer.write(img)
        finally:
            writer.release()


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
    pts = [p.points_px[p.confidence > 0] for k in keypoints for p in k.people]
    pts = np.concatenate(pts) if pts else np.zeros((0, 2))
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
    an earlier render of the same kind is refused before any drawing (see the module docstring).

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
        with _frame_sink(Path(out), mp4, result_stream.fps, layout.size) as write:
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


def contact_sheet(result_dir: str | Path, keypoints: str | Path | list | None, out_png: str | Path, n: int = 12, *,
                  focal: float = DEFAULT_FOCAL, image_size: tuple[int, int] = DEFAULT_IMAGE_SIZE,
                  video: str | Path | None = None, view: str = "both", tile_height: int = 520,
                  columns: int | None = None, warn: Callable[[str], None] | None = None,
                  name: str | None = None, stream: bool = False, note: Callable[[str], None] | None = None) -> Path:
    """One PNG: a grid of ``n`` evenly spaced frames of a result with their overlays (the
    re-projected skeletons over the input keypoints, and the 3D view with ``view="both"``).

    ``result_dir``: the ``--out`` folder of ``mocapdb reconstruct`` (or its ``result.jsonl``);
    ``keypoints``: its input (folder, file, or frames already read; None: skeletons only);
    ``focal`` (px) and ``image_size`` (width, height px): as given to reconstruct; ``video``:
    optional frames underneath; ``tile_height``: pixels per tile; ``name``: the result as the title
    shows it (default its folder and file name). Draws the track files (on their floor in the 3D
    view) unless ``stream`` or there are none (``note`` says why), as :func:`render_result`.
    Frames are chosen evenly among those the result and keypoints share. Written atomically,
    replacing only a PNG (checked first); returns ``out_png``. Raises
    :class:`~mocapdb.render.results.RenderError` on unusable inputs (``reconstruct --preview``).
    """
    if n < 1:
        raise RenderError(f"a contact sheet needs at least 1 frame, not {n}")
    check_output_file(out_png, PNG_FILE)
    camera = image_camera(float(focal), tuple(image_size))
    frames_in = VideoFrames(video) if video is not None else None
    try:
        full_h = camera.size[1] * (1 + 2 * 0.06)
        scale = max(0.05, tile_height / full_h)
        result, pairs, layout = prepare(result_dir, keypoints, camera, frames_in, view, scale, 0.06,
                                        warn or (lambda text: None), not stream, note)
        picks = sorted(set(np.round(np.linspace(0, len(pairs) - 1, min(n, len(pairs)))).astype(int).tolist()))
        tiles = []
        for i in picks:
            rframe, kframe = pairs[i]
            background = frames_in.get(rframe.index) if frames_in is not None else None
            frame, people_3d = as_drawn(layout, rframe)
            tiles.append(compose_frame(layout, frame, kframe, background, people_3d=people_3d))
    finally:
        if frames_in is not None:
            frames_in.close()
    tracks = result.tracks if layout.scene is None else [t.track for t in layout.scene.tracks]
    drawn = "the stream" if layout.scene is None else layout.scene.describe()
    shown = name or f"{result.path.parent.name}/{result.path.name}"
    title = (f"{shown}: {len(tiles)} of {len(pairs)} frames of {drawn}, {len(tracks)} track(s), "
             f"focal {camera.K[0, 0]:g} px, image {camera.size[0]}x{camera.size[1]}")
    return write_png(out_png, _sheet(tiles, title, tracks, columns))


def _sheet(tiles: list[np.ndarray], title: str, tracks: list[int], columns: int | None = None) -> np.ndarray:
    """Tiles of one size in a grid (``columns``, default about 1.5 times as wide as high) under a
    title line followed by the tracks' ids in their colours."""
    th, tw = tiles[0].shape[:2]
    cols = columns or max(1, min(len(tiles), round(math.sqrt(len(tiles) * 1.5 * th / tw))))
    rows = math.ceil(len(tiles) / cols)
    gap, title_h = 4, max(30, th // 12)
    sheet = np.full((title_h + rows * (th + gap), cols * (tw + gap) - gap, 3), 8, np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, cols)
        y, x = title_h + r * (th + gap), c * (tw + gap)
        sheet[y:y + th, x:x + tw] = tile
    tscale = title_h / 45
    draw.put_text(sheet, title, (8, int(title_h * 0.72)), tscale, draw.TEXT_COLOUR, 1)
    (tw_text, _), _ = cv2.getTextSize(title, draw.FONT, tscale, 1)
    x = 8 + tw_text + 20
    for t in tracks[:10]:
        draw.put_text(sheet, f"#{t}", (x, int(title_h * 0.72)), tscale, draw.track_colour(t), 2)
        x += int(60 * tscale) + 10
    return sheet


def _stereo_basis(cams) -> np.ndarray | None:
    """Camera-aligned (camera 1) → scene axes (x right, y up, z forward) from ``bvh_from_camera1``."""
    if cams.bvh_from_camera1 is None:
        return None
    b = np.diag([1.0, 1.0, -1.0]) @ cams.bvh_from_camera1 @ np.diag([1.0, -1.0, 1.0])
    u, _, vt = np.linalg.svd(b)   # keep it a rotation
    return u @ vt


def render_stereo_plot(stereo_dir: str | Path, out_png: str | Path, panel: int = 900, snapshots: int = 6) -> Path:
    """One PNG of a ``mocapdb stereo`` output: a top view and an oblique view of the two cameras
    (frusta with their names) and the people's motion (pelvis path over time, skeletons at
    ``snapshots`` evenly spaced frames, older ones darker). OpenCV only (no matplotlib). Written
    atomically, replacing only a PNG (checked first)."""
    check_output_file(out_png, PNG_FILE)
    cams = read_cameras(stereo_dir)
    if cams is None:
        raise RenderError(f"{stereo_dir}: no cameras.json (not the --out folder of `mocapdb stereo`; for a "
                          "reconstruction give --keypoints and draw its frames)")
    stream = read_result(stereo_dir)
    flip = np.diag([1.0, -1.0, 1.0])   # OpenCV camera-1 axes ↔ camera-aligned axes
    centres = np.array([flip @ c.center_m for c in cams.cameras])
    joints = stream.all_joints()
    basis = _stereo_basis(cams)
    top = draw.fit_view(joints, basis, centres, azimuth_deg=0.0, elevation_deg=90.0)
    oblique = draw.fit_view(joints, basis, centres, azimuth_deg=-35.0, elevation_deg=25.0)
    spread = top.half_extent
    panels = []
    for view, title in ((top, "top view"), (oblique, "oblique view")):
        img = np.full((panel, panel, 3), 24, np.uint8)
        draw.draw_floor(img, view)
        for k, c in enumerate(cams.cameras):
            axes = np.array([flip @ c.R[i] for i in range(3)])
            fov = (c.size[0] / 2 / c.K[0, 0], c.size[1] / 2 / c.K[1, 1])
            draw.draw_camera_3d(img, view, centres[k], axes, fov, 0.2 * spread, (235, 235, 235) if k == 0
                                else (120, 220, 255), c.name)
        for track in stream.tracks:
            colour = np.array(draw.track_colour(track), dtype=np.float64)
            frames = [(f, p) for f in stream.frames for p in f.people if p.track == track]
            pelvis = np.array([p.joints[PELVIS] for _, p in frames])
            px, _ = view.project(pelvis, (panel, panel))
            ok = np.all(np.isfinite(px), axis=1)
            for a in range(len(px) - 1):
                if ok[a] and ok[a + 1]:
                    shade = 0.35 + 0.65 * a / max(1, len(px) - 1)
                    cv2.line(img, draw._pt(px[a]), draw._pt(px[a + 1]), tuple(int(v) for v in colour * shade), 2,
                             cv2.LINE_AA)
            picks = sorted(set(np.round(np.linspace(0, len(frames) - 1, min(snapshots, len(frames)))).astype(int)))
            for j, i in enumerate(picks):
                shade = 0.35 + 0.65 * (j + 1) / len(picks)
                f, p = frames[i]
                last = j == len(picks) - 1
                draw.draw_skeleton_3d(img, view, p.joints, tuple(int(v) for v in colour * shade),
                                      f"#{track} frames {frames[0][0].index}-{f.index}" if last else None,
                                      shadow=last)
        draw.put_text(img, title, (10, 30), 0.8, (200, 200, 200), 2)
        panels.append(img)
    sheet = np.concatenate([panels[0], np.full((panel, 4, 3), 8, np.uint8), panels[1]], axis=1)
    header = np.full((50, sheet.shape[1], 3), 8, np.uint8)
    names = " and ".join(c.name for c in cams.cameras)
    text = f"{Path(stereo_dir).name}: cameras {names}"
    if cams.baseline_m is not None:
        text += f", baseline {cams.baseline_m:.2f} m"
    if cams.rotation_deg is not None:
        text += f", rotation {cams.rotation_deg:.0f} deg"
    text += f"; {len(stream.frames)} frames, {len(stream.tracks)} track(s); pelvis path darker = earlier"
    draw.put_text(header, text, (10, 34), 0.75, draw.TEXT_COLOUR, 1)
    return write_png(out_png, np.concatenate([header, sheet], axis=0))
