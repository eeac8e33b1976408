"""A real multi-person take as `mocapdb reconstruct --floor` sees it: one picture for the docs.

    mocapdb reconstruct data/sample_keypoints/video_sports2d --db demo/sample.db --out /tmp/sports2d \\
        --format bvh,csv --floor
    python tools/world_figure.py /tmp/sports2d data/sample_keypoints/video_sports2d \\
        ../shared/data/videos/sports2d_demo/demo.mp4 --png docs/world_sports2d.png

For a few frames (``--frames``, default three: in each third of the take the frame showing most
tracks), side by side: the video frame with the detector's keypoints (grey) and every track file
re-projected (one colour per track, labelled with its id, "main" and its stature), and the track
files in 3D on the floor the take found (y = 0, grid 1 m, the camera at its height), each person
labelled with its stature and where it stands ("on the floor", "2.0 m above the floor"). Below,
each track's line of ``world.json``: stature with its error and source, legs, where it stands,
flags. Drawn by `mocapdb render`'s own functions (what `render` draws by default); frames decoded
by the project's video reader. Written as a palette PNG (Pillow, from matplotlib's dependencies).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.detect.video import VideoReader  # noqa: E402
from mocapdb.render import draw  # noqa: E402
from mocapdb.render.frame_layout import Layout, image_camera, image_panel, panel_3d  # noqa: E402
from mocapdb.render.results import ResultFrame, TrackPose, load_keypoints, read_result, recorded_camera  # noqa: E402
from mocapdb.render.tracks import FileScene, file_scene, people_at  # noqa: E402

BACKGROUND = (8, 8, 8)
TEXT = (235, 235, 235)
DIM_TEXT = (170, 170, 170)
PANEL_3D_ASPECT = 1.45   # the 3D panel's width over its height


def pick_frames(scene: FileScene, frames: list[int], n: int) -> list[int]:
    """In each of ``n`` equal parts of ``frames`` (input frame numbers), the frame holding the most
    track files (the middle one of the ties)."""
    present = {i: 0 for i in frames}
    for t in scene.tracks:
        for i in t.frames.tolist():
            if i in present:
                present[i] += 1
    picks = []
    for part in np.array_split(np.array(frames), n):
        counts = np.array([present[i] for i in part])
        best = part[counts == counts.max()]
        picks.append(int(best[len(best) // 2]))
    return picks


def video_frames(path: str, wanted: list[int]) -> dict[int, np.ndarray]:
    """The frames ``wanted`` (indices from 0) of a video, decoded with mocapdb's reader."""
    reader = VideoReader(path)
    try:
        got = {}
        for frame in reader.frames():
            if frame.index in wanted:
                got[frame.index] = frame.image
            if frame.index >= max(wanted):
                break
        return got
    finally:
        reader.close()


def short_where(facts: dict | None) -> str:
    """Where a person stands in a few words: on the floor, 2.0 m above the floor, no planted foot."""
    facts = facts or {}
    feet = facts.get("feet_above_floor_m")
    if isinstance(feet, (int, float)) and feet > 0.1:
        return f"{feet:.1f} m above the floor"
    return {"floor": "on the floor", "no contacts": "no planted foot",
            "unreliable": "feet do not fit the floor"}.get(facts.get("kind"), "")


def labelled_3d(scene: FileScene, people: list[TrackPose]) -> list[TrackPose]:
    """The 3D view's people, each labelled with its size and where it stands."""
    facts = scene.world.tracks if scene.world is not None else {}
    out = []
    for p in people:
        where = short_where(facts.get(p.track))
        out.append(TrackPose(p.track, p.joints, label=f"{p.label}, {where}" if where else p.label))
    return out


def frame_row(scene: FileScene, image_layout: Layout, layout_3d: Layout, frame: ResultFrame, keypoints,
              video: np.ndarray | None) -> np.ndarray:
    """One frame: the video with the re-projected track files, beside the 3D view on the floor."""
    image, floor = people_at(scene, frame)
    image = [TrackPose(p.track, p.joints, label=p.label) for p in image]   # no match distances: fewer words
    left = image_panel(image_layout, image, keypoints, video)
    right = panel_3d(layout_3d, labelled_3d(scene, floor), text_scale=0.5, legend=False)
    draw.put_text(left, f"frame {frame.index}", (6, 22), 0.6, TEXT, 1)
    h = max(left.shape[0], right.shape[0])
    row = np.full((h, left.shape[1] + 4 + right.shape[1], 3), BACKGROUND, np.uint8)
    row[:left.shape[0], :left.shape[1]] = left
    row[:right.shape[0], left.shape[1] + 4:] = right
    return row


def wrapped(text: str, width: int, scale: float) -> list[str]:
    """``text`` cut at "; " into lines no wider than ``width`` pixels where it can be."""
    lines = [""]
    for piece in text.split("; "):
        joined = f"{lines[-1]}; {piece}" if lines[-1] else piece
        if lines[-1] and cv2.getTextSize(joined, draw.FONT, scale, 1)[0][0] > width:
            lines.append(piece)
        else:
            lines[-1] = joined
    return lines


def text_block(width: int, lines: list[tuple[tuple[int, int, int], str, float]]) -> np.ndarray:
    """Lines of text (colour, text, scale) on the figure's background, ``width`` pixels wide, each
    wrapped at "; " (:func:`wrapped`)."""
    lines = [(c, piece, s) for c, text, s in lines for piece in wrapped(text, width - 20, s)]
    heights = [int(cv2.getTextSize("Ag", draw.FONT, s, 1)[0][1] * 1.9) + 4 for _, _, s in lines]
    block = np.full((sum(heights) + 10, width, 3), BACKGROUND, np.uint8)
    y = 4
    for (colour, text, s), h in zip(lines, heights):
        y += h
        draw.put_text(block, text, (10, y - 6), s, colour, 1)
    return block


def figure(rec: str, keypoints: str, video: str, frames: list[int] | None, n: int, row_height: int,
           title: str | None, elevation: float = 28.0) -> np.ndarray:
    """The figure (BGR) of a reconstruction folder, its keypoints and its video."""
    stream = read_result(rec)
    taken = recorded_camera(rec)
    camera = image_camera(taken.focal_px, taken.image_size)
    scene, why = file_scene(rec, stream)
    if scene is None:
        raise SystemExit(f"world_figure: {why}")
    kp = {k.index: k for k in load_keypoints(keypoints)}
    frames = frames or pick_frames(scene, [f.index for f in stream.frames if f.index in kp], n)
    images = video_frames(video, frames)
    scale = row_height / camera.size[1]
    tracks = {t.track: t.scene for t in scene.tracks}
    view = draw.people_view(tracks, scene.main_track, np.eye(3), 0.0, scene.camera_scene, elevation_deg=elevation)
    image_layout = Layout(camera, "image", view, scale, 0.0, scene)
    layout_3d = Layout(camera, "3d", view, scale, 0.0, scene)
    layout_3d.panel_3d = (int(PANEL_3D_ASPECT * row_height), row_height)   # wider than high: a floor seen obliquely
    by_index = {f.index: f for f in stream.frames}
    rows = [frame_row(scene, image_layout, layout_3d, by_index[i], kp.get(i), images.get(i)) for i in frames]
    width = rows[0].shape[1]
    world = scene.world
    cam = camera_text(world)
    head = [(TEXT, title or f"{Path(rec).name}: {len(scene.tracks)} tracks from one camera", 0.75),
            (DIM_TEXT, f"{cam}; left: the video, the detector's keypoints (grey), each track file re-projected; "
                       "right: the track files in 3D on that floor (grid 1 m)", 0.48)]
    legend = [(draw.track_colour(t.track), t.legend, 0.5) for t in scene.tracks]
    parts = [text_block(width, head)]
    for row in rows:
        parts += [row, np.full((4, width, 3), BACKGROUND, np.uint8)]
    parts.append(text_block(width, legend))
    return np.concatenate(parts, axis=0)


def camera_text(world) -> str:
    """The camera's height (given or estimated, with its error), pitch and roll, from world.json."""
    if not world.known:
        return "no floor found"
    c = world.camera or {}
    sd = c.get("height_log_sd")
    how = "given" if c.get("height_given") else (f"estimated ±{100 * (np.exp(sd) - 1):.0f} %"
                                                  if isinstance(sd, (int, float)) else "estimated")
    pitch, roll = c.get("pitch_deg", float("nan")), c.get("roll_deg", float("nan"))
    return (f"camera {world.height_m:.2f} m above the floor ({how}), pitched {abs(pitch):.1f} deg "
            f"{'down' if pitch >= 0 else 'up'}, roll {roll:.1f} deg")


def write_palette_png(path: Path, img: np.ndarray, colours: int) -> int:
    """``img`` (BGR) as a PNG of at most ``colours`` colours: Pillow's median cut of the picture,
    its last entries replaced by the tracks' colours and the text's, so that thin skeletons keep
    their exact colour; returns the file's bytes."""
    from PIL import Image

    rgb = Image.fromarray(np.ascontiguousarray(img[:, :, ::-1]))
    exact = [c[::-1] for c in draw.TRACK_COLOURS] + [TEXT[::-1], DIM_TEXT[::-1], (0, 0, 0), (200, 200, 200)]
    cut = np.array(rgb.quantize(colors=colours - len(exact), method=Image.Quantize.MEDIANCUT).getpalette()[
        :3 * (colours - len(exact))]).reshape(-1, 3)
    table = np.concatenate([cut, np.array(exact)]).astype(np.uint8)
    palette = Image.new("P", (1, 1))
    palette.putpalette(table.ravel().tolist())
    rgb.quantize(palette=palette, dither=Image.Dither.NONE).save(path, optimize=True)
    return path.stat().st_size


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("rec", help="the --out folder of `mocapdb reconstruct ... --floor` (track CSV or BVH, world.json)")
    p.add_argument("keypoints", help="the keypoints given to reconstruct")
    p.add_argument("video", help="the video the keypoints were detected in")
    p.add_argument("--png", required=True, type=Path, help="the picture to write")
    p.add_argument("--frames", type=lambda s: [int(v) for v in s.split(",")], help="frame numbers (default: chosen)")
    p.add_argument("--count", type=int, default=3, help="frames chosen when --frames is not given (default 3)")
    p.add_argument("--row-height", type=int, default=360, help="pixels of a frame's video row (default 360)")
    p.add_argument("--colours", type=int, default=160, help="palette colours of the PNG (default 160)")
    p.add_argument("--title", help="the figure's first line")
    args = p.parse_args(argv)
    img = figure(args.rec, args.keypoints, args.video, args.frames, args.count, args.row_height, args.title)
    size = write_palette_png(args.png, img, args.colours)
    print(f"wrote {args.png} ({img.shape[1]}x{img.shape[0]} px, {size / 1024:.0f} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
