"""The camera's prior in the one-camera world (:mod:`mocapdb.runtime.world.fuse`): how far the bodies'
estimate of the pitch and roll may be off (each track's: :func:`track_tilt_sd_deg`; the take's:
:func:`tilt_prior_sds`, :func:`tilt_cost`), how high people film from (:func:`height_cost`), the
tilted floor normals of the grid (:func:`tilted_normals`) and the posterior spread over that grid
(:func:`tilt_spread_deg`, :func:`height_spread_log`). ``data_specs/world.md`` gives the decisions."""
from __future__ import annotations

import numpy as np

from mocapdb.runtime.world.body_size import TILT_SD_DEG

TILT_TAIL_SD_DEG, TILT_TAIL_SHARE = 15.0, 0.2  # the tilt prior's heavy tail: bodies' estimates can be far off
PITCH_SD_MIN_DEG = 5.0  # bodies show the pitch only by their foreshortening, and share its error (the camera's)
POSTURE_TILT_SD_DEG = 6.0  # one posture's up estimate error (rendered still people: 5.4-5.7° RMS)
# How high people film people (data_specs/world.md, decision 2): a hand or a tripod, 0.37-6 m (±2 SD of
# the log), 80 %; anything in the world's range (a camera on the ground, a stand, a roof, a drone), 20 %.
CAMERA_HEIGHT_MEDIAN_M, CAMERA_HEIGHT_LOG_SD, CAMERA_HEIGHT_TAIL_SHARE = 1.5, 0.7, 0.2


def track_tilt_sd_deg(frame_sd_deg: float, footfalls: int) -> float:
    """The error (degrees) of a track's up estimate (the mean of its frames'), from its frames'
    spread ``frame_sd_deg`` and its ``footfalls`` (contacts begun, both feet): each stride (two
    footfalls) shows a new posture, and the mean's error is a posture's over the root of the strides;
    what no stride removes is :data:`~mocapdb.runtime.world.body_size.TILT_SD_DEG`. The frames' spread
    measures how far postures differ only when there are several: the frames of a person standing
    still share one posture's lean (on rendered still people their spread is 4°, their error 5.5°),
    so a posture errs by at least :data:`POSTURE_TILT_SD_DEG` over the strides."""
    strides = max(footfalls / 2.0, 1.0)
    posture_sd = max(frame_sd_deg, POSTURE_TILT_SD_DEG / strides)
    return float(np.hypot(TILT_SD_DEG, posture_sd / np.sqrt(strides)))


def tilt_prior_sds(tilt_sd_deg: float) -> tuple[float, float]:
    """The prior's pitch and roll errors (degrees) about the bodies' estimate: ``tilt_sd_deg`` (the
    tracks' estimates combined), the pitch's at least :data:`PITCH_SD_MIN_DEG` (the people of one
    take share its error, so more of them do not average it away)."""
    return max(tilt_sd_deg, PITCH_SD_MIN_DEG), tilt_sd_deg


def tilt_cost(tilts_deg: np.ndarray, sds_deg: tuple[float, float]) -> np.ndarray:
    """``−log`` prior ``[T]`` of tilt corrections ``[T, 2]`` (pitch, roll; degrees) about the bodies'
    estimate, per axis a mixture: its error ``sds_deg`` (weight 1 − :data:`TILT_TAIL_SHARE`) and a
    wide tail (:data:`TILT_TAIL_SD_DEG`): a body shows the camera's pitch only by its foreshortening,
    so its estimate is now and then far off (16° on a real take's bystander), and then the floor
    under several people overrules it."""
    sds = np.asarray(sds_deg)
    narrow = np.log1p(-TILT_TAIL_SHARE) - 0.5 * (tilts_deg / sds) ** 2 - np.log(sds)
    wide = np.log(TILT_TAIL_SHARE) - 0.5 * (tilts_deg / TILT_TAIL_SD_DEG) ** 2 - np.log(TILT_TAIL_SD_DEG)
    return -np.sum(np.logaddexp(narrow, wide), axis=1)


def height_cost(log_heights: np.ndarray, log_range_width: float) -> np.ndarray:
    """``−log`` prior ``[H]`` of camera heights (log metres): a log-normal about
    :data:`CAMERA_HEIGHT_MEDIAN_M` (weight 1 − :data:`CAMERA_HEIGHT_TAIL_SHARE`) and a flat tail over
    the grid's range (``log_range_width`` in log metres). Where the people leave the height free (two
    people whose floor could pass through the camera), it keeps the camera off the grid's ends; any
    person on a floor outweighs it (a log stature's error is ~0.05, this prior's 0.7)."""
    z = (np.asarray(log_heights) - np.log(CAMERA_HEIGHT_MEDIAN_M)) / CAMERA_HEIGHT_LOG_SD
    usual = (1.0 - CAMERA_HEIGHT_TAIL_SHARE) * np.exp(-0.5 * z ** 2) / (CAMERA_HEIGHT_LOG_SD * np.sqrt(2.0 * np.pi))
    return -np.log(usual + CAMERA_HEIGHT_TAIL_SHARE / log_range_width)


def tilted_normals(normal: np.ndarray, tilts_deg: np.ndarray) -> np.ndarray:
    """``normal`` turned about the camera's x axis by each pitch, then about its viewing axis by each
    roll (``tilts_deg [T, 2]``): ``[T, 3]``."""
    pitch, roll = np.radians(tilts_deg[:, 0]), np.radians(tilts_deg[:, 1])
    c, s = np.cos(pitch), np.sin(pitch)
    x, y, z = np.full_like(c, normal[0]), c * normal[1] - s * normal[2], s * normal[1] + c * normal[2]
    c, s = np.cos(roll), np.sin(roll)
    return np.stack([c * x - s * y, s * x + c * y, z], axis=1)


def tilt_spread_deg(tilts_deg: np.ndarray, cost: np.ndarray, grid_step_deg: float) -> tuple[float, float]:
    """The posterior SDs of pitch and roll (degrees) over a tilt grid ``[T, 2]`` and its ``−log``
    posterior ``cost [T, H]`` (heights marginalised): the world's reported pitch and roll errors. At
    least the grid's step ``grid_step_deg`` over √12."""
    weight = np.exp(-(cost - cost.min())).sum(axis=1)
    weight /= weight.sum()
    mean = weight @ tilts_deg
    sd = np.sqrt(weight @ (tilts_deg - mean) ** 2)
    step = grid_step_deg / np.sqrt(12.0)
    return float(max(sd[0], step)), float(max(sd[1], step))


def height_spread_log(log_heights: np.ndarray, cost: np.ndarray) -> float:
    """The posterior SD of the log camera height over a grid's heights ``log_heights [H]`` (log
    metres) and its ``−log`` posterior ``cost [T, H]``, the tilts marginalised: the world's reported
    height error. 0 for one height (given)."""
    weight = np.exp(-(cost - cost.min())).sum(axis=0)
    mean = np.sum(weight * log_heights) / np.sum(weight)
    return float(np.sqrt(np.sum(weight * (log_heights - mean) ** 2) / np.sum(weight)))
