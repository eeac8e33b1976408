"""`mocapdb stereo`: same-frame detection pairs of the two views and their epipolar consistency.

Every (view-1, view-2) detection pair of a frame (:class:`Pairs`, :func:`all_pairs`) is measured
under an essential matrix (:func:`measure`: median Sampson distance in ≈ pixels, as detected and
with view 2's left and right swapped); a still 2D track paired with a moving one is marked
(:func:`spread`). Essential matrices for matching are fitted by RANSAC (:func:`fit_essential`) to
the correspondences of chosen pairs. Decisions and thresholds: ``data_specs/stereo.md``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.skeleton import MIRROR_SOURCE, N_KEYPOINTS_2D
from mocapdb.stereo.config import StereoConfig
from mocapdb.stereo.relative_pose import ESSENTIAL_METHOD, sampson_distance
from mocapdb.stereo.tracks_2d import Detections, box_diagonal, masked_median

# A pair (person in view 1, person in view 2) of one frame is consistent when at least
# MIN_SHARED_JOINTS joints are confident in both and the median of their first-order epipolar
# (Sampson) distances is at most MAX_EPIPOLAR_PX. Distances are measured in undistorted normalised
# coordinates and multiplied by the mean focal length of the two cameras (≈ pixels). On the
# Pose2Sim take (f ≈ 1680 px) the true pairs' medians are 2-17 px (median 4-6 px), while a false
# person paired with the true one in the other view lies 18-300 px off.
MIN_SHARED_JOINTS = 6
MAX_EPIPOLAR_PX = 20.0
# A detector sometimes swaps a body's left and right (a back view; on the demo video camera 1's frame
# 87, camera 2's frames 10 and 81): the pair of the person's 2D tracks is then inconsistent, and
# consistent with one detection's left and right swapped. Of its two detections, the one that the swap
# brings closer to its own 2D track's neighbouring detections is turned back (neither: left as it is;
# :func:`mocapdb.stereo.people.unflip`).
MIRROR = MIRROR_SOURCE[:N_KEYPOINTS_2D]  # each keypoint's left-right partner
# A 2D track whose joints stay within STILL_SPREAD box diagonals of their mean (median over the joints:
# a still person, detector noise only) is never the same person as one whose joints move MOVING_SPREAD
# or more in the other view over the same frames (every joint would have to move along the first
# camera's rays). Yet an essential matrix fitted to such a pair puts each moving joint on its fixed
# epipolar line: the Pose2Sim demo video's still woman behind (cameras 1 and 2: 0.005 and 0.011)
# paired with the performer (0.12-0.15) is consistent in 72-99 of 100 frames under its own matrix.
STILL_SPREAD = 0.03
MOVING_SPREAD = 0.06
MAX_MATCH_CORRESPONDENCES = 3000  # per essential matrix fitted for matching (the cameras' fit uses all)


@dataclass
class Pairs:
    """Every same-frame (view-1, view-2) detection pair and its epipolar distance."""

    i: np.ndarray         # [M] view-1 detection
    j: np.ndarray         # [M] view-2 detection
    frame: np.ndarray     # [M]
    shared: np.ndarray    # [M, 14] joints confident in both
    distance: np.ndarray  # [M] median Sampson distance (px); inf with fewer than MIN_SHARED_JOINTS shared
    mirrored: np.ndarray  # [M] the same with view 2's left and right swapped
    still_moving: np.ndarray  # [M] one of the pair's 2D tracks still, the other moving: never one person

    @property
    def consistent(self) -> np.ndarray:
        return self.distance <= MAX_EPIPOLAR_PX

    @property
    def flipped(self) -> np.ndarray:
        """``[M]`` pairs consistent only with one detection's left and right swapped."""
        return ~self.consistent & (self.mirrored <= MAX_EPIPOLAR_PX)


def all_pairs(d1: Detections, d2: Detections) -> Pairs:
    """Every (view-1, view-2) detection pair of the same frame (distances not yet measured)."""
    by_frame: dict[int, list[int]] = {}
    for row, f in enumerate(d2.frame.tolist()):
        by_frame.setdefault(f, []).append(row)
    ij = np.array([(i, j) for i, f in enumerate(d1.frame.tolist()) for j in by_frame.get(f, [])],
                  dtype=np.int64).reshape(-1, 2)
    i, j = ij[:, 0], ij[:, 1]
    pairs = Pairs(i, j, d1.frame[i], d1.vis[i] & d2.vis[j], np.full(len(i), np.inf), np.full(len(i), np.inf),
                  np.zeros(len(i), dtype=bool))
    for rows in pairing_groups(pairs, d1, d2)[1]:
        spreads = sorted((spread(d1, pairs.i[rows]), spread(d2, pairs.j[rows])))
        pairs.still_moving[rows] = spreads[0] < STILL_SPREAD and spreads[1] >= MOVING_SPREAD
    return pairs


def spread(d: Detections, det: np.ndarray) -> float:
    """How much detections ``det`` (of one 2D track) move: the median over their joints of each one's RMS
    distance from its mean position, in median box diagonals."""
    seen = d.vis[det].sum(axis=0) >= 2
    if not seen.any():
        return 0.0
    xy = np.where(d.vis[det][:, seen, None], d.points[det][:, seen], np.nan)
    rms = np.sqrt(np.nanvar(xy, axis=0).sum(axis=-1))
    return float(np.median(rms) / np.median(box_diagonal(d.points[det], d.vis[det])))


def measure(pairs: Pairs, d1: Detections, d2: Detections, essential: np.ndarray, focal: float) -> Pairs:
    """``pairs`` with their median Sampson distances (px) under ``essential``, as detected and with view
    2's left and right swapped."""
    n1, n2 = np.nan_to_num(d1.normalised[pairs.i]), np.nan_to_num(d2.normalised[pairs.j])
    mirrored = d1.vis[pairs.i] & d2.vis[pairs.j][:, MIRROR]
    return replace(pairs, distance=_median_px(n1, n2, pairs.shared, essential, focal),
                   mirrored=_median_px(n1, n2[:, MIRROR], mirrored, essential, focal))


def _median_px(n1: np.ndarray, n2: np.ndarray, shared: np.ndarray, essential: np.ndarray,
               focal: float) -> np.ndarray:
    """Median Sampson distance (px) of the ``shared`` joints of each pair; inf with fewer than MIN_SHARED_JOINTS."""
    median = masked_median(sampson_distance(essential, n1, n2) * focal, shared)
    return np.where(shared.sum(axis=1) >= MIN_SHARED_JOINTS, median, np.inf)


def fit_essential(n1: np.ndarray, n2: np.ndarray, config: StereoConfig) -> np.ndarray | None:
    """Essential matrix by RANSAC from normalised correspondences ``[N, 2]`` (None when none fits);
    at most MAX_MATCH_CORRESPONDENCES of them, evenly spread (matching needs no more)."""
    step = max(1, int(np.ceil(len(n1) / MAX_MATCH_CORRESPONDENCES)))
    n1, n2 = n1[::step], n2[::step]
    essential, _ = cv2.findEssentialMat(n1, n2, np.eye(3), method=ESSENTIAL_METHOD, prob=config.ransac_prob,
                                        threshold=config.ransac_threshold)
    return None if essential is None or essential.shape[0] < 3 else essential[:3]


def pair_correspondences(pairs: Pairs, rows: np.ndarray, d1: Detections,
                         d2: Detections) -> tuple[np.ndarray, np.ndarray]:
    shared = pairs.shared[rows]
    return d1.normalised[pairs.i[rows]][shared], d2.normalised[pairs.j[rows]][shared]


def pairing_groups(pairs: Pairs, d1: Detections, d2: Detections) -> tuple[np.ndarray, list[np.ndarray]]:
    """The (view-1 2D track, view-2 2D track) pairings ``[K, 2]`` present in ``pairs``, and each one's rows."""
    n2 = int(d2.track.max(initial=-1)) + 1
    keys, inverse = np.unique(d1.track[pairs.i] * n2 + d2.track[pairs.j], return_inverse=True)
    order = np.argsort(inverse, kind="stable")
    groups = np.split(order, np.cumsum(np.bincount(inverse, minlength=len(keys)))[:-1]) if len(keys) else []
    return np.stack([keys // max(n2, 1), keys % max(n2, 1)], axis=1), groups


def mean_focal(cam1: CameraModel, cam2: CameraModel) -> float:
    """The mean focal length (px) of both cameras: normalised distances × it ≈ pixels."""
    return float(np.mean([cam1.K[0, 0], cam1.K[1, 1], cam2.K[0, 0], cam2.K[1, 1]]))
