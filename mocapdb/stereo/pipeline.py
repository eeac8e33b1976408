"""`mocapdb stereo`: two uncalibrated cameras' OpenPose JSON → 3D motion (ElliPose), JSON lines and BVH.

Steps: load both folders (:mod:`mocapdb.stereo.views`: frame-synchronised, same frame count) →
find everyone seen by both views (:mod:`mocapdb.stereo.people`: 2D tracks per view, matched by
epipolar consistency over time) → :func:`mocapdb.stereo.ellipose.reconstruct` on all of them
stacked along time (relative camera pose from the bodies, ellipsoid correction) → each person
triangulated with those cameras and given its own bone-length consistency, metres, levelling and
inverse kinematics (:mod:`mocapdb.stereo.motion`) → ``result.jsonl``, ``cameras.json`` and one BVH
per person (:mod:`mocapdb.stereo.outputs`). Output contract: ``data_specs/stream_output.md``;
method: ``../shared/method/ellipose_stereo.md``; decisions: ``data_specs/stereo.md``.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.domains import FPS_HZ
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.outputs import check_output_folder
from mocapdb.core.progress import progress
from mocapdb.stereo.checks import check_synchronised
from mocapdb.stereo.config import STEREO_FILES, StereoConfig, StereoError, StereoResult
from mocapdb.stereo.ellipose import reconstruct
from mocapdb.stereo.motion import people_motions
from mocapdb.stereo.outputs import (
    StereoSummary,
    calibration_text,
    cameras_text,
    track_records,
    write_outputs,
)
from mocapdb.stereo.people import MIN_PERSON_FRAMES, People, Selection, match_people
from mocapdb.stereo.relative_pose import rotation_angle_deg
from mocapdb.stereo.views import load_views


def select_people(frames1: list[KeypointFrame], frames2: list[KeypointFrame], cam1: CameraModel,
                  cam2: CameraModel, config: StereoConfig) -> Selection:
    """The main person (track 0: the most joints seen by both views) of :func:`match_people`;
    ``dropped`` lists the frames where nobody is reconstructed."""
    return require_people(match_people(frames1, frames2, cam1, cam2, config)).persons[0]


def require_people(people: People) -> People:
    """``people``; StereoError naming the unmatched detections when nobody is seen by both views."""
    if not people.persons:
        raise StereoError(f"no person is seen consistently by both cameras in {MIN_PERSON_FRAMES} frames or more "
                          f"({'; '.join(people.unmatched) or 'no detections'})")
    return people


def estimate_cameras(people: People, cam1: CameraModel, cam2: CameraModel, config: StereoConfig) -> StereoResult:
    """Camera 2's pose from every person's correspondences: :func:`mocapdb.stereo.ellipose.reconstruct` on
    the people stacked one after the other along time (one essential matrix and one ellipsoid
    per bone type for all; each person's stage 3 is
    :func:`mocapdb.stereo.motion.person_points`)."""
    x1, c1, x2, c2 = (np.concatenate([getattr(p, name) for p in people.persons]) for name in ("x1", "c1", "x2", "c2"))
    person = np.concatenate([np.full(len(p.kept), k) for k, p in enumerate(people.persons)])
    return reconstruct(x1, c1, x2, c2, cam1, cam2, config, person=person)


def run_stereo(view1_dir: str | Path, view2_dir: str | Path, cam1: CameraModel, cam2: CameraModel,
               config: StereoConfig, fps: float, out_dir: str | Path, layout: str | None = None,
               trim: bool = False) -> StereoSummary:
    """Reconstruct everyone two cameras see; writes ``result.jsonl``, ``cameras.json``,
    ``calibration.toml`` and one BVH per person (:func:`mocapdb.stereo.config.bvh_name`) as the
    folder ``out_dir``: an earlier stereo output there is replaced once the new one is complete, a
    folder holding anything else is refused before any work (OutputFolderError naming a file).

    ``cam1``, ``cam2``: intrinsics and distortion (their extrinsics are not used). ``fps`` (Hz)
    times the frames. Raises StereoError, CalibrationError or KeypointError with a clear message.
    """
    FPS_HZ.check(fps, "fps (--fps)")
    check_output_folder(out_dir, STEREO_FILES)
    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    stages = progress(total=5, desc="stereo", unit="stage")  # load, select, reconstruct, ik, write

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[stage], clock = now - clock, now
        stages.set_postfix_str(stage, refresh=False)
        stages.update()
        if stages.n == stages.total:
            stages.close()

    frames1, frames2, warnings = load_views(view1_dir, view2_dir, layout, trim)
    lap("load")
    people = require_people(match_people(frames1, frames2, cam1, cam2, config))
    check_synchronised(people.persons[0], cam1, cam2, config)
    lap("select")
    result = estimate_cameras(people, cam1, cam2, config)
    warnings += list(result.warnings)
    lap("reconstruct")
    motions, world = people_motions(people, result, cam1, cam2, config, fps)
    warnings += [w for m in motions for w in m.warnings]
    notes = [n for m in motions for n in m.notes]
    lap("ik")
    tracks = track_records(people, motions)
    cameras = cameras_text(cam1, cam2, result, world, people, tracks, warnings, notes)
    paths = write_outputs(out_dir, motions, world, cameras, fps, calibration_text(cam1, cam2, result, world))
    lap("write")
    return StereoSummary(len(frames1), people.dropped, [float(e) for e in result.epsilons],
                         int(result.kept_round), rotation_angle_deg(np.asarray(result.R)),
                         float(np.linalg.norm(result.t)) * world.scale, bool(result.scaled),
                         world.scale_source, warnings, seconds, paths, tracks, people.unmatched, result.converged,
                         notes)
