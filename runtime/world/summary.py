"""What the summary and ``world.json`` say of a take's world and of each track placed in it.

:func:`track_facts` reads a track placed in the world (:func:`~mocapdb.runtime.world.fuse.place_in_world`):
its stature, legs, distance and the world's verdict on its size, with the flags of anything a person
cannot be; :func:`world_line` and :meth:`TrackFacts.line` are the summary's lines,
:func:`world_record` is ``world.json`` (data_specs/world.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapdb.core.outputs import TrackRecording
from mocapdb.core.skeleton import MEASURED_BONE_NAMES, swing_matrices
from mocapdb.runtime.world.fuse import PersonSize, World
from mocapdb.runtime.world.stature import HUMAN_STATURE_M


@dataclass(frozen=True)
class TrackFacts:
    """What the summary says of one written track: its stature and leg length (metres), how far
    from the camera its root is (metres, min and max), whether it stays in front of the camera, and
    the world's verdict on its size (:class:`PersonSize`)."""

    track: int
    stature_m: float
    legs_m: float
    distance_m: tuple[float, float]
    in_front: bool
    size: PersonSize

    @property
    def flags(self) -> list[str]:
        """Anything a person cannot be: a size outside the human range, a body at or behind the
        camera, feet below the floor or standing high above it."""
        flags = []
        if not HUMAN_STATURE_M[0] <= round(self.stature_m, 3) <= HUMAN_STATURE_M[1] \
                or self.size.stature_m in HUMAN_STATURE_M:
            flags.append(f"SIZE AT OR OUTSIDE THE HUMAN RANGE {HUMAN_STATURE_M[0]}-{HUMAN_STATURE_M[1]} m")
        if not self.in_front:
            flags.append("AT OR BEHIND THE CAMERA")
        feet = self.size.feet_above_floor_m
        if feet is not None and feet < -FEET_TOLERANCE_M:
            flags.append(f"FEET {-feet:.2f} m BELOW THE FLOOR")
        return flags

    def line(self, main: bool = False, written: bool = True, why_no_files: str = "--people") -> str:
        """One summary line: ``track 3: 1.62 m (±4 %, floor), legs 0.78 m, 4.1-6.3 m away, on the floor``
        (``track 3 (main)`` for the take's subject; "no files" and ``why_no_files`` where not ``written``:
        ``--people`` left it out, or it was static)."""
        size = self.size
        where = {"floor": "on the floor", "no contacts": "no planted foot (size from the prior)",
                 "unreliable": "its feet do not fit the floor (size from the prior)"}.get(size.kind)
        if size.kind == "elevated" or (where is None and size.feet_above_floor_m is not None):
            where = f"standing {size.feet_above_floor_m:.2f} m above the floor (on something; size from the prior)"
        source = {"floor": "from the floor", "prior": "the stature prior's: the take cannot fix it",
                  "given": "given"}[size.source]
        label = f"track {self.track}" + (" (main)" if main else "") \
            + ("" if written else f" (no files: {why_no_files})")
        text = (f"{label}: {self.stature_m:.2f} m (±{100 * (np.exp(size.stature_log_sd) - 1):.0f} %, "
                f"{source}), legs {self.legs_m:.2f} m, {self.distance_m[0]:.1f}-{self.distance_m[1]:.1f} m away, "
                f"{where or size.kind}")
        return text + "".join(f"; {flag}" for flag in self.flags)


FEET_TOLERANCE_M = 0.05  # feet this far below the floor are flagged
_LEGS = [MEASURED_BONE_NAMES.index("thigh"), MEASURED_BONE_NAMES.index("shank")]


def track_facts(rec: TrackRecording, world: World, fps: float) -> TrackFacts:
    """:class:`TrackFacts` of a track placed in ``world`` (:func:`place_in_world`), at ``fps`` Hz."""
    motion = rec.motion(fps)
    roots = motion.root_m
    distances = np.linalg.norm(roots, axis=1)
    return TrackFacts(rec.track, motion.height_m, float(motion.bones_m()[_LEGS].sum()),
                      (float(distances.min()), float(distances.max())), bool(np.all(roots[:, 2] < 0.0)),
                      world.people[rec.track])


UNFIXED_HEIGHT_PCT = 50.0  # a camera height estimated more loosely than this is said not to be fixed


def world_line(world: World) -> str:
    """The summary's line on the world: the camera's height (given, or estimated with its error),
    pitch and roll, and what decided the tilt (the people, the scene's lines or both)."""
    pitch = f"{abs(world.pitch_deg):.1f} deg {'down' if world.pitch_deg >= 0 else 'up'}"
    tilt = (f"pitched {pitch}{_sd_text(world.pitch_sd_deg)}, roll {world.roll_deg:.1f} deg"
            f"{_sd_text(world.roll_sd_deg)}{TILT_FROM_TEXT[world.tilt_from]}")
    if not world.floor_known:
        return ("world: no floor found (no planted foot, no --camera-height): each track's size is the prior's; "
                f"camera {tilt}{'' if world.tilt_from == 'scene' else ', from the people alone: no floor checks it'}")
    error = 100 * (np.exp(world.camera_height_log_sd) - 1)
    height = "given" if world.camera_height_given else (
        f"±{error:.0f} %, from the people's sizes" if error <= UNFIXED_HEIGHT_PCT
        else f"±{error:.0f} %: not fixed by this take, the people's assumed sizes; --camera-height fixes it")
    return f"world: camera {world.camera_height_m:.2f} m above the floor ({height}), {tilt}"


TILT_FROM_TEXT = {"people": "", "scene": ", from the scene's lines",
                  "people and scene": ", from the people and the scene's lines"}


def _sd_text(sd_deg: float) -> str:
    """`` (±x deg)``, or nothing where the error is unknown."""
    return f" (±{sd_deg:.1f} deg)" if np.isfinite(sd_deg) else ""


def world_record(world: World, facts: list[TrackFacts], main: int | None, written: set[int],
                 joined: dict[int, int] | None = None, files_on_floor: bool = False) -> dict:
    """``world.json`` (data_specs/world.md): the take's world, its subject and every track's size,
    floor contact and flags, whether it got files, the tracks joined into others, and whether the
    files are on the floor (``--floor``) or in the view frame."""
    camera = {"height_m": _finite(world.camera_height_m), "height_given": world.camera_height_given,
              "height_log_sd": _finite(world.camera_height_log_sd), "pitch_deg": round(world.pitch_deg, 2),
              "roll_deg": round(world.roll_deg, 2), "pitch_sd_deg": _finite(world.pitch_sd_deg, 2),
              "roll_sd_deg": _finite(world.roll_sd_deg, 2), "tilt_from": world.tilt_from,
              "scene_share": _finite(world.scene_share, 2), "scene": _scene_record(world),
              "floor_normal_view": [round(float(v), 5) for v in world.normal]}
    tracks = [{"track": f.track, "main": f.track == main, "written": f.track in written,
               "stature_m": round(f.stature_m, 3), "stature_log_sd": _finite(f.size.stature_log_sd),
               "size_from": f.size.source, "kind": f.size.kind, "legs_m": round(f.legs_m, 3),
               "distance_m": [round(d, 2) for d in f.distance_m], "in_front": f.in_front,
               "feet_above_floor_m": _finite(f.size.feet_above_floor_m), "flags": f.flags} for f in facts]
    if files_on_floor and world.floor_known:
        camera |= files_camera_pose(world)
    return {"format": "mocapdb-world", "version": 1, "camera": camera, "main_track": main, "tracks": tracks,
            "joined": {str(track): into for track, into in (joined or {}).items()},
            "files": "floor" if files_on_floor else "view"}


def _scene_record(world: World) -> dict | None:
    """The up the room's lines alone showed (its pitch, roll and their errors, degrees; its vertical's
    segments a frame), or None where they showed none."""
    tilt = world.scene
    if tilt is None:
        return None
    return {"pitch_deg": round(tilt.pitch_deg, 2), "roll_deg": round(tilt.roll_deg, 2),
            "pitch_sd_deg": round(tilt.pitch_sd_deg, 2), "roll_sd_deg": round(tilt.roll_sd_deg, 2),
            "vertical_segments_per_frame": round(tilt.segments_per_frame, 1)}


def files_camera_pose(world: World) -> dict:
    """Where the camera is in the track files on the floor (:func:`~mocapdb.core.motion_ops.on_floor`,
    y up, the origin on the floor under the camera): ``position_m`` and ``view_to_files`` (the
    rotation taking view-frame vectors, x right, y up, z towards the camera, to the files' frame)."""
    level = swing_matrices(world.normal / np.linalg.norm(world.normal), np.array([0.0, 1.0, 0.0]))
    return {"position_m": [0.0, round(float(world.camera_height_m), 4), 0.0],
            "view_to_files": np.round(level, 6).tolist()}


def _finite(value: float | None, decimals: int = 3) -> float | None:
    """``value`` rounded, or None when unknown (None, NaN, infinite)."""
    return None if value is None or not np.isfinite(value) else round(float(value), decimals)
