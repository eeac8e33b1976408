"""`mocapdb stereo`: everyone two synchronised, uncalibrated cameras see, in 3D (ElliPose).

Modules, in the order a run uses them: ``views`` (read and check the two keypoint folders),
``people`` (who is who across the views), ``ellipose`` (the three stages: relative pose in
``relative_pose``, ellipsoid correction in ``ellipsoid``, bone lengths in ``bone_lengths``, sanity in
``checks``), ``motion`` (each person's 3D points → levelled motion on the universal rig), ``outputs``
(``result.jsonl``, ``cameras.json``, ``calibration.toml``, BVHs, the summary) and ``pipeline`` (:func:`run_stereo`);
``config`` holds what they share. Decisions: ``data_specs/stereo.md``.
"""
from mocapdb.stereo.config import StereoConfig, StereoError
from mocapdb.stereo.outputs import StereoSummary
from mocapdb.stereo.pipeline import run_stereo

__all__ = ["StereoConfig", "StereoError", "StereoSummary", "run_stereo"]
