"""What ``mocapdb build`` is asked to do: :class:`BuildConfig` (the method's parameters, the
sources' joint maps, memory, work folder and scheduler, each checked by its flag) and
:class:`BuildError`, a build that cannot go on.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapdb.builder.memory import default_memory_limit_mb
from mocapdb.core import domains as D
from mocapdb.core.cameras import DatabaseCamera
from mocapdb.core.clips import ClipOptions
from mocapdb.core.errors import MocapdbError
from mocapdb.core.joint_map import UNITS, UP_AXES

MAX_YAWS = 32767  # projections.yaw is int16


class BuildError(MocapdbError, RuntimeError):
    """A build that cannot go on; the message says why, ``skipped`` names the files skipped before
    it stopped, each with its reason (``(path, reason)`` pairs)."""

    def __init__(self, message: str, skipped: Sequence[tuple[str, str]] = ()):
        super().__init__(message)
        self.skipped = list(skipped)


@dataclass
class BuildConfig:
    """Parameters of a database build (defaults are the method's)."""

    fps: float = D.DATABASE_FPS_HZ.default
    yaw_step_deg: float = D.YAW_STEP_DEG.default
    camera: DatabaseCamera = field(default_factory=DatabaseCamera)
    clusters: int = D.CLUSTERS.default
    dims: int = D.DIMS.default
    seed: int = 0
    landmarks: int = D.LANDMARKS.default
    workers: int = 1
    strict: bool = False
    joint_map: Path | None = None  # for the files no other map covers
    joint_maps: tuple[tuple[str, Path], ...] = ()  # (glob pattern, map), first match first
    unit: str | None = None
    up_axis: str | None = None
    credit: str | None = None
    mirror: bool = True  # also store every clip's left-right mirror image
    memory_limit_mb: int | None = None  # peak memory aimed at; None: default_memory_limit_mb()
    work_dir: Path | None = None  # the work folder; None: the output's path with ".work" appended
    restart: bool = False  # ignore an interrupted build's work and start again
    scheduler: str | None = None  # run the tasks on Dask: a scheduler's address, or "local:N" workers here

    def clip_options(self) -> ClipOptions:
        """The options that turn a BVH file into clips (:mod:`mocapdb.core.clips`)."""
        return ClipOptions(self.fps, self.joint_map, self.unit, self.up_axis, self.credit, self.mirror,
                           self.joint_maps)

    @property
    def yaws_deg(self) -> np.ndarray:
        step = D.YAW_STEP_DEG.check(self.yaw_step_deg, "--yaw-step")
        ratio = 360.0 / step
        n = round(ratio) if ratio < MAX_YAWS + 1 else 0
        if n < 1 or abs(n * step - 360.0) > 1e-6:
            raise BuildError(f"--yaw-step {step} does not divide 360 degrees into 1 to {MAX_YAWS} yaws")
        return np.arange(n) * step

    @property
    def limit_mb(self) -> int:
        """The memory limit in MB: the one given, else the default (a share of the machine's)."""
        return default_memory_limit_mb() if self.memory_limit_mb is None else self.memory_limit_mb

    def check(self) -> None:
        """Raise DomainError or BuildError naming the first option (by its ``mocapdb build`` flag)
        that cannot work."""
        for flag, domain, value in [
                ("--fps", D.FPS_HZ, self.fps), ("--camera-height", D.CAMERA_HEIGHT_M, self.camera.height_m),
                ("--camera-distance", D.CAMERA_DISTANCE_M, self.camera.distance_m),
                ("--focal", D.FOCAL_PX, self.camera.focal_px), ("--clusters", D.CLUSTERS, self.clusters),
                ("--dims", D.DIMS, self.dims), ("--landmarks", D.LANDMARKS, self.landmarks),
                ("--workers", D.WORKERS, self.workers), ("--seed", D.SEED, self.seed),
                ("camera width_px", D.IMAGE_SIDE_PX, self.camera.width_px),
                ("camera height_px", D.IMAGE_SIDE_PX, self.camera.height_px)]:
            domain.check(value, flag)
        D.MEMORY_LIMIT_MB.check_optional(self.memory_limit_mb, "--memory-limit")
        self.yaws_deg
        if self.landmarks <= self.dims:
            raise BuildError(f"--landmarks {self.landmarks} is too few for --dims {self.dims}: "
                             "landmark MDS needs at least dims + 1 landmarks")
        if self.unit not in (None, *UNITS) or self.up_axis not in (None, *UP_AXES):
            raise BuildError(f"unknown --unit {self.unit!r} or --up-axis {self.up_axis!r}: "
                             f"units {', '.join(UNITS)}; up axes {', '.join(UP_AXES)}")
