"""What `mocapdb detect` writes: one OpenPose ``--write_json`` file per frame, and the loop that
runs the model over a video to write them.

Detections come in the detector's layout: BlazePose's 33 landmarks are written as they are
(``mediapipe33``), YOLO-pose and RTMO's COCO-17 in OpenPose's COCO-18 layout
(:func:`coco17_to_coco18`), as ``<video stem>_<frame:012d>_keypoints.json``, each file atomically,
so `mocapdb reconstruct` and `live` read them like OpenPose's own output. Each file also says its
frame's number on the video's nominal timeline and its time from the container (``frame``, ``time``:
:class:`~mocapdb.detect.video.FrameClock`), so a gap in the video keeps its length. File format:
``data_specs/pose_models.md``; the frame times: ``data_specs/take_description.md``.

The output folder is written in place as the video is read (``live`` may follow it meanwhile), not
swapped in at the end as other commands' outputs are: a folder holding anything but an earlier
detect output (its frame files and ``take.json``, :data:`DETECT_FILES`) is refused before any work,
an earlier detect output's files are deleted when the run starts, and no other file is ever
overwritten (:func:`mocapdb.core.outputs.clear_output_folder`).
"""
from __future__ import annotations

import json
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from mocapdb.core.files import os_error_message, write_atomic
from mocapdb.core.formats.camera_path import CAMERA_PATH_FILE
from mocapdb.core.formats.face_keypoints import face_field
from mocapdb.core.formats.hand_keypoints import hand_fields
from mocapdb.core.formats.keypoints import LAYOUTS
from mocapdb.core.formats.openpose import WORLD_FIELD
from mocapdb.core.formats.scene import SCENE_FILE
from mocapdb.core.formats.take import TAKE_FILE, TakeInfo, write_take
from mocapdb.core.outputs import OutputFiles, clear_output_folder
from mocapdb.core.progress import progress
from mocapdb.detect.errors import DetectError
from mocapdb.detect.video import FrameClock, VideoReader

if TYPE_CHECKING:
    from mocapdb.detect.detectors import FrameDetector
    from mocapdb.detect.face import Faces
    from mocapdb.detect.hands import Hands

N_COCO = len(LAYOUTS["coco17"])
# what an earlier output holds
DETECT_FILES = OutputFiles("detect", ("*_keypoints.json", TAKE_FILE, CAMERA_PATH_FILE, SCENE_FILE), TAKE_FILE)


class FrameWatcher(Protocol):
    """Something more `detect` reads from the decoded frames (e.g.
    :class:`~mocapdb.detect.camera_motion.BackgroundMotion`): it sees every frame written with its
    number and people, then writes its own file beside the keypoints."""

    def see(self, number: int, image: np.ndarray, keypoints: np.ndarray) -> None:
        """Frame number ``number`` (``[H, W, 3]`` BGR) and its people ``[P, K, 3]`` (x px, y px, confidence)."""

    def finish(self, out_dir: Path) -> list[str]:
        """Write its file(s) into ``out_dir``; the lines `detect` reports."""


def _coco17_name(openpose_name: str) -> str:
    """An OpenPose COCO-18 name in the COCO-17 spelling: ``RShoulder`` → ``right_shoulder``."""
    sides = {"R": "right_", "L": "left_"}
    if openpose_name[0] in sides and openpose_name[1:2].isupper():
        return sides[openpose_name[0]] + openpose_name[1:].lower()
    return openpose_name.lower()


_COCO18_SOURCE = np.array([LAYOUTS["coco17"].index(n) if n in LAYOUTS["coco17"] else -1
                           for n in map(_coco17_name, LAYOUTS["coco18"])])
_NECK = LAYOUTS["coco18"].index("Neck")
_SHOULDERS = [LAYOUTS["coco17"].index("left_shoulder"), LAYOUTS["coco17"].index("right_shoulder")]


def coco17_to_coco18(keypoints: np.ndarray) -> np.ndarray:
    """``[P, 17, 3]`` (x px, y px, confidence) → ``[P, 18, 3]`` in the OpenPose COCO-18 order.

    The neck is the mid-shoulder point with the smaller shoulder confidence; (0, 0, 0), OpenPose's
    "not found", when either shoulder has confidence 0. Non-finite entries become (0, 0, 0) too.
    """
    out = keypoints[:, np.maximum(_COCO18_SOURCE, 0)].copy()
    shoulders = keypoints[:, _SHOULDERS]
    neck_conf = shoulders[..., 2].min(axis=1)
    neck = np.concatenate([shoulders[..., :2].mean(axis=1), neck_conf[:, None]], axis=-1)
    out[:, _NECK] = np.where(neck_conf[:, None] > 0, neck, 0.0)
    return np.where(np.isfinite(out).all(axis=-1, keepdims=True), out, 0.0)


def written_layout(layout: str) -> str:
    """The layout of the files written for a detector's ``layout``: COCO-17 is written as OpenPose's
    COCO-18, any other layout as it is."""
    return "coco18" if layout == "coco17" else layout


def openpose_json(keypoints: np.ndarray, layout: str = "coco17", world: np.ndarray | None = None, *,
                  frame: int | None = None, time_s: float | None = None, hands: Hands | None = None,
                  faces: Faces | None = None) -> str:
    """One OpenPose ``--write_json`` frame (version 1.3) for people ``[P, K, 3]`` in ``layout``:
    COCO-17 becomes COCO-18 (:func:`coco17_to_coco18`), other layouts (BlazePose's 33) stay; non-finite
    points become (0, 0, 0), "not found". ``world [P, K, 3]`` (metres; BlazePose's world landmarks) is
    written as each person's :data:`WORLD_FIELD`, ``[x0, y0, z0, x1, ...]`` to 0.1 mm (a person whose
    world landmarks are not all finite gets none). ``frame`` (the frame's number at the keypoints'
    rate) and ``time_s`` (seconds since the first frame, to 1 µs) are written as ``frame`` and ``time``
    when given, the fields the JSON-lines stream reads (``data_specs/keypoint_formats.md``). ``hands``
    (:class:`~mocapdb.detect.hands.Hands`): each person's hands in OpenPose's ``hand_right_keypoints_2d``
    and ``hand_left_keypoints_2d`` and mocapdb's ``hands`` details (:func:`hand_fields`); ``faces``
    (:class:`~mocapdb.detect.face.Faces`): each person's face mesh in mocapdb's ``face_mesh`` (:func:`face_field`)."""
    size = len(LAYOUTS[layout])
    rows = np.asarray(keypoints, dtype=np.float64).reshape(-1, size, 3)
    rows = coco17_to_coco18(rows) if layout == "coco17" else \
        np.where(np.isfinite(rows).all(axis=-1, keepdims=True), rows, 0.0)
    rows = np.concatenate([np.round(rows[..., :2], 2), np.round(rows[..., 2:], 4)], axis=-1)
    people = [{"person_id": [-1], "pose_keypoints_2d": person.ravel().tolist(), "face_keypoints_2d": [],
               "hand_left_keypoints_2d": [], "hand_right_keypoints_2d": []} for person in rows]
    if world is not None:
        if layout == "coco17":
            raise ValueError("world landmarks are written for layouts written as they are, not COCO-17")
        for person, points in zip(people, np.asarray(world, dtype=np.float64).reshape(-1, size, 3)):
            if np.isfinite(points).all():
                person[WORLD_FIELD] = np.round(points, 4).ravel().tolist()
    if hands is not None:
        for i, person in enumerate(people):
            person.update(hand_fields(hands.points[i], hands.presence[i], hands.handedness[i], hands.absent[i]))
    if faces is not None:
        for i, person in enumerate(people):
            person.update(face_field(faces.points[i], faces.presence[i], faces.absent[i]))
    timing: dict[str, float] = {"frame": frame} if frame is not None else {}
    if time_s is not None:
        timing["time"] = round(time_s, 6)
    return json.dumps({"version": 1.3, **timing, "people": people})


def frame_file_name(stem: str, index: int) -> str:
    """OpenPose's per-frame file name: ``<stem>_<frame:012d>_keypoints.json``."""
    return f"{stem}_{index:012d}_keypoints.json"


@dataclass
class DetectSummary:
    """What a detect run did; :meth:`report` renders it."""

    frames_read: int = 0
    people: list[int] = field(default_factory=list)   # people in each frame written
    detection_fps: float = 0.0
    interrupted: bool = False
    truncated: str | None = None   # why the video looks truncated (VideoReader.truncation), else None
    warnings: list[str] = field(default_factory=list)   # the video's truncation and timestamps (the caller's to say)
    gaps: str | None = None        # the gaps in the video's timestamps (FrameClock.report), else None
    notes: list[str] = field(default_factory=list)   # what the frame watchers report (the camera's path)

    def report(self) -> str:
        counts = np.array(self.people, dtype=np.int64)
        mean, most = (counts.mean(), counts.max()) if counts.size else (0.0, 0)
        return "\n".join([
            f"frames read {self.frames_read}, frames written {counts.size}"
            + (" (interrupted)" if self.interrupted else "")
            + (" (the video ended before its declared frame count)" if self.truncated else ""),
            f"people per frame: mean {mean:.2f}, max {most}, frames with nobody {int(np.sum(counts == 0))}",
            f"detection {self.detection_fps:.1f} frames/s"]
            + ([f"frame times: {self.gaps}"] if self.gaps else []) + self.notes)


def detect_video(reader: VideoReader, model: FrameDetector, out_dir: Path, every: int = 1,
                 stop: threading.Event | None = None, watchers: Sequence[FrameWatcher] = ()) -> DetectSummary:
    """Detect people in every ``every``-th frame (by the paths ``model`` allows:
    :mod:`mocapdb.detect.tracked`) and write one OpenPose JSON file per frame
    (atomically) into ``out_dir``, then the take description (``take.json``: the keypoints' frame
    rate, the image size, the frames written, source and model; :mod:`mocapdb.core.formats.take`);
    each file holds its frame's number and time (:func:`openpose_json`). Ends with the video or once
    ``stop`` is set. ``out_dir`` is emptied of an earlier detect output first and refused
    (OutputFolderError) when it holds anything else (see the module docstring). The summary's
    ``truncated`` says when the video file ended before its declared frame count (every frame read is
    written), its ``warnings`` that and frames without a usable timestamp, its ``gaps`` the jumps in
    the timestamps; DetectError naming the path when the folder or a file cannot be written.
    ``watchers`` see every frame written and write their files at the end (their lines in the
    summary's ``notes``)."""
    try:
        clear_output_folder(out_dir, DETECT_FILES)
    except OSError as exc:
        raise DetectError(os_error_message(exc, out_dir, "create the output folder")) from None
    summary = DetectSummary()
    rate_hz = reader.fps / every if reader.fps else None
    clock = FrameClock(None if reader.is_camera else rate_hz)   # a camera's frames are numbered as they come
    total = -(-reader.frame_count // every) if reader.frame_count else None
    size = None
    with progress(total=total, desc=f"detect {reader.name}", unit="frame") as bar:
        for frame in reader.frames(every):
            size = size or (int(frame.image.shape[1]), int(frame.image.shape[0]))
            found = model(frame.image)
            number = clock.number(frame.time_s)
            for watcher in watchers:
                watcher.see(number, frame.image, found.keypoints)
            path = out_dir / frame_file_name(reader.name, frame.index)
            try:
                write_atomic(path, openpose_json(found.keypoints, model.keypoint_layout, found.world,
                                                 frame=number, time_s=frame.time_s, hands=found.hands,
                                                 faces=found.faces))
            except OSError as exc:
                raise DetectError(os_error_message(exc, path, "write the keypoints")) from None
            summary.people.append(len(found.scores))
            bar.update()
            if stop is not None and stop.is_set():
                summary.interrupted = True
                break
    summary.frames_read, summary.detection_fps = reader.frames_read, model.fps
    summary.truncated = None if summary.interrupted else reader.truncation()
    summary.warnings = [w for w in (summary.truncated, *reader.time_warnings()) if w]
    summary.gaps = clock.report()
    take = TakeInfo(fps=rate_hz, image_size=size, frames=len(summary.people),
                    source=reader.label, model=model.path.name, layout=written_layout(model.keypoint_layout))
    try:
        write_take(out_dir, take)
        summary.notes = [line for watcher in watchers for line in watcher.finish(out_dir)]
    except OSError as exc:
        raise DetectError(os_error_message(exc, out_dir, "write the take description and the camera path")) from None
    return summary
