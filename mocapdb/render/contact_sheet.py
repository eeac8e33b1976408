"""``mocapdb render --contact-sheet`` and ``reconstruct --preview``: one PNG, a grid of evenly
spaced frames of a result with their overlays (:func:`contact_sheet`).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from mocapdb.core.outputs import check_output_file
from mocapdb.render import draw
from mocapdb.render.frame_layout import compose_frame, image_camera
from mocapdb.render.results import RenderError
from mocapdb.render.video import DEFAULT_FOCAL, DEFAULT_IMAGE_SIZE, as_drawn, prepare
from mocapdb.render.video_io import PNG_FILE, VideoFrames, write_png


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
    width, height = image_size  # a pair, a list too
    camera = image_camera(float(focal), (width, height))
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
