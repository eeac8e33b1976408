"""A recorded take as the viewer shows it (:func:`open_take`): what ``mocapdb render`` draws, as JSON.

A ``mocapdb reconstruct`` folder shows its track files (:func:`mocapdb.render.tracks.file_scene`:
the whole take, on the world's floor) in their own frame, re-projected through the take's camera
(the result's header, else the keypoints' ``take.json``, else reconstruct's defaults); without
track files or ``world.json`` its per-frame stream, in the view frame. A ``mocapdb stereo`` folder
shows its people in the stereo world (y up) with both cameras, re-projected into camera 1.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapdb.core.formats.take import read_take, resolve_camera
from mocapdb.core.geometry import quat_to_matrix
from mocapdb.core.outputs import CAMERA_FROM_VIEW
from mocapdb.core.skeleton import KEYPOINTS
from mocapdb.render.draw import project_pinhole
from mocapdb.render.results import (
    RenderError,
    ResultStream,
    StereoCameras,
    load_keypoints,
    read_cameras,
    read_result,
    recorded_camera,
)
from mocapdb.render.stereo_plot import stereo_basis
from mocapdb.render.tracks import FileScene, file_scene, track_texts, turning_path
from mocapdb.view import payload

FILE_PATTERNS = ("track_*.bvh", "track_*.trc", "track_*.csv", "stereo*.bvh", "world.json", "result.jsonl",
                 "cameras.json", "calibration.toml", "preview.png")
MAX_FRAMES_PER_REQUEST = 1000
JPEG_QUALITY = 85
RECENT_FRAMES = 16   # video frames kept after reading, and read on (not sought) up to this far ahead
_ANKLES = [KEYPOINTS.index("r_ankle"), KEYPOINTS.index("l_ankle")]
_OPENCV = np.diag([1.0, -1.0, 1.0])   # camera-aligned ↔ OpenCV camera axes


@dataclass
class ViewTrack:
    """One person as drawn: input frame numbers ``[F]``, scene joints ``[F, 15, 3]`` and their
    pixels ``[F, 15, 2]``, what the page says of it (label, legend, colour, main), and by frame number
    where its face and hands point (:func:`payload.end_directions`; frames the stream turns them in)."""
    track: int
    frames: np.ndarray
    scene: np.ndarray
    pixels: np.ndarray
    info: dict
    ends: dict[int, dict] = field(default_factory=dict)
    rows: dict[int, int] = field(init=False)

    def __post_init__(self) -> None:
        self.rows = {f: i for i, f in enumerate(self.frames.tolist())}


class TakeView:
    """A take ready to serve: ``meta`` (the page's description of it), the frames' JSON by their
    position on the timeline (:meth:`frames_json`) and the video's frames as JPEG (:meth:`video_jpeg`)."""

    def __init__(self, meta: dict, frames: list[int], times: list[float], tracks: list[ViewTrack],
                 keypoints: dict[int, list] | None, video=None) -> None:
        self.meta, self.frames, self.times, self.tracks = meta, frames, times, tracks
        self.keypoints, self.video = keypoints, video
        self._video_lock = threading.Lock()
        self._recent: dict[int, np.ndarray | None] = {}   # the video frames read last, by index

    def frames_json(self, start: int, count: int) -> list[dict]:
        """The frames at timeline positions ``start`` to ``start + count`` (at most
        :data:`MAX_FRAMES_PER_REQUEST`): each person's scene joints, pixels, face and hands' directions,
        the input keypoints and hands."""
        out = []
        for pos in range(max(0, start), min(len(self.frames), start + min(count, MAX_FRAMES_PER_REQUEST))):
            index = self.frames[pos]
            people = [{"track": t.track, "joints": payload.numbers(t.scene[row], 5),
                       "px": payload.numbers(t.pixels[row], 1), **t.ends.get(index, {})}
                      for t in self.tracks if (row := t.rows.get(index)) is not None]
            item = {"frame": index, "time": round(self.times[pos], 6), "people": people}
            if self.keypoints is not None:
                item["keypoints"] = payload.input_people(self.keypoints.get(index, []))
                if (hands := payload.input_hands(self.keypoints.get(index, []))) is not None:
                    item["hands"] = hands
            out.append(item)
        return out

    def video_jpeg(self, index: int) -> bytes | None:
        """Frame ``index`` of the video as JPEG (None: no video or no such frame)."""
        if self.video is None:
            return None
        import cv2

        with self._video_lock:
            img = self._video_frame(index)
        if img is None:
            return None
        ok, data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        return data.tobytes() if ok else None

    def _video_frame(self, index: int) -> np.ndarray | None:
        """Frame ``index``: from the frames read last, else read on (a page asks for a few frames
        ahead at once, in any order: a seek for each would cost far more than reading on)."""
        if index in self._recent:
            return self._recent[index]
        if not self.video.next <= index <= self.video.next + RECENT_FRAMES:
            return self.video.get(index)
        img = None
        for k in range(self.video.next, index + 1):
            img = self._recent[k] = self.video.get(k)
        for k in [k for k in self._recent if k <= index - RECENT_FRAMES]:
            del self._recent[k]
        return img

    def close(self) -> None:
        if self.video is not None:
            self.video.close()


def written_files(folder: Path) -> list[str]:
    """The files a run wrote in ``folder`` that the page links to."""
    return sorted({p.name for pattern in FILE_PATTERNS for p in folder.glob(pattern) if p.is_file()})


def _take_image(stream: ResultStream, keypoints: str | Path | None, video_size: tuple[int, int] | None) -> dict:
    """The camera of a single-camera run: the result's header, else the keypoints' take.json, else
    the video's size and reconstruct's defaults."""
    info, where = recorded_camera(stream.path), f"the header of {stream.path}"
    if info is None and keypoints is not None and Path(keypoints).is_dir():
        info, where = read_take(keypoints), f"{keypoints}/take.json"
    size = video_size if info is None or info.image_size is None else None
    settings = resolve_camera(info, where, None, size, None)
    return payload.image(settings.focal_px, settings.image_size)


def _floor_y(tracks: list[ViewTrack]) -> float:
    """Where to draw the grid without a floor: under the lowest ankles (2nd percentile) less 8 cm."""
    ankles = np.concatenate([t.scene[:, _ANKLES, 1].ravel() for t in tracks]) if tracks else np.zeros(0)
    ankles = ankles[np.isfinite(ankles)]
    return round(float(np.percentile(ankles, 2)) - 0.08, 3) if len(ankles) else 0.0


def _project(image: dict, camera_aligned: np.ndarray) -> np.ndarray:
    return project_pinhole(camera_aligned, image["focal"], (image["cx"], image["cy"]))


def _end_directions(stream: ResultStream, to_scene: np.ndarray) -> dict[int, dict[int, dict]]:
    """Per track, by frame number, where the face and hands point (:func:`payload.end_directions`) in the
    frames whose stream line turns them; ``to_scene`` the view frame's rotation into the scene."""
    out: dict[int, dict[int, dict]] = {}
    for f in stream.frames:
        for p in f.people:
            if p.quaternions is not None and p.end_quaternions is not None:
                out.setdefault(p.track, {})[f.index] = payload.end_directions(p.quaternions, p.end_quaternions,
                                                                              to_scene)
    return out


def _stream_tracks(stream: ResultStream, image: dict, scene_from_aligned: np.ndarray) -> list[ViewTrack]:
    """The per-frame stream's people, ``scene_from_aligned`` the rotation of camera-aligned joints into the scene."""
    frames: dict[int, list[int]] = {}
    joints: dict[int, list[np.ndarray]] = {}
    for f in stream.frames:
        for p in f.people:
            frames.setdefault(p.track, []).append(f.index)
            joints.setdefault(p.track, []).append(p.joints)
    ends = _end_directions(stream, scene_from_aligned * CAMERA_FROM_VIEW)
    tracks = []
    for k in sorted(frames):
        aligned = np.stack(joints[k])
        tracks.append(ViewTrack(k, np.array(frames[k]), aligned @ scene_from_aligned.T, _project(image, aligned),
                                {"track": k, "label": f"#{k}", "legend": f"#{k}", "colour": payload.colour(k),
                                 "main": False}, ends.get(k, {})))
    return tracks


PATH_CAMERAS = 6   # a turning camera's frustums drawn along its path, first frame to last


def path_cameras(scene: FileScene, image: dict) -> list[dict]:
    """A turning camera's frustums at :data:`PATH_CAMERAS` frames spread over its path (``world.json``'s
    ``camera_path``, files on the floor), the last labelled with its frame and turn; none for a still
    camera or without a floor. Frame ``t``'s rows are its right, down and forward: ``view_to_files_t``
    applied to the view frame's (as the reference camera's, ``FileScene.camera_axes``)."""
    if scene.world is None or scene.camera_scene is None:
        return []
    path = turning_path(scene.world)
    if path is None:
        return []
    turns = quat_to_matrix(np.array(path["view_to_files_wxyz"], dtype=np.float64))
    picks = np.unique(np.linspace(0, len(turns) - 1, PATH_CAMERAS).round().astype(int))[1:]
    return [payload.camera(f"path {path['frames'][i]}", scene.camera_scene,
                           payload.VIEW_AXES @ turns[i].T * CAMERA_FROM_VIEW, payload.fov(image),
                           f"frame {path['frames'][i]}, {path['turn_deg'][i]:.1f} deg" if i == picks[-1] else "")
            for i in picks]


def _world_summary(scene: FileScene) -> tuple[list[str], str]:
    """The summary's line on the camera and the camera's label in the 3D view."""
    camera = (scene.world.camera if scene.world is not None else None) or {}
    height, pitch, roll = camera.get("height_m"), camera.get("pitch_deg"), camera.get("roll_deg")
    if not scene.on_floor or not isinstance(height, (int, float)):
        return ["world: no floor found: the camera at the origin"], "camera"
    spread = "given" if camera.get("height_given") else payload.spread_text(camera.get("height_log_sd")).strip()
    tilt = f"pitched {abs(pitch):.1f}° {'down' if pitch >= 0 else 'up'}, roll {roll:.1f}°" \
        if isinstance(pitch, (int, float)) and isinstance(roll, (int, float)) else ""
    return [f"camera {height:.2f} m above the floor ({spread}), {tilt}"], f"camera {height:.2f} m"


def _file_tracks(scene: FileScene, image: dict, ends: dict[int, dict[int, dict]]) -> list[ViewTrack]:
    """The track files' people: scene joints in the files' own frame (on the floor), labelled with
    ``world.json``'s facts: id, main, stature ± its spread, flags; legend with legs, distance, contact;
    ``ends`` the stream's face and hands' directions per track."""
    world = scene.world
    tracks = []
    for t in scene.tracks:
        facts = (world.tracks.get(t.track) if world is not None else None) or {}
        main = t.track == scene.main_track
        _, legend = track_texts(t.track, facts, main)
        label = f"#{t.track}" + (" main" if main else "")
        if isinstance(facts.get("stature_m"), (int, float)):
            label += f" {facts['stature_m']:.2f} m" + payload.spread_text(facts.get("stature_log_sd"))
        flags = list(facts.get("flags") or [])
        label += "".join(f" · {flag}" for flag in flags)
        distance = facts.get("distance_m")
        if isinstance(distance, list) and len(distance) == 2:
            legend += f"; {distance[0]:.1f}–{distance[1]:.1f} m away"
        tracks.append(ViewTrack(t.track, t.frames, t.scene * CAMERA_FROM_VIEW, _project(image, t.camera),
                                {"track": t.track, "label": label, "legend": legend,
                                 "colour": payload.colour(t.track), "main": main}, ends.get(t.track, {})))
    return tracks


def _stereo(stream: ResultStream, cams: StereoCameras) -> tuple[dict, list[ViewTrack], list[dict], list[str]]:
    """A stereo run: camera 1's image, its people in the stereo world (y up; the view frame of
    camera 1 when it records no world), both cameras, the summary."""
    c1 = cams.cameras[0]
    image = payload.image(float(c1.K[0, 0]), c1.size, (float(c1.K[0, 2]), float(c1.K[1, 2])))
    basis = stereo_basis(cams)
    world = np.diag(CAMERA_FROM_VIEW) if basis is None else np.diag(CAMERA_FROM_VIEW) @ basis  # right-handed
    tracks = _stream_tracks(stream, image, world)
    cameras = []
    for c in cams.cameras:
        axes = c.R @ _OPENCV @ world.T
        view_fov = (c.size[0] / 2 / c.K[0, 0], c.size[1] / 2 / c.K[1, 1])
        cameras.append(payload.camera(c.name, world @ _OPENCV @ c.center_m, axes, view_fov, c.name))
    summary = ["cameras " + " and ".join(c.name for c in cams.cameras)
               + (f", {cams.baseline_m:.2f} m apart" if cams.baseline_m is not None else "")
               + (f", turned {cams.rotation_deg:.0f}°" if cams.rotation_deg is not None else "")]
    return image, tracks, cameras, summary


def open_take(result: str | Path, keypoints: str | Path | None = None, video: str | Path | None = None,
              warn: Callable[[str], None] = lambda text: None) -> TakeView:
    """The take in ``result`` (a ``reconstruct`` or ``stereo`` folder, or its result.jsonl) with the
    input ``keypoints`` and ``video`` when given; RenderError (a UsageError) naming what cannot be read."""
    stream = read_result(result)
    folder = stream.path.parent
    if not stream.frames:
        raise RenderError(f"{stream.path}: no frame to show (the stream holds only its header)")
    frames_in = None
    if video is not None:
        from mocapdb.render.video_io import VideoFrames

        frames_in = VideoFrames(video)
    try:
        cams = read_cameras(folder)
        note, on_floor = "", False
        if cams is not None:
            kind = "stereo"
            image, tracks, cameras, summary = _stereo(stream, cams)
        else:
            image = _take_image(stream, keypoints, frames_in.size if frames_in is not None else None)
            scene, why = file_scene(folder, stream)
            if scene is None:
                kind, note = "stream", f"the per-frame stream ({stream.path.name}): {why}"
                tracks = _stream_tracks(stream, image, np.diag(CAMERA_FROM_VIEW))
                summary, label, position, axes = [], "camera", np.zeros(3), payload.VIEW_AXES
            else:
                axes = payload.VIEW_AXES if scene.camera_axes is None else scene.camera_axes * CAMERA_FROM_VIEW
                ends = _end_directions(stream, payload.scene_from_view(axes))
                kind, tracks, on_floor = "take", _file_tracks(scene, image, ends), scene.on_floor
                summary, label = _world_summary(scene)
                position = np.zeros(3) if scene.camera_scene is None else scene.camera_scene
                note = scene.describe()
            cameras = [payload.camera("camera", position, axes, payload.fov(image), label)]
            if scene is not None:
                cameras += path_cameras(scene, image)
        if frames_in is not None and tuple(frames_in.size) != (image["width"], image["height"]):
            warn(f"the video is {frames_in.size[0]}×{frames_in.size[1]} px, the image {image['width']}×"
                 f"{image['height']} px: the video is stretched to the image")
        kp = None
        if keypoints is not None:
            kp = {k.index: k.people for k in load_keypoints(keypoints)}
    except BaseException:
        if frames_in is not None:
            frames_in.close()
        raise
    frames = [f.index for f in stream.frames]
    fps = stream.fps
    summary = [f"{len(frames)} frames at {fps:g} fps ({len(frames) / fps:.1f} s), {folder.name}"] + summary \
        + [t.info["legend"] for t in tracks]
    meta = {"kind": kind, "title": folder.name, "fps": fps, "frames": frames, "skeleton": payload.skeleton(),
            "image": image, "video": frames_in is not None, "keypoints": kp is not None,
            "tracks": [t.info for t in tracks], "cameras": cameras, "floor": on_floor,
            "floor_y": 0.0 if on_floor else _floor_y(tracks), "summary": summary,
            "files": written_files(folder), "note": note}
    times = [f.time_s if np.isfinite(f.time_s) else f.index / fps for f in stream.frames]
    return TakeView(meta, frames, times, tracks, kp, frames_in)
