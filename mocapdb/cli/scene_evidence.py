"""The scene's lines of a keypoint folder (``scene.json``, written by `mocapdb detect`) for
``reconstruct`` and ``live``: the focal length where nothing gave one, and the vanishing points the
world looks for the vertical in (:mod:`mocapdb.runtime.world.scene_lines`)."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

LOG = logging.getLogger(__name__)
DEFAULT_FOCAL_SD = 0.25   # the guessed focal's error, relative (phones' main cameras 24-28 mm; others differ more)


def use_scene(args: argparse.Namespace, source: str) -> None:
    """Sets ``args.scene`` (a :class:`~mocapdb.runtime.world.scene_lines.SceneEvidence` or None) from
    ``source/scene.json``; where the focal was the default guess and the scene's orthogonal vanishing
    points give one, ``args.focal`` becomes that (``args.camera_sources["focal_px"]``: "scene"),
    else the guess is warned about. A given focal the scene contradicts by more than 3 SD is kept,
    with a warning. A turning camera's lines (``args.camera_path``) are first seen from its
    reference camera, as its keypoints are (:func:`in_reference_camera`)."""
    from mocapdb.runtime.world.scene_lines import SceneEvidence, vanishing_points

    scene = _readable_scene(source, tuple(args.image_size))
    path = getattr(args, "camera_path", None)
    if scene is not None and path is not None and not path.still:
        scene = in_reference_camera(scene, path)
    points = None if scene is None else vanishing_points(scene)
    found = None if points is None else points.focal()
    how = args.camera_sources.get("focal_px")
    focal_sd = DEFAULT_FOCAL_SD * args.focal if how == "default" else 0.0
    if how == "default" and found is None:
        from mocapdb.core.formats.take import DEFAULT_FOCAL_35MM

        LOG.warning("no focal length given: assuming a typical phone main camera, %g mm equivalent (%.0f px for "
                    "%dx%d); give --focal PX, --fov DEG or --focal-35mm MM", DEFAULT_FOCAL_35MM, args.focal,
                    *args.image_size)
    elif how == "default" and found is not None:
        LOG.warning("no focal length given: %.0f px (±%.0f) from the scene's lines (scene.json)",
                    found.focal_px, found.sd_px)
        args.focal, focal_sd = found.focal_px, found.sd_px
        args.camera_sources["focal_px"] = "scene"
    elif found is not None and abs(found.focal_px - args.focal) > 3 * found.sd_px:
        LOG.warning("the scene's lines give a focal of %.0f px (±%.0f), the %s one is %.0f px: using %.0f px",
                    found.focal_px, found.sd_px, how, args.focal, args.focal)
    args.scene = None if points is None else SceneEvidence(points, args.focal, focal_sd)


def _readable_scene(source: str, image_size: tuple[int, int]):
    """The folder's :class:`~mocapdb.core.formats.scene.SceneLines`, or None: no folder, no file, or
    lines seen in an image of another size than the keypoints' (warned)."""
    from mocapdb.core.formats.scene import SCENE_FILE, read_scene

    scene = read_scene(source) if source and Path(source).is_dir() else None
    if scene is not None and tuple(scene.image_size) != image_size:
        LOG.warning("%s: its lines were seen in a %dx%d image, the keypoints' is %dx%d: not used",
                    Path(source) / SCENE_FILE, *scene.image_size, *image_size)
        return None
    return scene


def in_reference_camera(scene, path):
    """``scene``'s segments as the reference camera of a turning camera's ``path``
    (:class:`~mocapdb.core.formats.camera_path.CameraPath`) sees them: each sampled frame's turned
    back by its rotation (a homography keeps lines straight); a segment with an end behind the
    reference camera is dropped. The world's tilt is then the reference camera's, as the people's."""
    from dataclasses import replace

    import numpy as np

    from mocapdb.core.formats.camera_path import derotate_points

    def turned(frame: int, segments: np.ndarray) -> np.ndarray:
        ends = derotate_points(segments.reshape(-1, 2), path.rotation(frame), path.intrinsics).reshape(-1, 4)
        return ends[np.isfinite(ends).all(axis=1)]
    return replace(scene, segments=tuple(turned(f, s) for f, s in zip(scene.frames, scene.segments)))
