"""Reading what the engine wrote, for pictures: the result stream, a stereo run's cameras, the 2D input.

The stream's schema is ``data_specs/stream_output.md`` (header line, then one line per frame);
``cameras.json`` is written by ``mocapdb stereo`` (both cameras; camera 1's OpenCV frame).
Every problem a user can cause raises :class:`RenderError` naming the file and what to change.
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import MIB, open_input, read_input_text
from mocapdb.core.formats.take import TakeInfo
from mocapdb.core.hand_rig import FINGER_JOINTS
from mocapdb.core.outputs import STREAM_FORMAT, STREAM_VERSION
from mocapdb.core.skeleton import END_JOINTS, KEYPOINTS, N_POINTS, N_RIG_JOINTS

RESULT_FILE = "result.jsonl"
CAMERAS_FILE = "cameras.json"
MAX_RESULT_BYTES = 512 * MIB  # a result stream: an hour at 60 fps of two people takes ~400 MiB
MAX_CAMERAS_BYTES = MIB       # cameras.json: two cameras and the tracks' summaries
MAX_POSITION_M = 10_000.0  # a joint or camera farther from camera 1 is no position a run gives: refused
# every version up to the writer's: the fields drawn here (fps, joints, frames) have not changed
STREAM_VERSIONS = tuple(range(1, STREAM_VERSION + 1))


class RenderError(MocapdbError, ValueError):
    """An input of ``mocapdb render`` that cannot be drawn; the message names the file and the problem."""


@dataclass
class TrackPose:
    """One person of one result frame: joints ``[15, 3]`` metres, camera-aligned frame (NaN: unknown)."""
    track: int
    joints: np.ndarray
    height: float | None = None
    distance_2d: float | None = None   # the match's Eq. 1 distance (None for stereo results)
    label: str | None = None           # drawn instead of "#<track>" (the track files': id, main, stature)
    # [5, 4] the feet's, hands' and head's local rotations (the stream's end_quaternions; None: not in it)
    end_quaternions: np.ndarray | None = None
    # [30, 4] the finger joints' local rotations (the stream's finger_quaternions [2, 15, 4]; None: not in it)
    finger_quaternions: np.ndarray | None = None
    quaternions: np.ndarray | None = None   # [11, 4] the rig's local rotations, view frame (None: not in it)


@dataclass
class ResultFrame:
    index: int
    time_s: float
    people: list[TrackPose]


@dataclass
class ResultStream:
    """A ``result.jsonl``: its header and frames (in file order)."""
    path: Path
    header: dict
    frames: list[ResultFrame]

    @property
    def fps(self) -> float:
        fps = self.header.get("fps")
        return float(fps) if isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0 else 30.0

    @property
    def tracks(self) -> list[int]:
        return sorted({p.track for f in self.frames for p in f.people})

    def all_joints(self) -> np.ndarray:
        """Every person-frame's joints stacked ``[N, 15, 3]`` (``[0, 15, 3]`` when nobody)."""
        poses = [p.joints for f in self.frames for p in f.people]
        return np.stack(poses) if poses else np.zeros((0, N_POINTS, 3))


@dataclass
class StereoCameras:
    cameras: list[CameraModel]  # x_cam = R x_cam1 + t: camera 1's OpenCV frame (metres)
    bvh_from_camera1: np.ndarray | None   # [3, 3] camera-1 OpenCV axes → y-up world (BVH) axes
    baseline_m: float | None = None
    rotation_deg: float | None = None
    extra: dict = field(default_factory=dict)


def result_path(result: str | Path) -> Path:
    """The ``result.jsonl`` of a result folder (or the file itself); RenderError when missing."""
    path = Path(result)
    if path.is_dir():
        path = path / RESULT_FILE
        if not path.is_file():
            raise RenderError(f"{result}: no {RESULT_FILE} in this folder (give the --out folder of "
                              "`mocapdb reconstruct` or `mocapdb stereo`)")
    elif not path.exists():
        raise RenderError(f"{result}: no such result folder or file")
    return path


def recorded_camera(result: str | Path) -> TakeInfo | None:
    """The camera a result's run recorded in its header (image size, focal length, fps), as a take
    description; None for a stream that records none (older runs, stereo)."""
    path = result_path(result)
    try:
        with open_input(path, MAX_RESULT_BYTES, RenderError, "result stream") as fh:
            header = json.loads(fh.readline(1_000_000).decode("utf-8"))
    except (RenderError, OSError, UnicodeDecodeError, ValueError, RecursionError):
        return None  # read_result names the problem when the result is drawn
    if not isinstance(header, dict) or "focal_px" not in header:
        return None
    size = header.get("image_size")
    try:
        return TakeInfo(fps=header.get("fps"), image_size=tuple(size) if isinstance(size, list) else None,
                        frames=None, source=str(path), focal_px=header.get("focal_px"))
    except ValueError as exc:
        raise RenderError(f"{path}: the header's camera: {exc}") from None


def _bad(path: Path, line_no: int, why: str) -> RenderError:
    return RenderError(f"{path}, line {line_no}: {why}")


def read_result(result: str | Path) -> ResultStream:
    """The stream of a result folder (``result.jsonl`` inside) or file; RenderError naming the file
    and line when it is no mocapdb stream (header), a frame line is malformed or a joint lies beyond
    :data:`MAX_POSITION_M` (refused rather than drawn: nothing a camera films is that far)."""
    path = result_path(result)
    lines = read_input_text(path, MAX_RESULT_BYTES, RenderError, "mocapdb result stream").splitlines()
    if not lines or not lines[0].strip():
        raise RenderError(f"{path}: empty, no mocapdb stream header (did the run fail?)")
    try:
        header = json.loads(lines[0])
    except json.JSONDecodeError:
        header = None
    if not isinstance(header, dict) or header.get("format") != STREAM_FORMAT:
        raise RenderError(f"{path}: the first line is not a mocapdb stream header "
                          f"({{\"format\": \"{STREAM_FORMAT}\", ...}}); is this a result.jsonl of mocapdb?")
    if header.get("version") not in STREAM_VERSIONS:
        raise RenderError(f"{path}: stream version {header.get('version')!r}; this mocapdb reads version(s) "
                          f"{', '.join(map(str, STREAM_VERSIONS))}")
    joints = header.get("joints")
    if joints is not None and list(joints) != list(KEYPOINTS):
        raise RenderError(f"{path}: the header's joints {joints} are not the universal skeleton's {list(KEYPOINTS)}")
    frames = [_frame(path, i + 2, line) for i, line in enumerate(lines[1:]) if line.strip()]
    return ResultStream(path, header, frames)


def _frame(path: Path, line_no: int, line: str) -> ResultFrame:
    try:
        obj = json.loads(line)
    except json.JSONDecodeError as exc:
        raise _bad(path, line_no, f"not JSON ({exc.msg}); the file is cut or not a result stream") from None
    if not isinstance(obj, dict) or not isinstance(obj.get("frame"), int) or not isinstance(obj.get("people"), list):
        raise _bad(path, line_no, "a frame line needs an integer \"frame\" and a \"people\" list")
    time_s = obj.get("time")
    people = []
    for k, p in enumerate(obj["people"]):
        try:
            joints = np.array(p["joints"], dtype=np.float64)
            track = int(p["track"])
        except (KeyError, TypeError, ValueError):
            raise _bad(path, line_no, f"person {k} needs \"track\" and \"joints\" [15, 3] numbers") from None
        if joints.shape != (N_POINTS, 3):
            raise _bad(path, line_no, f"person {k} (track {track}) has joints of shape {list(joints.shape)}, "
                                      f"not [{N_POINTS}, 3]")
        if np.nanmax(np.abs(joints), initial=0.0) > MAX_POSITION_M:
            raise _bad(path, line_no, f"person {k} (track {track}) has a joint {np.nanmax(np.abs(joints)):.3g} m "
                                      f"from the camera, beyond {MAX_POSITION_M:,.0f} m: not a position to draw")
        match = p.get("match")
        dist = match.get("distance_2d") if isinstance(match, dict) else None
        height = p.get("height")
        people.append(TrackPose(track, joints, float(height) if isinstance(height, (int, float)) else None,
                                float(dist) if isinstance(dist, (int, float)) else None,
                                end_quaternions=_rotations(path, line_no, k, p, "end_quaternions", len(END_JOINTS)),
                                quaternions=_rotations(path, line_no, k, p, "quaternions", N_RIG_JOINTS),
                                finger_quaternions=_finger_rotations(path, line_no, k, p)))
    return ResultFrame(obj["frame"], float(time_s) if isinstance(time_s, (int, float)) else math.nan, people)


def _rotations(path: Path, line_no: int, k: int, person: dict, name: str, rows: int) -> np.ndarray | None:
    """Person ``k``'s quaternions ``name`` ``[rows, 4]`` (None when the line has none); RenderError when malformed."""
    value = person.get(name)
    if value is None:
        return None
    try:
        quats = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        quats = np.zeros(0)
    if quats.shape != (rows, 4) or not np.isfinite(quats).all():
        raise _bad(path, line_no, f"person {k} has {name} that are not [{rows}, 4] numbers")
    return quats


def _finger_rotations(path: Path, line_no: int, k: int, person: dict) -> np.ndarray | None:
    """Person ``k``'s ``finger_quaternions`` ``[2, 15, 4]`` as ``[30, 4]`` (None when the line has none);
    RenderError when malformed."""
    value = person.get("finger_quaternions")
    if isinstance(value, list) and len(value) == 2 and all(isinstance(hand, list) for hand in value):
        value = value[0] + value[1]
    return _rotations(path, line_no, k, {"finger_quaternions": value}, "finger_quaternions", len(FINGER_JOINTS))


def read_cameras(folder: str | Path) -> StereoCameras | None:
    """The cameras of a ``mocapdb stereo`` output folder, or None when it has no ``cameras.json``."""
    path = Path(folder) / CAMERAS_FILE
    if not Path(folder).is_dir() or not path.is_file():
        return None
    try:
        obj = json.loads(read_input_text(path, MAX_CAMERAS_BYTES, RenderError, "stereo cameras file"))
        cams: list[CameraModel] = []
        for c in obj["cameras"]:
            K = np.array(c["K"], dtype=np.float64)
            R = np.array(c["R"], dtype=np.float64)
            t = np.array(c["t"], dtype=np.float64).reshape(3)
            if K.shape != (3, 3) or R.shape != (3, 3) or not (np.all(np.isfinite(K)) and np.all(np.isfinite(R))
                                                             and np.all(np.isfinite(t))):
                raise ValueError("K, R must be 3×3 and t 3 finite numbers")
            if (far := float(np.linalg.norm(R.T @ t))) > MAX_POSITION_M:
                raise ValueError(f"camera {len(cams) + 1} is {far:.3g} m from camera 1, beyond {MAX_POSITION_M:,.0f} m")
            size = (int(c["size"][0]), int(c["size"][1]))
            cams.append(CameraModel(K, np.zeros(5), R, t, size, str(c.get("name") or f"camera {len(cams) + 1}")))
        if not cams:
            raise ValueError("no camera")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, ValueError, IndexError) as exc:
        raise RenderError(f"{path}: not a camera file of `mocapdb stereo` ({exc})") from None
    bvh = obj.get("bvh_from_camera1")
    try:
        bvh = np.array(bvh, dtype=np.float64) if bvh is not None else None
        if bvh is not None and (bvh.shape != (3, 3) or not np.all(np.isfinite(bvh))):
            bvh = None
    except (TypeError, ValueError):
        bvh = None
    num = (lambda v: float(v) if isinstance(v, (int, float)) else None)  # noqa: E731
    return StereoCameras(cams, bvh, num(obj.get("baseline_m")), num(obj.get("rotation_deg")),
                         {k: v for k, v in obj.items() if k not in ("cameras", "bvh_from_camera1")})


def load_keypoints(source: str | Path, layout: str | None = None) -> list:
    """The 2D input frames (:class:`~mocapdb.core.formats.keypoints.KeypointFrame`) of a folder of
    OpenPose JSON, a JSON-lines file, an MMPose ``.json`` or a ``.npy``/``.npz`` array, numbered as
    ``mocapdb reconstruct`` numbers them (folder: position; JSON lines: their ``frame``, else counted)."""
    from mocapdb.core.formats.keypoint_arrays import KEYPOINT_FILE_SUFFIXES, read_keypoint_file
    from mocapdb.core.formats.openpose import parse_stream_line, read_openpose_folder

    path = Path(source)
    if path.is_dir():
        return list(read_openpose_folder(path, layout))
    if not path.is_file():
        raise RenderError(f"{source}: no such keypoint folder or file (--keypoints)")
    if path.suffix.lower() in KEYPOINT_FILE_SUFFIXES:
        return list(read_keypoint_file(path, layout))
    frames, next_index = [], 0
    with open(path, encoding="utf-8") as f:
        for line_no, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                frame = parse_stream_line(line, layout)
            except MocapdbError as exc:
                raise RenderError(f"{path}, line {line_no}: {exc}") from None
            if frame.index < 0:
                frame.index = next_index
            next_index = frame.index + 1
            frames.append(frame)
    return frames


def _span(indices: list[int]) -> str:
    return f"{len(indices)} frame(s) ({indices[0]}–{indices[-1]})" if indices else "no frame"


def overlap(result: ResultStream, keypoints: list | None, video_frames: int | None,
            warn: Callable[[str], None]) -> list[tuple[ResultFrame, object]]:
    """The result frames to draw with their keypoint frame (or None): those whose index the keypoints
    (and the video, when its frame count is known) also have; ``warn`` says what is left out.
    RenderError when nothing is left."""
    frames = result.frames
    if keypoints is not None:
        by_index = {k.index: k for k in keypoints}
        both = [f for f in frames if f.index in by_index]
        if len(both) != len(frames) or len(by_index) != len(frames):
            warn(f"the result has {_span([f.index for f in frames])}, the keypoints {_span(sorted(by_index))}: "
                 f"drawing the {len(both)} frame(s) in both")
        if not both:
            raise RenderError(f"{result.path} and the keypoints share no frame number: are they from the same input?")
        pairs = [(f, by_index[f.index]) for f in both]
    else:
        pairs = [(f, None) for f in frames]
    if video_frames is not None and video_frames > 0:
        inside = [p for p in pairs if p[0].index < video_frames]
        if len(inside) != len(pairs):
            warn(f"the video has {video_frames} frame(s), the result goes to frame {pairs[-1][0].index}: "
                 f"drawing the {len(inside)} frame(s) the video has")
        if not inside:
            raise RenderError("the video has none of the result's frames")
        pairs = inside
    if not pairs:
        raise RenderError(f"{result.path}: no frame to draw (the stream holds only its header)")
    return pairs
