"""mocapdb: motion capture from ordinary cameras by retrieval in a database of real motion.

The Python API (docs/api.md); each name is imported on first use, so ``import mocapdb``
stays light:

* building: :func:`build`, :class:`BuildConfig`, :func:`load_database`;
* reconstructing: :class:`Engine` (``step(frame)`` → one :class:`PersonPose` per tracked person,
  ``finish()`` → the tracks' recordings), :class:`EngineConfig`, :func:`frames_from_arrays`,
  :func:`read_keypoint_file`, :func:`read_openpose_folder`, :class:`KeypointFrame`, :class:`Person`;
* the whole take: :func:`fit_takes` (:class:`TakeParams`): a take's recordings (``EngineConfig(keep_take=True)``)
  smoothed, feet planted, on one floor: what ``reconstruct`` writes;
* motion: :class:`Motion` (rotations and root over frames, the one motion type), :func:`read_motion`
  (any humanoid BVH as one);
* outputs: :func:`write_tracks` (:class:`TrackExport`: BVH, TRC, CSV, rig, floor), :func:`write_motion`,
  :func:`motion_bvh`, :func:`read_bvh`, :func:`write_bvh`, :func:`frame_line`, :func:`header_line`;
* errors: :class:`MocapdbError`, the base of every error about inputs.
"""
from __future__ import annotations

import importlib

from mocapdb.core.kernel_cache import choose_kernel_cache

__version__ = "0.1.0"
choose_kernel_cache()  # before any module defines a numba kernel: where numba may cache them

_API = {
    "build": "mocapdb.builder.pipeline",
    "BuildConfig": "mocapdb.builder.config",
    "load_database": "mocapdb.core.formats.database_reader",
    "Engine": "mocapdb.runtime.engine",
    "EngineConfig": "mocapdb.runtime.engine_config",
    "frames_from_arrays": "mocapdb.core.formats.keypoint_arrays",
    "read_keypoint_file": "mocapdb.core.formats.keypoint_arrays",
    "read_openpose_folder": "mocapdb.core.formats.openpose",
    "KeypointFrame": "mocapdb.core.formats.keypoints",
    "Person": "mocapdb.core.formats.keypoints",
    "PersonPose": "mocapdb.core.outputs",
    "fit_takes": "mocapdb.runtime.world.fuse",
    "TakeParams": "mocapdb.runtime.take_params",
    "write_tracks": "mocapdb.core.exports",
    "TrackExport": "mocapdb.core.exports",
    "motion_bvh": "mocapdb.core.outputs",
    "Motion": "mocapdb.core.motion",
    "write_motion": "mocapdb.core.exports",
    "read_motion": "mocapdb.core.clips",
    "frame_line": "mocapdb.core.outputs",
    "header_line": "mocapdb.core.outputs",
    "read_bvh": "mocapdb.core.formats.bvh",
    "write_bvh": "mocapdb.core.formats.bvh",
    "MocapdbError": "mocapdb.core.errors",
}
__all__ = ["__version__", *_API]


def __getattr__(name: str) -> object:
    if name not in _API:
        raise AttributeError(f"module 'mocapdb' has no attribute {name!r}")
    value = getattr(importlib.import_module(_API[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
