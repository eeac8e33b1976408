"""``mocapdb render`` of a ``mocapdb stereo`` output: one PNG of the two cameras and the people's
motion, from above and obliquely (:func:`render_stereo_plot`). OpenCV only (no matplotlib).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mocapdb.core.outputs import check_output_file
from mocapdb.core.skeleton import PELVIS
from mocapdb.render import draw
from mocapdb.render.results import RenderError, read_cameras, read_result
from mocapdb.render.video_io import PNG_FILE, write_png


def stereo_basis(cams) -> np.ndarray | None:
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
    basis = stereo_basis(cams)
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
