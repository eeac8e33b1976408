"""One output frame of ``mocapdb render``: its layout (:class:`Layout`: the image panel and/or the
3D panel), the camera a result was made with (:func:`image_camera`) and the drawing of the panels
(:func:`compose_frame`, :func:`image_panel`, :func:`panel_3d`).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from mocapdb.core.cameras import CameraModel, camera_from_intrinsics
from mocapdb.core.skeleton import PELVIS
from mocapdb.render import draw
from mocapdb.render.results import RenderError, ResultFrame, TrackPose
from mocapdb.render.tracks import FileScene

VIEWS = ("both", "image", "3d")
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
    if scene is None or scene.camera_scene is None or scene.camera_axes is None or scene.world is None \
            or scene.world.height_m is None:
        raise RuntimeError("the camera is drawn only on the track files' floor (its centre, axes and height)")
    centre, height_m = scene.camera_scene, scene.world.height_m
    if np.max(np.abs(view.scene(centre)[[0, 2]] - view.centre)) > view.half_extent:
        return
    cam = layout.camera
    fov = (cam.size[0] / 2 / cam.K[0, 0], cam.size[1] / 2 / cam.K[1, 1])
    foot = centre * [1.0, 0.0, 1.0] + [0.0, view.floor, 0.0]
    px, _ = view.project(np.array([centre, foot]), panel.shape[1::-1])
    cv2.line(panel, draw._pt(px[0]), draw._pt(px[1]), (150, 150, 150), 1, cv2.LINE_AA)
    draw.draw_camera_3d(panel, view, centre, scene.camera_axes, fov, 0.08 * view.half_extent, (200, 200, 200), "")
    draw.put_text(panel, f"camera {height_m:.2f} m up", (int(px[1][0]), int(px[1][1]) + 16),
                  0.3 + panel.shape[0] / 2400, (200, 200, 200), anchor="centre")
