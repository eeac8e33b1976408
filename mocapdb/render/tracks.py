"""The track files of a reconstruction, as ``mocapdb render`` draws them by default.

A ``mocapdb reconstruct`` folder holds per track its whole-take fit (``track_<id>.csv`` or
``.bvh``; ``track_<id>_part<k>`` for long tracks) and ``world.json`` (the floor, the camera's
height, every track's size: ``data_specs/world.md``). The files are in the view frame (x right,
y up, z towards the camera, the camera at the origin) or, with ``--floor``, on the floor: turned
by the smallest rotation ``L`` taking the floor's normal ``n`` (view frame) to +y, then shifted up
by the camera height ``h``, so ``p_floor = L p_view + (0, h, 0)`` (:func:`mocapdb.core.exports.on_floor`).

Here they are read (the CSV's joints, else the BVH's by forward kinematics), taken back to the
camera exactly (``p_view = Lᵀ (p_floor − (0, h, 0))``; z negated: the camera-aligned frame the
re-projection uses), and onto the floor for the 3D view. Which of the two frames the files are in
is not recorded, so it is read from the files themselves: the frame whose joints line up with the
stream's (the directions from the camera to each pelvis, frame by frame) is theirs.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import MIB, read_input_text
from mocapdb.core.geometry import quat_to_matrix
from mocapdb.core.outputs import CAMERA_FROM_VIEW
from mocapdb.core.skeleton import KEYPOINTS, N_POINTS, PELVIS, swing_matrices
from mocapdb.render.results import RenderError, ResultFrame, ResultStream, TrackPose

WORLD_FILE = "world.json"
WORLD_FORMAT = "mocapdb-world"
MAX_WORLD_BYTES = MIB                # world.json: the camera and a few lines per track
MAX_TRACK_FILE_BYTES = 1024 * MIB    # a track's CSV or BVH: an hour at 60 fps is ~130 MB of CSV
LINE_UP_DEG = 5.0    # the files' pelvis within this median angle of the stream's, seen from the camera
_TRACK_FILE = re.compile(r"track_(\d+)(?:_part(\d+))?\.(csv|bvh)$")
_Y = np.array([0.0, 1.0, 0.0])


@dataclass
class WorldFloor:
    """What ``world.json`` says: the floor (``normal_view``, unit, view frame; ``height_m`` the
    camera's height above it; both None when the take found no floor), the main track, each
    track's facts as written (stature_m, legs_m, kind, feet_above_floor_m, flags, ...) and the
    camera's record (height_given, pitch_deg, roll_deg, ...)."""
    normal_view: np.ndarray | None
    height_m: float | None
    main_track: int | None
    tracks: dict[int, dict]
    camera: dict | None = None
    files: str | None = None  # "floor" or "view": the frame its track files were written in (None: not said)
    camera_path: dict | None = None  # a turning camera's path (data_specs/world.md, "A camera that turns")

    @property
    def known(self) -> bool:
        return self.normal_view is not None and self.height_m is not None

    def level(self) -> np.ndarray:
        """``L [3, 3]``: the view frame turned so that the floor's normal is +y (exports.on_floor)."""
        if self.normal_view is None:
            raise ValueError("world.json found no floor: no floor frame to turn the view to")
        return swing_matrices(self.normal_view, _Y)

    def to_floor(self, view: np.ndarray) -> np.ndarray:
        """View-frame points ``[..., 3]`` (metres) in the floor frame: ``L p + (0, h, 0)``."""
        return np.asarray(view, dtype=np.float64) @ self.level().T + [0.0, self.height_m, 0.0]

    def to_view(self, floor: np.ndarray) -> np.ndarray:
        """Floor-frame points ``[..., 3]`` (metres) back in the view frame: ``Lᵀ (p − (0, h, 0))``."""
        return (np.asarray(floor, dtype=np.float64) - [0.0, self.height_m, 0.0]) @ self.level()


def read_world(folder: str | Path) -> WorldFloor | None:
    """The ``world.json`` of a reconstruction folder; None when there is none. RenderError naming
    the file when it is not one ``mocapdb reconstruct`` wrote."""
    path = Path(folder) / WORLD_FILE
    if not path.is_file():
        return None
    try:
        obj = json.loads(read_input_text(path, MAX_WORLD_BYTES, RenderError, "world file"))
        if not isinstance(obj, dict) or obj.get("format") != WORLD_FORMAT:
            raise ValueError(f"no \"format\": \"{WORLD_FORMAT}\"")
        camera = obj.get("camera") or {}
        normal, height = camera.get("floor_normal_view"), camera.get("height_m")
        normal = None if normal is None else np.array(normal, dtype=np.float64).reshape(3)
        if normal is not None and not (np.all(np.isfinite(normal)) and np.linalg.norm(normal) > 0.5):
            raise ValueError(f"floor_normal_view {normal.tolist()} is no direction")
        if height is not None and not (isinstance(height, (int, float)) and math.isfinite(height) and height > 0):
            raise ValueError(f"camera height_m {height!r} is not a positive number")
        tracks = {int(t["track"]): t for t in obj.get("tracks", [])}
        main = obj.get("main_track")
        files = obj.get("files")
        if files not in (None, "floor", "view"):
            raise ValueError(f"files {files!r} is neither \"floor\" nor \"view\"")
    except (json.JSONDecodeError, TypeError, KeyError, ValueError) as exc:
        raise RenderError(f"{path}: not a world file of `mocapdb reconstruct` ({exc})") from None
    return WorldFloor(None if normal is None else normal / np.linalg.norm(normal),
                      None if height is None else float(height), main if isinstance(main, int) else None, tracks,
                      camera, files, obj.get("camera_path"))


@dataclass
class TrackFile:
    """One track's file(s): input frame numbers ``[F]`` and joints ``[F, 15, 3]`` (metres, in the
    file's own frame: view or floor)."""
    track: int
    frames: np.ndarray
    joints: np.ndarray
    paths: list[Path]


def read_csv_joints(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Frame numbers ``[F]`` and joints ``[F, 15, 3]`` (metres) of a track CSV (``frame,time_s,
    <joint>_x,...``: exports.csv_text); RenderError naming the file when it is not one."""
    text = read_input_text(path, MAX_TRACK_FILE_BYTES, RenderError, "track CSV")
    lines = text.splitlines()
    columns = ["frame", "time_s"] + [f"{name}_{axis}" for name in KEYPOINTS for axis in "xyz"]
    header = lines[0].strip().split(",") if lines else []
    if header[:len(columns)] != columns:
        raise RenderError(f"{path}: not a track CSV of mocapdb (its header is not frame,time_s,head_x,...)")
    try:
        rows = np.loadtxt(lines[1:], delimiter=",", ndmin=2, dtype=np.float64)
    except ValueError as exc:
        raise RenderError(f"{path}: a row is not {len(columns)} numbers ({exc})") from None
    if rows.shape[0] == 0:
        raise RenderError(f"{path}: no frame")
    if rows.shape[1] != len(header):
        raise RenderError(f"{path}: rows of {rows.shape[1]} values, not {len(header)}")
    return rows[:, 0].astype(np.int64), rows[:, 2:len(columns)].reshape(-1, N_POINTS, 3)


def read_bvh_joints(path: Path) -> np.ndarray:
    """Joints ``[F, 15, 3]`` (metres, the file's axes) of a track BVH (universal or humanoid rig, m
    or cm) by forward kinematics; RenderError naming the file when it cannot be read."""
    from mocapdb.core.formats.bvh import Bvh, parse_bvh
    from mocapdb.core.joint_map import detect_mapping, extract_keypoints, leg_length

    try:
        bvh: Bvh = parse_bvh(read_input_text(path, MAX_TRACK_FILE_BYTES, RenderError, "BVH file"), str(path))
        mapping = detect_mapping(bvh)
        unit = "cm" if leg_length(bvh, mapping) > 5.0 else "m"   # legs: 0.3-1.2 m, 30-120 cm
        return extract_keypoints(bvh, mapping, unit, "y")
    except MocapdbError as exc:
        if isinstance(exc, RenderError):
            raise
        raise RenderError(f"{path}: not a track BVH of mocapdb ({exc})") from None


def track_file_names(folder: str | Path) -> dict[int, dict[int, dict[str, Path]]]:
    """Per track id, per part (0: a whole track), its files by suffix (csv, bvh)."""
    found: dict[int, dict[int, dict[str, Path]]] = {}
    for path in sorted(Path(folder).iterdir()):
        m = _TRACK_FILE.match(path.name)
        if m and path.is_file():
            found.setdefault(int(m[1]), {}).setdefault(int(m[2] or 0), {})[m[3]] = path
    return found


def _bvh_frames(counts: list[int], last: int) -> list[np.ndarray]:
    """Input frame numbers of a track's BVH parts of ``counts`` frames, the last ending at input
    frame ``last``: padded (``--bvh-start input``: the last part's frame k is input frame k) when
    its count says so, else the parts back to back."""
    if counts[-1] == last + 1:
        return [np.arange(n) for n in counts]
    frames, end = [], last
    for n in reversed(counts):
        frames.append(np.arange(end - n + 1, end + 1))
        end -= n
    return frames[::-1]


def _merge(frames: list[np.ndarray], joints: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Parts joined in order, a frame held by several taken from the first (a padded part's held
    leading frames repeat its predecessors')."""
    all_frames, all_joints = np.concatenate(frames), np.concatenate(joints)
    unique, first = np.unique(all_frames, return_index=True)
    return unique, all_joints[first]


def read_track_files(folder: str | Path, stream: ResultStream) -> list[TrackFile]:
    """Every track's files in ``folder``: its CSV where there is one (explicit frame numbers), else
    its BVH, whose frames are placed by the stream (the files end on the track's last frame in the
    stream); frames before the track's first in the stream, less one (a padded BVH's held pose),
    are left out. Tracks the stream does not hold are left out."""
    seen: dict[int, tuple[int, int]] = {}  # track: its first and last frame in the stream
    for frame in stream.frames:
        for p in frame.people:
            lo, hi = seen.get(p.track, (frame.index, frame.index))
            seen[p.track] = (min(lo, frame.index), max(hi, frame.index))
    out = []
    for track, parts in track_file_names(folder).items():
        if track not in seen:
            continue
        order = sorted(parts)
        if all("csv" in parts[k] for k in order):
            paths = [parts[k]["csv"] for k in order]
            frames, joints = zip(*(read_csv_joints(p) for p in paths))
        elif all("bvh" in parts[k] for k in order):
            paths = [parts[k]["bvh"] for k in order]
            joints = [read_bvh_joints(p) for p in paths]
            frames = _bvh_frames([len(j) for j in joints], seen[track][1])
        else:
            continue
        frames, joints = _merge(list(frames), list(joints))
        keep = frames >= seen[track][0] - 1
        if np.any(keep):
            out.append(TrackFile(track, frames[keep], joints[keep], paths))
    return sorted(out, key=lambda t: t.track)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (degrees) between the rows of ``a`` and ``b`` ``[N, 3]``, as seen from the origin."""
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    cos = np.sum(a * b, axis=1) / np.maximum(na * nb, 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def stream_pelvis(stream: ResultStream) -> dict[tuple[int, int], np.ndarray]:
    """(frame, track) → the stream's pelvis, view frame (metres)."""
    return {(f.index, p.track): p.joints[PELVIS] * CAMERA_FROM_VIEW for f in stream.frames for p in f.people}


def misalignment_deg(files: list[TrackFile], to_view, pelvis: dict[tuple[int, int], np.ndarray]) -> float:
    """The median angle (degrees) between each file pelvis, taken to the view frame by ``to_view``,
    and the stream's in the same frame, seen from the camera: the image distance between the two
    (nan when they share no frame)."""
    ours, theirs = [], []
    for t in files:
        for frame, joints in zip(t.frames.tolist(), t.joints):
            if (frame, t.track) in pelvis:
                ours.append(joints[PELVIS])
                theirs.append(pelvis[(frame, t.track)])
    if not ours:
        return math.nan
    angles = _angle_deg(to_view(np.array(ours)), np.array(theirs))
    return float(np.nanmedian(angles)) if np.any(np.isfinite(angles)) else math.nan


def files_frame(files: list[TrackFile], world: WorldFloor | None, stream: ResultStream) -> tuple[str | None, str]:
    """Which frame the track files are in, "floor" (``--floor``, on the world's floor) or "view": as
    ``world.json`` says (its ``files``), else read from how they line up with the stream
    (:func:`misalignment_deg`); None and the reason when neither lines up within :data:`LINE_UP_DEG`."""
    pelvis = stream_pelvis(stream)
    options = {"view": lambda p: p}
    if world is not None and world.known:
        options["floor"] = world.to_view
    if world is not None and world.files in options:
        options = {world.files: options[world.files]}
    errors = {name: misalignment_deg(files, f, pelvis) for name, f in options.items()}
    best = min(errors, key=lambda k: errors[k] if math.isfinite(errors[k]) else math.inf)
    if not math.isfinite(errors[best]):
        return None, "the track files share no frame with the stream"
    if errors[best] > LINE_UP_DEG:
        floor = "" if "floor" in options else " (world.json has no floor to take them back to the camera)"
        return None, (f"the track files do not line up with the stream{floor}: their pelvis is "
                      f"{errors[best]:.1f} deg off, seen from the camera")
    return best, ""


@dataclass
class SceneTrack:
    """One track as drawn: input frame numbers ``[F]``, joints ``[F, 15, 3]`` camera-aligned (for
    the re-projection) and in the 3D view's scene (on the floor: x right, y up from it, z away
    from the camera; without a floor the camera-aligned joints), its short label and its legend
    line (sizes, where it stands, flags)."""
    track: int
    frames: np.ndarray
    camera: np.ndarray
    scene: np.ndarray
    label: str
    legend: str


@dataclass
class FileScene:
    """What ``render`` draws of a reconstruction's track files: the tracks, whether the 3D view is
    on the world's floor (scene y = 0), the camera there (``camera_scene``: its centre; rows of
    ``camera_axes``: its right, down and forward, scene coordinates), the files' own frame."""
    tracks: list[SceneTrack]
    world: WorldFloor | None
    files_frame: str
    on_floor: bool
    camera_scene: np.ndarray | None = None
    camera_axes: np.ndarray | None = None
    by_frame: dict[int, list[tuple[SceneTrack, int]]] | None = None   # filled by people_at

    @property
    def main_track(self) -> int | None:
        return None if self.world is None else self.world.main_track

    def describe(self) -> str:
        """What is drawn, for titles and summaries."""
        where = "on their floor" if self.on_floor else "camera at the origin (no floor found)"
        frame = "" if self.files_frame == "floor" else ", shown on the floor of world.json" if self.on_floor else ""
        return f"the track files ({where}{frame})"


def where_text(facts: dict) -> str:
    """Where a track stands, from its ``world.json`` facts: "on the floor", "1.9 m above the floor
    (on something)", ..."""
    feet, kind = facts.get("feet_above_floor_m"), facts.get("kind")
    if not isinstance(kind, str):
        return ""
    above = f"{feet:.1f} m above the floor" if isinstance(feet, (int, float)) else "above the floor"
    return {"floor": "on the floor", "elevated": f"{above} (on something)",
            "unreliable": f"feet do not fit the floor ({above})" if isinstance(feet, (int, float)) and feet > 0.1
            else "feet do not fit the floor", "no contacts": "no planted foot"}.get(kind, "")


def track_texts(track: int, facts: dict | None, main: bool) -> tuple[str, str]:
    """A track's short label (``#1 main 1.71 m``) and its legend line (``#1 main: 1.71 m ±13 %
    (floor), legs 0.80 m, on the floor``, world flags appended) from its ``world.json`` facts."""
    name = f"#{track}" + (" main" if main else "")
    if not facts or not isinstance(facts.get("stature_m"), (int, float)):
        return name, name
    stature = f"{facts['stature_m']:.2f} m"
    sd = facts.get("stature_log_sd")
    spread = f" ±{100 * (math.exp(sd) - 1):.0f} %" if isinstance(sd, (int, float)) else ""
    source = f" ({facts['size_from']})" if facts.get("size_from") else ""
    legs = f", legs {facts['legs_m']:.2f} m" if isinstance(facts.get("legs_m"), (int, float)) else ""
    where = where_text(facts)
    flags = list(facts.get("flags") or [])
    legend = f"{name}: {stature}{spread}{source}{legs}" + (f", {where}" if where else "") \
        + "".join(f"; {f}" for f in flags)
    return f"{name} {stature}" + (" FLAGGED" if flags else ""), legend


def file_scene(folder: str | Path, stream: ResultStream) -> tuple[FileScene | None, str]:
    """The track files of a reconstruction folder ready to draw, or None and why they cannot be
    (no track files, no ``world.json``, files that do not line up with the stream)."""
    world = read_world(folder)
    if world is None:
        return None, f"{Path(folder)} has no {WORLD_FILE} (--per-frame runs and older versions write none)"
    files = read_track_files(folder, stream)
    if not files:
        return None, f"{Path(folder)} has no track files of the stream's tracks"
    frame, why = files_frame(files, world, stream)
    if frame is None:
        return None, why
    tracks = []
    for t in files:
        view = world.to_view(t.joints) if frame == "floor" else t.joints
        if frame == "floor":
            scene = t.joints * CAMERA_FROM_VIEW   # exactly the file's values
        else:
            scene = (world.to_floor(view) if world.known else view) * CAMERA_FROM_VIEW
        label, legend = track_texts(t.track, world.tracks.get(t.track), t.track == world.main_track)
        filmed = as_filmed(world, t.frames, view * CAMERA_FROM_VIEW)
        tracks.append(SceneTrack(t.track, t.frames, filmed, scene, label, legend))
    if not world.known:
        return FileScene(tracks, world, frame, False), ""
    axes = (np.eye(3) * [1.0, -1.0, -1.0]) @ world.level().T * CAMERA_FROM_VIEW  # view right, down, forward
    return FileScene(tracks, world, frame, True, np.array([0.0, world.height_m, 0.0]), axes), ""


def turning_path(world: WorldFloor) -> dict | None:
    """``world.json``'s ``camera_path`` of a camera that turned, its files on the floor; else None."""
    path = world.camera_path
    if not world.known or not path or path.get("still") or "view_to_files_wxyz" not in path:
        return None
    return path


def as_filmed(world: WorldFloor, frames: np.ndarray, camera_aligned: np.ndarray) -> np.ndarray:
    """Camera-aligned points ``[F, J, 3]`` of the take's reference camera as each input frame's camera
    filmed them (a turning camera's path: the re-projection onto the frames as filmed; a frame the
    path does not hold takes the last one before it); as they are for a still camera."""
    path = turning_path(world)
    if path is None:
        return camera_aligned
    to_files = quat_to_matrix(np.array(path["view_to_files_wxyz"], dtype=np.float64))
    to_reference = np.einsum("ji,njk->nik", to_files[0], to_files)        # frame t's view frame → the reference's
    at = np.clip(np.searchsorted(np.array(path["frames"]), frames, side="right") - 1, 0, len(to_files) - 1)
    flip = np.diag(CAMERA_FROM_VIEW)
    turns = flip @ np.transpose(to_reference[at], (0, 2, 1)) @ flip       # camera-aligned, reference → frame t
    return np.einsum("fij,fkj->fki", turns, camera_aligned)


def people_at(scene: FileScene, frame: ResultFrame) -> tuple[list[TrackPose], list[TrackPose]]:
    """The track files' people in a result frame: camera-aligned (for the re-projection, with the
    stream's match distance of that frame) and in the 3D view's scene, each labelled."""
    if scene.by_frame is None:
        scene.by_frame = {}
        for t in scene.tracks:
            for row, index in enumerate(t.frames.tolist()):
                scene.by_frame.setdefault(index, []).append((t, row))
    distances = {p.track: p.distance_2d for p in frame.people}
    drawn = scene.by_frame.get(frame.index, [])
    return ([TrackPose(t.track, t.camera[row], None, distances.get(t.track), t.label) for t, row in drawn],
            [TrackPose(t.track, t.scene[row], None, None, t.label) for t, row in drawn])
