"""What every stage of `mocapdb stereo` shares: its parameters, its error, its result, its files.

Coordinates: camera 1's OpenCV axes (x right, y down, z forward), the baseline = 1 unless
``camera_distance_m`` gives metres. Decisions: ``data_specs/stereo.md``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocapdb.core.domains import BASELINE_M
from mocapdb.core.errors import MocapdbError
from mocapdb.core.outputs import OutputFiles

# The files `mocapdb stereo` writes (``data_specs/stream_output.md``); one BVH per person (``bvh_name``).
RESULT_FILE, CAMERAS_FILE, BVH_FILE = "result.jsonl", "cameras.json", "stereo.bvh"
CALIBRATION_FILE = "calibration.toml"  # the two cameras for Pose2Sim
# An earlier output folder of `mocapdb stereo` holds cameras.json and only these (replaced whole).
STEREO_FILES = OutputFiles("stereo", (RESULT_FILE, CAMERAS_FILE, CALIBRATION_FILE, BVH_FILE, "stereo_track_*.bvh"),
                           CAMERAS_FILE)


def bvh_name(track: int) -> str:
    """The BVH of a track: ``stereo.bvh`` for the main person (track 0), ``stereo_track_<id>.bvh`` for the others."""
    return BVH_FILE if track == 0 else f"stereo_track_{track}.bvh"


class StereoError(MocapdbError, ValueError):
    """Input the stereo reconstruction cannot use; the message says why."""


@dataclass
class StereoConfig:
    """The method's parameters (defaults: the paper's)."""

    ransac_threshold: float = 0.005   # essential-matrix RANSAC, normalised image units
    ransac_prob: float = 0.999
    epsilon: float = 0.025            # sphericity that stops stage 2
    plateau_rounds: int = 5           # rounds without a lower ε after which ε has reached the data's floor
    plateau_epsilon: float = 0.1      # such a floor below this converges (real detections: 0.05–0.08, true cameras)
    delta: float = 0.2                # bone inlier band: length within 1 ± delta of its scale
    gamma: float = 0.2                # fraction of the ellipsoid undistortion applied per round
    max_rounds: int = 20
    max_draws: int = 2500
    good_samples: int = 100
    pnp_iterations: int = 10000
    alpha: float = 20.0               # stage 3 weight of the bone term
    bone_rounds: int = 5              # stage 3 rounds m
    confidence: float = 0.3
    camera_distance_m: float | None = None
    seed: int = 0
    min_correspondences: int = 50
    noise_correction: bool = True     # remove triangulation-noise bias from the ellipsoid fit (not in the paper)

    def __post_init__(self) -> None:
        BASELINE_M.check_optional(self.camera_distance_m, "camera_distance_m (--camera-distance)")


@dataclass
class StereoResult:
    """The reconstruction in camera 1's OpenCV axes (metres when ``scaled``, else baselines).

    ``points_m [T, J, 3]`` final joints (NaN where invalid), ``stage1_points``/``stage2_points``
    the intermediate ones; camera 2 is ``x₂ = R x₁ + t`` (``stage1_R``, ``stage1_t``: its stage-1
    estimate); ``epsilons`` the sphericity of each ellipsoid round, ``kept_round`` the one kept,
    ``converged`` whether a round reached the stop (:func:`mocapdb.stereo.ellipose.converged`; None: no round).
    """

    points_m: np.ndarray
    stage1_points: np.ndarray
    stage2_points: np.ndarray
    R: np.ndarray
    t: np.ndarray
    stage1_R: np.ndarray
    stage1_t: np.ndarray
    scaled: bool
    epsilons: list[float] = field(default_factory=list)
    kept_round: int = 0
    warnings: list[str] = field(default_factory=list)
    valid: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    converged: bool | None = None
