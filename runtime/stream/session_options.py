"""What a session does beyond the engine (:class:`SessionOptions`): strictness, track files and
their limits, checkpoints, the whole-take fit, the shared floor, the stream's lag, the people
given files; each number checked against its domain (:mod:`mocapdb.core.domains`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mocapdb.core import domains as D
from mocapdb.core.exports import TrackExport
from mocapdb.core.formats.camera_path import CameraPath
from mocapdb.runtime.take_params import TakeParams
from mocapdb.runtime.world.scene_lines import SceneEvidence


@dataclass
class SessionOptions:
    """What a session does beyond the engine: ``strict`` stops at input that contradicts the
    parameters (reconstruct) instead of skipping and counting it (live); ``fps_given`` says
    whether ``--fps`` was given (else frames without time warn once). With ``bvh_dir`` each
    track's files (``export``: BVH, TRC, CSV; :mod:`mocapdb.core.exports`) are written
    (atomically) when the track ends, and every ``checkpoint_s`` seconds the open tracks' files so
    far, so a killed process loses at most that much of them.

    Limits (0: none): at most ``max_bvh_files`` files; a track shorter than ``min_track_s`` gets
    none; a track longer than ``bvh_part_min`` minutes is written in parts of that length.
    ``rate_by_arrival``: the engine's new-track limit counts by arrival time (live: the sender
    chooses the frames' times), not by the frames' time (reconstruct: the same result every run).
    """

    strict: bool = True
    fps_given: bool = True
    keep_static: bool = False
    bvh_dir: Path | None = None
    export: TrackExport = field(default_factory=TrackExport)
    checkpoint_s: float = 30.0
    max_bvh_files: int = D.MAX_BVH_FILES.default
    min_track_s: float = D.MIN_TRACK_S.default
    bvh_part_min: float = D.BVH_PART_MIN.default
    rate_by_arrival: bool = False
    take: TakeParams | None = None  # track files from the whole-take fit (runtime.take); None: per frame
    shared_floor: bool = False      # files written at the end, every track on one floor (runtime.world.fuse)
    lag_frames: int = 0             # stream lines written this many frames late (runtime.online_take)
    online_take: bool = True        # the stream through the online whole take; False: as the engine gives it
    camera_sources: dict[str, str] = field(default_factory=dict)  # where fps, image size, focal came from
    camera_height_m: float | None = None  # the shared floor's distance below the camera, when known
    scene: SceneEvidence | None = None  # the room's vanishing points (runtime.world.scene_lines), if any
    subject_heights_m: dict[int | None, float] = field(default_factory=dict)  # track (None: all) → stature
    people: str | tuple[int, ...] = "all"  # the tracks given files at the end: "all", "main" or ids (world.subject)
    write_in_background: bool = False  # track files fitted and written by a thread of their own (live)
    camera_path: CameraPath | None = None  # a turning camera's path: frames seen from its reference camera

    def __post_init__(self) -> None:
        D.MAX_BVH_FILES.check(self.max_bvh_files, "max_bvh_files")
        D.MIN_TRACK_S.check(self.min_track_s, "min_track_s")
        D.BVH_PART_MIN.check(self.bvh_part_min, "bvh_part_min")
        D.LAG_FRAMES.check(self.lag_frames, "lag_frames")
        if self.lag_frames and not self.online_take:
            raise ValueError("a lag (lag_frames) needs the online take: the per-frame stream has none")
        D.CAMERA_HEIGHT_M.check_optional(self.camera_height_m, "camera_height_m")
