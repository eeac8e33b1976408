"""Drawing skeletons with OpenCV: pinhole re-projection over the image, an orthographic 3D view
with a floor grid, and camera frusta. Images are BGR ``uint8``; colours are BGR tuples.

Conventions: joints are metres in the camera-aligned frame (x right, y up, z away from the
camera, ``data_specs/stream_output.md``); pixels are x right, y down.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from mocapdb.core import geometry
from mocapdb.core.skeleton import DRAWING_LINES, KP, PELVIS

# One colour per track (BGR), bright enough on a dark background and on video; track id modulo 10.
TRACK_COLOURS: tuple[tuple[int, int, int], ...] = (
    (14, 127, 255), (255, 160, 44), (75, 220, 60), (230, 50, 240), (25, 225, 255),
    (240, 240, 70), (75, 25, 230), (255, 110, 170), (60, 245, 210), (212, 190, 250))
INPUT_COLOUR = (150, 150, 150)     # the 2D input keypoints: thin grey
BACKGROUND = (32, 30, 28)          # dark background without a video
BORDER_COLOUR = (110, 110, 110)    # the image's edge when drawn with a margin
GRID_COLOUR = (70, 70, 70)
TEXT_COLOUR = (235, 235, 235)
POOR_MATCH = 1.0   # a match's distance_2d above this is labelled: the database has no close pose
FONT = cv2.FONT_HERSHEY_SIMPLEX


def track_colour(track: int) -> tuple[int, int, int]:
    """The BGR colour of a track id."""
    return TRACK_COLOURS[int(track) % len(TRACK_COLOURS)]


def project_pinhole(joints: np.ndarray, focal: float, principal: tuple[float, float]) -> np.ndarray:
    """Pixels ``[..., 2]`` of camera-aligned points ``[..., 3]`` (metres) through a pinhole camera:
    ``u = cx + f·x/z``, ``v = cy − f·y/z`` (y is up in the camera-aligned frame, down in pixels).
    Points at or behind the camera (z ≤ 1 mm) and unknown points give NaN."""
    opencv = np.asarray(joints, dtype=np.float64) * [1.0, -1.0, 1.0]  # camera-aligned → OpenCV axes (y down)
    with np.errstate(divide="ignore", invalid="ignore"):
        px = geometry.project_pinhole(opencv, focal, principal)
    return np.where((opencv[..., 2] > 1e-3)[..., None], px, np.nan)


def line_width(size: tuple[int, int], base: float = 1.0) -> int:
    """A line thickness (pixels) that reads well on an image of ``size`` (width, height)."""
    return max(1, int(round(base * max(size) / 600)))


def _pt(p: np.ndarray) -> tuple[int, int]:
    return int(round(float(np.clip(p[0], -1e5, 1e5)))), int(round(float(np.clip(p[1], -1e5, 1e5))))


def _finite(p: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(p)))


def put_text(img: np.ndarray, text: str, origin: tuple[int, int], scale: float, colour=TEXT_COLOUR,
             thickness: int = 1, anchor: str = "left") -> None:
    """Text with a dark outline (legible over any background); ``anchor`` left, centre or right."""
    (w, h), _ = cv2.getTextSize(text, FONT, scale, thickness)
    x, y = origin
    if anchor == "centre":
        x -= w // 2
    elif anchor == "right":
        x -= w
    x = int(np.clip(x, 2, max(2, img.shape[1] - w - 2)))
    y = int(np.clip(y, h + 2, max(h + 2, img.shape[0] - 3)))
    r = max(1, thickness)   # outline: the same glyphs shifted around (a thicker stroke changes the spacing)
    for dx, dy in ((-r, 0), (r, 0), (0, -r), (0, r), (-r, -r), (r, r), (-r, r), (r, -r)):
        cv2.putText(img, text, (x + dx, y + dy), FONT, scale, (0, 0, 0), thickness, cv2.LINE_AA)
    cv2.putText(img, text, (x, y), FONT, scale, colour, thickness, cv2.LINE_AA)


def draw_keypoints_2d(img: np.ndarray, points_px: np.ndarray, confidence: np.ndarray, offset=(0.0, 0.0),
                      scale: float = 1.0, colour=INPUT_COLOUR, threshold: float = 0.3) -> None:
    """One input person's 14 keypoints (pixels of the input image) as thin lines and dots; points
    below ``threshold`` confidence are left out. ``offset``/``scale`` map input pixels to ``img``."""
    pts = np.asarray(points_px, dtype=np.float64) * scale + np.asarray(offset)
    ok = (np.asarray(confidence) >= threshold) & np.all(np.isfinite(pts), axis=1)
    w = line_width(img.shape[1::-1], 0.6)
    for a, b in DRAWING_LINES:
        if ok[a] and ok[b]:
            cv2.line(img, _pt(pts[a]), _pt(pts[b]), colour, w, cv2.LINE_AA)
    for i in np.flatnonzero(ok):
        cv2.circle(img, _pt(pts[i]), w + 1, colour, -1, cv2.LINE_AA)


def draw_skeleton_px(img: np.ndarray, px: np.ndarray, colour, label: str | None = None, width: int | None = None,
                     dim: bool = False) -> None:
    """A skeleton given as pixels ``[15, 2]`` of ``img`` (NaN: not drawn): bones of
    :data:`DRAWING_LINES`, joint dots, the pelvis, and ``label`` above the head. ``dim``: thinner
    lines and hollow joints (used for poor fits)."""
    w = width or line_width(img.shape[1::-1], 1.4)
    if dim:
        w = max(1, w // 2)
    for a, b in DRAWING_LINES:
        if _finite(px[a]) and _finite(px[b]):
            cv2.line(img, _pt(px[a]), _pt(px[b]), colour, w, cv2.LINE_AA)
    for i in range(len(px)):
        if _finite(px[i]):
            cv2.circle(img, _pt(px[i]), w + 1, colour, 1 if dim else -1, cv2.LINE_AA)
    if _finite(px[PELVIS]) and _finite(px[KP["neck"]]):   # the spine, thinner
        cv2.line(img, _pt(px[PELVIS]), _pt(px[KP["neck"]]), colour, max(1, w // 2), cv2.LINE_AA)
    if label:
        known = px[np.all(np.isfinite(px), axis=1)]
        if len(known):
            head = px[KP["head"]] if _finite(px[KP["head"]]) else known[np.argmin(known[:, 1])]
            top = float(np.min(known[:, 1]))
            put_text(img, label, (int(head[0]), int(min(top, head[1]) - 3 * w - 4)), 0.22 * w + 0.3, colour,
                     max(1, w // 2), "centre")


def track_label(track: int, distance_2d: float | None = None, at_edge: bool = False, name: str | None = None) -> str:
    """``#3`` (or ``name``); ``poor match 2.4`` added when the database's pose is far from the
    keypoints (Eq. 1 distance), ``at image edge`` when the skeleton touches the image's border
    (often a false detection, or a person cut by the frame)."""
    text = name or f"#{track}"
    if distance_2d is not None and distance_2d > POOR_MATCH:
        text += f" poor match {distance_2d:.1f}"
    if at_edge:
        text += " at image edge"
    return text


def at_image_edge(px: np.ndarray, size: tuple[int, int], border: float = 0.01) -> bool:
    """Whether any known point of ``px [N, 2]`` (image pixels) lies within ``border`` of the image's
    size from its edge, or outside the image."""
    p = px[np.all(np.isfinite(px), axis=1)]
    if not len(p):
        return False
    b = border * max(size)
    return bool(np.any((p[:, 0] < b) | (p[:, 1] < b) | (p[:, 0] > size[0] - b) | (p[:, 1] > size[1] - b)))


# --------------------------------------------------------------------------- 3D view


def _unit(v: np.ndarray) -> np.ndarray | None:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-9 and math.isfinite(n) else None


def body_up(joints: np.ndarray) -> np.ndarray:
    """The mean pelvis → neck direction of poses ``[N, 15, 3]`` (people stand mostly upright), or +y."""
    if len(joints):
        d = joints[:, KP["neck"]] - joints[:, PELVIS]
        d = d[np.all(np.isfinite(d), axis=1)]
        if len(d):
            up = _unit(np.mean(d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9), axis=0))
            if up is not None and up[1] > 0.5:
                return up
    return np.array([0.0, 1.0, 0.0])


def basis_with_up(up: np.ndarray) -> np.ndarray:
    """Rows: scene right, up, forward (camera-aligned coordinates) with the given up, forward as
    near the camera's +z as possible: the scene frame of :class:`View3D`."""
    unit_up = _unit(np.asarray(up, dtype=np.float64))
    if unit_up is None:
        raise ValueError(f"no up direction in {up!r}")
    fwd = _unit(np.array([0.0, 0.0, 1.0]) - unit_up[2] * unit_up)
    if fwd is None:
        raise ValueError("up along the camera's z: no forward direction for the scene")
    right = np.cross(unit_up, fwd)
    if right[0] < 0:
        right = -right
    return np.stack([right, unit_up, fwd])


@dataclass
class View3D:
    """An orthographic view of a scene from a fixed oblique angle.

    ``basis`` (rows) maps input coordinates to the scene frame (x right, y up, z forward); the view
    turns the scene by ``azimuth_deg`` about up and looks down by ``elevation_deg`` (90: top view).
    ``centre`` (scene x, z), ``half_extent`` (metres) and ``floor`` (scene y) fix the grid.
    """
    basis: np.ndarray
    centre: np.ndarray
    half_extent: float
    floor: float
    top: float
    azimuth_deg: float = -35.0
    elevation_deg: float = 22.0

    def scene(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, dtype=np.float64) @ self.basis.T

    def _screen(self, scene: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a, e = math.radians(self.azimuth_deg), math.radians(self.elevation_deg)
        x, y, z = scene[..., 0] - self.centre[0], scene[..., 1], scene[..., 2] - self.centre[1]
        x1 = math.cos(a) * x - math.sin(a) * z
        z1 = math.sin(a) * x + math.cos(a) * z
        sy = math.cos(e) * y + math.sin(e) * z1
        depth = -math.sin(e) * y + math.cos(e) * z1
        return np.stack([x1, sy], axis=-1), depth

    def _fit(self, size: tuple[int, int]) -> tuple[float, np.ndarray]:
        h = self.half_extent
        corners = np.array([[x, y, z] for x in (-h, h) for z in (-h, h) for y in (self.floor, self.top)])
        corners[:, 0] += self.centre[0]
        corners[:, 2] += self.centre[1]
        s, _ = self._screen(corners)
        lo, hi = s.min(axis=0), s.max(axis=0)
        pad = 0.06
        k = min(size[0] * (1 - 2 * pad) / max(hi[0] - lo[0], 1e-6), size[1] * (1 - 2 * pad) / max(hi[1] - lo[1], 1e-6))
        return k, (lo + hi) / 2

    def project(self, points: np.ndarray, size: tuple[int, int], scene: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Panel pixels ``[..., 2]`` and depths ``[...]`` (larger: further) of input points (scene
        points when ``scene``) in a panel of ``size`` (width, height)."""
        s, depth = self._screen(np.asarray(points, dtype=np.float64) if scene else self.scene(points))
        k, mid = self._fit(size)
        px = np.stack([size[0] / 2 + k * (s[..., 0] - mid[0]), size[1] / 2 - k * (s[..., 1] - mid[1])], axis=-1)
        return px, depth


def fit_view(joints: np.ndarray, basis: np.ndarray | None = None, extra_points: np.ndarray | None = None,
             azimuth_deg: float = -35.0, elevation_deg: float = 22.0, ankle_height_m: float = 0.08) -> View3D:
    """A :class:`View3D` holding every pose of ``joints [N, 15, 3]`` (and ``extra_points [M, 3]``,
    e.g. cameras) for the whole sequence, so the view does not move between frames. ``basis``
    None: up from the bodies (:func:`body_up`); the floor is the low ankles' level minus the
    ankle height."""
    basis = basis_with_up(body_up(joints)) if basis is None else np.asarray(basis, dtype=np.float64)
    pts = joints.reshape(-1, 3) if len(joints) else np.zeros((0, 3))
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    scene = pts @ basis.T
    if len(scene):
        ankles = joints[:, [KP["r_ankle"], KP["l_ankle"]]].reshape(-1, 3)
        ankles = ankles[np.all(np.isfinite(ankles), axis=1)] @ basis.T
        floor = (float(np.percentile(ankles[:, 1], 5)) if len(ankles) else float(scene[:, 1].min())) - ankle_height_m
        top = max(float(scene[:, 1].max()), floor + 1.9)
    else:
        floor, top = -1.0, 1.0
    xz = scene[:, [0, 2]]
    if extra_points is not None and len(extra_points):
        extra = np.asarray(extra_points, dtype=np.float64) @ basis.T
        xz = np.concatenate([xz, extra[:, [0, 2]]])
        top = max(top, float(extra[:, 1].max()))
        floor = min(floor, float(extra[:, 1].min()) - 0.3) if not len(scene) else floor
    if len(xz):
        lo, hi = xz.min(axis=0), xz.max(axis=0)
        centre, half = (lo + hi) / 2, max(float(np.max(hi - lo)) / 2 + 0.6, 1.2)
    else:
        centre, half = np.zeros(2), 2.0
    return View3D(basis, centre, half, floor, top, azimuth_deg, elevation_deg)


GRID_LINES = 12  # at most this many grid spacings across the floor, whatever its extent


def grid_step(half_extent: float) -> float:
    """Grid spacing (metres): the smallest of 0.25 m and 1, 2, 5 × 10ᵏ m giving at most
    :data:`GRID_LINES` spacings across ``2 · half_extent`` (metres, finite), however large."""
    span = 2 * half_extent / GRID_LINES
    if span <= 0.25:
        return 0.25
    power = 10.0 ** math.floor(math.log10(span))
    return next(m * power for m in (1, 2, 5, 10) if m * power >= span)


def draw_floor(img: np.ndarray, view: View3D, colour=GRID_COLOUR, label: bool = True) -> None:
    """The floor grid of ``view`` (scene plane y = floor), with its spacing written in a corner: at
    most :data:`GRID_LINES` + 1 lines each way (:func:`grid_step`), so time and memory stay bounded
    whatever the coordinates."""
    size = img.shape[1::-1]
    h, step = view.half_extent, grid_step(view.half_extent)
    cx, cz = view.centre
    lines = []   # on whole multiples of the step (scene metres), inside the square ± h around the centre
    for x in np.arange(math.ceil((cx - h) / step) * step, cx + h + 1e-9, step):
        lines.append(([x, view.floor, cz - h], [x, view.floor, cz + h]))
    for z in np.arange(math.ceil((cz - h) / step) * step, cz + h + 1e-9, step):
        lines.append(([cx - h, view.floor, z], [cx + h, view.floor, z]))
    for a, b in lines:
        px, _ = view.project(np.array([a, b]), size, scene=True)
        cv2.line(img, _pt(px[0]), _pt(px[1]), colour, 1, cv2.LINE_AA)
    if label:
        put_text(img, f"grid {step:g} m", (8, size[1] - 10), 0.4 + size[1] / 2400, (150, 150, 150), 1)


def draw_skeleton_3d(img: np.ndarray, view: View3D, joints: np.ndarray, colour, label: str | None = None,
                     dim: bool = False, shadow: bool = True) -> None:
    """A skeleton ``[15, 3]`` (input coordinates) in the 3D panel ``img`` seen by ``view``, with its
    shadow on the floor (a dark line below the feet shows the height above the floor)."""
    size = img.shape[1::-1]
    w = line_width(size, 1.2)
    if shadow:
        scene = view.scene(joints)
        flat = scene.copy()
        flat[:, 1] = view.floor
        spx, _ = view.project(flat, size, scene=True)
        for a, b in DRAWING_LINES:
            if _finite(spx[a]) and _finite(spx[b]):
                cv2.line(img, _pt(spx[a]), _pt(spx[b]), (55, 55, 55), max(1, w), cv2.LINE_AA)
    px, _ = view.project(joints, size)
    draw_skeleton_px(img, px, colour, label, width=w, dim=dim)


def draw_camera_3d(img: np.ndarray, view: View3D, centre: np.ndarray, axes: np.ndarray, fov: tuple[float, float],
                   depth: float, colour, name: str) -> None:
    """A camera as a frustum: ``centre`` (input coordinates), ``axes`` rows right, down, forward
    (input coordinates), ``fov`` the half-angle tangents (x, y), ``depth`` metres, its name."""
    size = img.shape[1::-1]
    axis_end = centre + 2.2 * depth * axes[2]   # the optical axis, further than the frustum
    corners = [centre + depth * (axes[2] + sx * fov[0] * axes[0] + sy * fov[1] * axes[1])
               for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    pts, _ = view.project(np.array([centre] + corners + [axis_end]), size)
    w = line_width(size, 1.2)
    cv2.line(img, _pt(pts[0]), _pt(pts[5]), colour, max(1, w // 2), cv2.LINE_AA)
    for i in range(1, 5):
        cv2.line(img, _pt(pts[0]), _pt(pts[i]), colour, w, cv2.LINE_AA)
        cv2.line(img, _pt(pts[i]), _pt(pts[1 + i % 4]), colour, w, cv2.LINE_AA)
    up_edge = (pts[1] + pts[2]) / 2   # the image's top edge (y down): marks which way is up
    cv2.circle(img, _pt(up_edge), w + 2, colour, -1, cv2.LINE_AA)
    cv2.circle(img, _pt(pts[0]), w + 3, colour, -1, cv2.LINE_AA)
    put_text(img, name, (int(pts[0][0]) + 10, int(pts[0][1]) - 10), 0.5 + size[1] / 2000, colour, max(1, w // 2 + 1))


def people_view(tracks: dict[int, np.ndarray], main: int | None = None, basis: np.ndarray | None = None,
                floor: float | None = None, camera: np.ndarray | None = None, share: float = 0.9,
                margin_m: float = 0.8, min_half_m: float = 1.5, azimuth_deg: float = -35.0,
                elevation_deg: float = 22.0) -> View3D:
    """A :class:`View3D` at a scale that shows people: its floor square holds the ``main`` track's
    whole pelvis path and the middle ``share`` of everyone's pelvis positions (their frames pooled),
    plus ``margin_m`` (metres; half side at least ``min_half_m``), so a short-lived outlier 50 m
    away is left outside instead of shrinking everyone to dots. ``tracks``: per track id its poses
    ``[F, 15, 3]`` (input coordinates); ``basis`` None: up from the bodies (:func:`body_up`);
    ``floor`` None: the low ankles' level minus 8 cm, else that scene height (0: the files' floor);
    ``camera``: a point (input coordinates) taken into the square when within twice its half side."""
    poses = [p for p in tracks.values() if len(p)]
    everyone = np.concatenate(poses) if poses else np.zeros((0, len(KP), 3))
    basis = basis_with_up(body_up(everyone)) if basis is None else np.asarray(basis, dtype=np.float64)
    view = fit_view(everyone, basis, azimuth_deg=azimuth_deg, elevation_deg=elevation_deg)
    pelvis = everyone[:, PELVIS] @ basis.T
    ok = np.all(np.isfinite(pelvis), axis=1)
    if not np.any(ok):
        return view
    lo, hi = np.percentile(pelvis[ok][:, [0, 2]], [50 * (1 - share), 50 * (1 + share)], axis=0)
    if main is not None and main in tracks and len(tracks[main]):
        path = (tracks[main][:, PELVIS] @ basis.T)[:, [0, 2]]
        path = path[np.all(np.isfinite(path), axis=1)]
        if len(path):
            lo, hi = np.minimum(lo, path.min(axis=0)), np.maximum(hi, path.max(axis=0))
    centre, half = (lo + hi) / 2, max(float(np.max(hi - lo)) / 2 + margin_m, min_half_m)
    if camera is not None:
        cam = (np.asarray(camera, dtype=np.float64) @ basis.T)[[0, 2]]
        if np.max(np.abs(cam - centre)) <= 2 * half:
            lo, hi = np.minimum(lo, cam), np.maximum(hi, cam)
            centre, half = (lo + hi) / 2, float(np.max(hi - lo)) / 2 + margin_m
    inside = np.all(np.abs(pelvis[:, [0, 2]] - centre) <= half, axis=1)
    heights = (everyone[inside] @ basis.T)[..., 1].ravel()
    heights = heights[np.isfinite(heights)]
    view.floor = view.floor if floor is None else float(floor)
    view.top = max(float(np.percentile(heights, 99)) if len(heights) else view.floor, view.floor + 1.9)
    if camera is not None and np.max(np.abs(cam - centre)) <= half:
        view.top = max(view.top, float((np.asarray(camera) @ basis.T)[1]))
    view.top += 0.2 + 0.1 * half   # room for the labels above the heads
    view.centre, view.half_extent = centre, half
    return view


def draw_legend(img: np.ndarray, lines: list[tuple[tuple[int, int, int], str]], origin: tuple[int, int],
                scale: float) -> None:
    """Lines of text, each in its colour, from ``origin`` (pixels, the first line's baseline) down."""
    (_, h), _ = cv2.getTextSize("Ag", FONT, scale, 1)
    x, y = origin
    for colour, text in lines:
        put_text(img, text, (x, y), scale, colour, 1)
        y += int(h * 1.7) + 1
