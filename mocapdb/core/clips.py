"""BVH files → clips on the universal skeleton (what the builder stores and evaluations take as truth).

A file is read, mapped onto the universal skeleton (:mod:`mocapdb.core.joint_map`), split at jumps
in the data, resampled to the database frame rate and retargeted; optionally followed by its
left-right mirror image.
"""
from __future__ import annotations

import fnmatch
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from mocapdb.core.files import MIB, read_input_text
from mocapdb.core.formats.bvh import BvhError, read_bvh
from mocapdb.core.joint_map import detect_mapping, extract_keypoints, load_joint_map_file
from mocapdb.core.motion import Motion
from mocapdb.core.motion_ops import mirror_keypoints, resample
from mocapdb.core.skeleton import ANKLE_HEIGHT_M, BONE_LENGTHS_M, KP, PELVIS, retarget

CREDIT_FILE = "CREDIT.txt"
JOINT_MAP_FILE = "joint_map.toml"  # a joint map beside the sources: for its folder and those below
MAX_CREDIT_BYTES = MIB  # a licence text
MIRROR_SUFFIX = "~mirror"  # added to the name of a clip's left-right mirror image


@dataclass(frozen=True)
class ClipOptions:
    """How BVH files become clips: the database frame rate and how to read the source rig."""

    fps: float = 24.0
    joint_map: Path | None = None  # TOML file mapping skeleton roles to source joint names (files no
    #                                other map covers)
    unit: str | None = None        # source length unit (None: detected)
    up_axis: str | None = None     # source up axis (None: detected)
    credit: str | None = None      # credit text (None: nearest CREDIT.txt)
    mirror: bool = True            # each clip followed by its left-right mirror image
    joint_maps: tuple[tuple[str, Path], ...] = ()  # (glob pattern, map): the first whose pattern the
    #                                                file's name or path matches (before joint_map.toml)


@dataclass
class Clip:
    """One source clip on the universal skeleton at the database frame rate: its :class:`Motion`
    (world frame, the universal body, float32) and where it came from."""

    name: str
    source: str
    source_fps: float
    convention: str
    credit: str
    motion: Motion
    positions: np.ndarray    # [F, 15, 3] the motion's joints (forward kinematics, float32): metres, y up,
    #                          floor at y = 0
    mirrored: bool = False   # the left-right mirror image of the captured motion
    source_m: np.ndarray | None = None  # [F, 15, 3] the source's own joints (its bone lengths), metres,
    #                                     y up, the lowest ankle ANKLE_HEIGHT_M × its leg / universal leg

    @property
    def quaternions(self) -> np.ndarray:
        """The rig joints' local rotations ``[F, R, 4]`` (the motion's)."""
        return self.motion.rotations


def _nearest(path: Path, root: Path, name: str) -> Path | None:
    """The file ``name`` nearest ``path``: in its folder, else the parents' up to its source ``root``."""
    folder = path.parent
    while True:
        candidate = folder / name
        if candidate.is_file():
            return candidate
        if folder == root or folder == folder.parent or root not in folder.parents:
            return None
        folder = folder.parent


def credit_for(path: Path, root: Path, given: str | None) -> str:
    """``given``, else the nearest CREDIT.txt from the file's folder up to its source root."""
    if given is not None:
        return given
    found = _nearest(path, root, CREDIT_FILE)
    return read_input_text(found, MAX_CREDIT_BYTES, BvhError, "credit text").strip() if found else ""


def joint_map_for(path: Path, root: Path, options: ClipOptions) -> Path | None:
    """The joint map a file is read with: the first of ``options.joint_maps`` whose glob pattern its
    name or path matches, else the nearest :data:`JOINT_MAP_FILE` from its folder up to its source
    ``root``, else ``options.joint_map`` (None: detected without a map)."""
    for pattern, map_path in options.joint_maps:
        if fnmatch.fnmatch(path.name, pattern) or fnmatch.fnmatch(str(path), pattern):
            return map_path
    return _nearest(path, root, JOINT_MAP_FILE) or options.joint_map


def clips_from_bvh(path: Path, root: Path, options: ClipOptions) -> list[Clip]:
    """Read, map, split at data jumps, resample and retarget one BVH file.

    The joint map is :func:`joint_map_for`'s. Each continuous run (:func:`continuous_runs`)
    becomes a clip, named after the file, with ``@first-end`` (source frames) added when the file
    was split. With ``options.mirror`` each
    clip is followed by its left-right mirror image (:data:`MIRROR_SUFFIX` added to the name),
    retargeted from the mirrored source keypoints. Raises BvhError or JointMapError when the
    file cannot be used, also when a clip would hold a NaN or infinite value.
    """
    bvh = read_bvh(path)
    map_path = joint_map_for(path, root, options)
    overrides = load_joint_map_file(map_path) if map_path else None
    mapping = detect_mapping(bvh, overrides.joints if overrides else None)
    unit = options.unit or (overrides.unit if overrides else None)
    up_axis = options.up_axis or (overrides.up_axis if overrides else None)
    points = extract_keypoints(bvh, mapping, unit=unit, up_axis=up_axis)
    runs = continuous_runs(points, bvh.fps)
    if not runs:
        raise BvhError(f"{path}: no stretch of {MIN_RUN_S} s without a jump in the data")
    credit = credit_for(path, root, options.credit)
    whole = len(runs) == 1 and runs[0] == slice(0, len(points))
    origin: dict[str, Any] = dict(fps=options.fps, source=str(path), source_fps=bvh.fps, convention=mapping.convention,
                  credit=credit)
    clips = []
    for run in runs:
        name = path.stem if whole else f"{path.stem}@{run.start}-{run.stop}"
        resampled = resample(points[run], bvh.fps, options.fps)
        clips.append(_clip(name, resampled, **origin))
        if options.mirror:
            clips.append(_clip(name + MIRROR_SUFFIX, mirror_keypoints(resampled), mirrored=True, **origin))
    if not all(np.isfinite(c.positions).all() and np.isfinite(c.quaternions).all() for c in clips):
        raise BvhError(f"{path}: NaN or infinite joint positions after retargeting "
                       "(absurdly large values in the file, or a degenerate skeleton)")
    return clips


def process_clip(path: Path, root: Path, options: ClipOptions) -> Clip:
    """The longest continuous clip of a BVH file as captured, never a mirror image (what
    evaluations use as ground truth)."""
    return max(clips_from_bvh(path, root, replace(options, mirror=False)), key=lambda c: len(c.positions))


def read_motion(path: str | Path, fps: float = 24.0) -> Motion:
    """The motion of a BVH file of any humanoid rig on the universal skeleton: its longest stretch
    without a jump in the data, resampled to ``fps`` Hz, retargeted (the universal body, world
    frame, the floor at y = 0), as the builder reads it. The counterpart of
    :func:`mocapdb.core.exports.write_motion`. Raises BvhError or JointMapError when the file
    cannot be used."""
    path = Path(path)
    return process_clip(path, path.parent, ClipOptions(fps=fps)).motion


def _clip(name: str, points: np.ndarray, *, fps: float, source: str, source_fps: float, convention: str, credit: str,
          mirrored: bool = False) -> Clip:
    """Retarget resampled source keypoints (metres, y up, at ``fps`` Hz) and put the floor at y = 0."""
    scale = leg_scale(points)
    quats, positions = retarget(points * scale)
    positions[..., 1] -= _lowest_ankle(positions) - ANKLE_HEIGHT_M
    source_m = points.copy()
    source_m[..., 1] -= _lowest_ankle(points) - ANKLE_HEIGHT_M / scale
    motion = Motion(quats.astype(np.float32), positions[:, PELVIS].astype(np.float32), fps)
    return Clip(name, source, source_fps, convention, credit, motion, positions.astype(np.float32), mirrored,
                source_m.astype(np.float32))


def _lowest_ankle(points: np.ndarray) -> float:
    """The lowest ankle height (y) over a clip's keypoints ``[F, 15, 3]``."""
    return float(points[:, [KP["r_ankle"], KP["l_ankle"]], 1].min())


MAX_JOINT_SPEED_MPS = 15.0  # faster than any human joint: a jump in the data, not motion
MIN_RUN_S = 0.5             # shorter continuous stretches are dropped


def continuous_runs(points_m: np.ndarray, fps: float) -> list[slice]:
    """The runs of frames (at least :data:`MIN_RUN_S` long) with no joint faster than
    :data:`MAX_JOINT_SPEED_MPS` between consecutive frames.

    Converted BVH files often start with a bind pose (T-pose) and then jump to the motion, and
    some hold glitches (a knee flipping 30 cm in 1/60 s); splitting there keeps the database free
    of teleports that the temporal match would otherwise learn. ``points_m [F, J, 3]`` at ``fps``.
    """
    step = np.linalg.norm(np.diff(points_m, axis=0), axis=-1).max(axis=-1)
    cuts = np.concatenate([[0], np.flatnonzero(step * fps > MAX_JOINT_SPEED_MPS) + 1, [len(points_m)]])
    return [slice(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:]) if b - a >= MIN_RUN_S * fps]


def leg_scale(points: np.ndarray) -> float:
    """Universal over source leg length (hip→knee→ankle, median over the clip), for root motion."""
    legs = []
    for side in ("r", "l"):
        hip, knee, ankle = (points[:, KP[f"{side}_{j}"]] for j in ("hip", "knee", "ankle"))
        legs.append(np.linalg.norm(knee - hip, axis=-1) + np.linalg.norm(ankle - knee, axis=-1))
    return (BONE_LENGTHS_M["thigh"] + BONE_LENGTHS_M["shin"]) / float(np.median(np.concatenate(legs)))
