"""The stream's rotations (issue 50): each rig joint's local rotation through a Kalman filter that
predicts it at a constant angular velocity, in the tangent space about the prediction, and, given a
lag of ``L`` frames, a fixed-lag Rauch–Tung–Striebel smoother over the last ``L`` frames.

Per joint (the three tangent axes alike and independent, so one 2 × 2 covariance per joint):

* **state**: the rotation ``q`` (unit quaternion) and its angular velocity ``ω`` (rad/s, in ``q``'s
  own frame: ``q(t + dt) = q ⊗ exp(ω dt)``);
* **motion**: ``ω`` changes by white angular acceleration of spectral density ``a_j² · τ`` (``a_j``:
  :data:`ROTATION_ACCEL_RAD_S2`, the joint's RMS angular acceleration per axis in real motion, times
  ``accel_factor``, the shoulders' also times ``shoulder_factor``; ``τ`` = :data:`ACCEL_FRAME_S`, the
  frame time it was measured at; :func:`spectral_density`), so the prediction over ``T`` seconds adds
  ``q_c [[T³/3, T²/2], [T²/2, T]]``;
* **measurement**: the frame's per-frame fit ``z``; the innovation is ``log(q_pred⁻¹ z)`` (its
  rotation vector in the prediction's frame), its noise SD ``fit_sd_rad`` divided by the frame's
  confidence in the joint (the mean confidence of the keypoints that place the joint's child bones,
  :data:`JOINT_KEYPOINTS`, at least :data:`MIN_CONFIDENCE`): each frame's fit is weighed by its
  own uncertainty. An innovation beyond :data:`GATE_CHI2` (squared Mahalanobis distance; a
  retrieval's pop) has its noise inflated by the excess, so it pulls no harder than one at the gate.

Constant angular velocity is followed with no lag: the filter predicts instead of delaying. With
``L > 0`` the estimate of frame ``t − L`` also takes frames ``t − L + 1 … t`` (the smoother runs
back from ``t``): every frame of lag adds evidence and takes none away.

Cost per frame: one numba pass over the joints, plus ``L`` backward steps when lagged.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numba import njit

from mocapdb.core.kernels import quat_exp_into, quat_mul_into, quat_relative_log_into
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D, RIG_JOINTS

# The RMS angular acceleration (rad/s², per tangent axis) of each rig joint's local rotation in the
# 62 CMU clips of ../shared/data/cmu_bvh retargeted at 24 fps, left and right pooled
# (`tools/rotation_motion.py ../shared/data/cmu_bvh` prints them): the process noise's shape over the joints
ROTATION_ACCEL_RAD_S2 = {"pelvis": 13.7, "r_hip": 24.6, "l_hip": 24.6, "r_knee": 16.9, "l_knee": 16.9,
                         "spine": 13.0, "neck": 7.6, "r_shoulder": 31.4, "l_shoulder": 31.4,
                         "r_elbow": 14.6, "l_elbow": 14.6}
ACCEL_FRAME_S = 1.0 / 24.0  # the frame time they were measured at
# The keypoints that place each rig joint's child bones (the joint's rotation is measured through them)
JOINT_KEYPOINTS = {"pelvis": ("r_hip", "l_hip", "neck"), "r_hip": ("r_knee",), "r_knee": ("r_ankle",),
                   "l_hip": ("l_knee",), "l_knee": ("l_ankle",), "spine": ("neck", "r_shoulder", "l_shoulder"),
                   "neck": ("head",), "r_shoulder": ("r_elbow",), "r_elbow": ("r_wrist",),
                   "l_shoulder": ("l_elbow",), "l_elbow": ("l_wrist",)}
MIN_CONFIDENCE = 0.25   # a joint whose keypoints are unseen: its fit counts 1/16 of a seen one's
GATE_CHI2 = 16.0        # squared Mahalanobis distance of a 3-axis innovation
FIRST_TURN_SD_RAD_S = 3.0  # a new track's angular velocity: unknown, of a limb swinging
RESTART_GAP_S = 0.5        # a track unseen this long starts its rotations anew


@dataclass(frozen=True)
class RotationNoise:
    """The filter's model: the fit's SD (radians, at confidence 1), the factor on
    :data:`ROTATION_ACCEL_RAD_S2` (unitless) and the shoulders' further factor (unitless). The
    first two were chosen on unseen bodies (two leave-one-subject-out folds, clean and noisy 2D,
    and the accuracy gate's bodies; a 5 × 4 grid, ``docs/benchmarks.md``): the lag-0 stream's MPJPE
    within 3 % of the per-frame stream's, pooled, at the least acceleration. The shoulders' half
    their measured acceleration (31.4 rad/s², the largest; they turn the whole arm, so their noise
    shakes the elbow and wrist most): of the joint groups halved in turn (shoulders, hips, elbows and
    knees, the trunk; four leave-one-subject-out folds and the gate's bodies), the only one that took
    acceleration off the real take (4 % at lags 0 and 6) for at most 0.4 % of the lag-0 MPJPE on
    unseen bodies; the others cost 1.5–4 % (hips, trunk) or shook more (elbows and knees)."""

    fit_sd_rad: float = float(np.radians(4.0))
    accel_factor: float = 1.0
    shoulder_factor: float = 0.5

    def __post_init__(self) -> None:
        if not (self.fit_sd_rad > 0 and self.accel_factor > 0 and self.shoulder_factor > 0):
            raise ValueError(f"rotation noise out of range: {self}")


ACCEL = np.array([ROTATION_ACCEL_RAD_S2[j] for j in RIG_JOINTS])
SHOULDERS = np.array([j in ("r_shoulder", "l_shoulder") for j in RIG_JOINTS])
# [R, 14]: each rig joint's mean over its JOINT_KEYPOINTS
_JOINT_MEAN = np.array([[float(k in [KP[n] for n in JOINT_KEYPOINTS[j]]) / len(JOINT_KEYPOINTS[j])
                         for k in range(N_KEYPOINTS_2D)] for j in RIG_JOINTS])


def joint_confidence(keypoints_px: np.ndarray | None) -> np.ndarray:
    """``[R]`` each rig joint's confidence from a frame's keypoints ``[14, 3]`` (x, y px, confidence):
    the mean over :data:`JOINT_KEYPOINTS`, at least :data:`MIN_CONFIDENCE`; 1 without keypoints."""
    if keypoints_px is None:
        return np.ones(len(RIG_JOINTS))
    conf = np.nan_to_num(np.asarray(keypoints_px, dtype=np.float64)[:, 2], nan=0.0)
    return np.clip(_JOINT_MEAN @ conf, MIN_CONFIDENCE, 1.0)


def spectral_density(noise: RotationNoise) -> np.ndarray:
    """``[R]`` each rig joint's spectral density of white angular acceleration (rad²/s³) under ``noise``."""
    accel = noise.accel_factor * ACCEL * np.where(SHOULDERS, noise.shoulder_factor, 1.0)
    return accel ** 2 * ACCEL_FRAME_S


def process_noise(spectral: np.ndarray, dt_s: float) -> np.ndarray:
    """``[R, 2, 2]`` the covariance white acceleration of spectral density ``spectral [R]`` (rad²/s³)
    adds to (angle, angular velocity) over ``dt_s`` seconds."""
    block = np.array([[dt_s ** 3 / 3.0, dt_s ** 2 / 2.0], [dt_s ** 2 / 2.0, dt_s]])
    return spectral[:, None, None] * block


@dataclass
class _Entry:
    """One frame of the filter: its filtered state and covariance, and the prediction it was made from."""

    index: int
    q: np.ndarray        # [R, 4] filtered rotations
    w: np.ndarray        # [R, 3] filtered angular velocities (rad/s)
    cov: np.ndarray      # [R, 2, 2] filtered covariance (rad², rad²/s, rad²/s²)
    q_pred: np.ndarray   # [R, 4] the prediction from the frame before
    w_pred: np.ndarray   # [R, 3]
    cov_pred: np.ndarray  # [R, 2, 2]
    dt_s: float          # since the frame before (0: the first frame: no prediction)


class RotationKalman:
    """A track's rotations: :meth:`add` each frame's fit (frame indices increasing), :meth:`estimate`
    any of the last ``lag_frames + 1`` frames given every frame added so far (module docstring);
    ``spectral [R]``: the joints' spectral density (rad²/s³) where not the rig's (:func:`spectral_density`)."""

    def __init__(self, fps: float, lag_frames: int, noise: RotationNoise = RotationNoise(),
                 spectral: np.ndarray | None = None):
        self.dt = 1.0 / fps
        self.noise = noise
        self.spectral = spectral_density(noise) if spectral is None else np.asarray(spectral, dtype=np.float64)
        self.history: deque[_Entry] = deque(maxlen=lag_frames + 1)

    def add(self, index: int, quats: np.ndarray, confidence: np.ndarray) -> None:
        """Frame ``index``'s fit ``quats [R, 4]`` with each joint's ``confidence [R]`` (0 … 1)."""
        z = np.asarray(quats, dtype=np.float64)
        r2 = (self.noise.fit_sd_rad / np.asarray(confidence, dtype=np.float64)) ** 2
        last = self.history[-1] if self.history else None
        if last is None or (index - last.index) * self.dt > RESTART_GAP_S:
            self.history.clear()
            cov = np.zeros((len(z), 2, 2))
            cov[:, 0, 0], cov[:, 1, 1] = r2, FIRST_TURN_SD_RAD_S ** 2
            w = np.zeros((len(z), 3))
            self.history.append(_Entry(index, z / np.linalg.norm(z, axis=-1, keepdims=True), w, cov, z, w, cov, 0.0))
            return
        dt = (index - last.index) * self.dt
        cov_pred = _predicted_cov(last.cov, dt) + process_noise(self.spectral, dt)
        q, w, cov, q_pred = (np.empty_like(last.q), np.empty_like(last.w), np.empty_like(cov_pred),
                             np.empty_like(last.q))
        _kalman_step(last.q, last.w, cov_pred, z, r2, dt, GATE_CHI2, q_pred, q, w, cov)
        self.history.append(_Entry(index, q, w, cov, q_pred, last.w, cov_pred, dt))

    def estimate(self, index: int) -> np.ndarray:
        """``[R, 4]`` the rotations of frame ``index`` (one of those kept) given every frame added:
        the filtered state of the newest, smoothed back from it for an older one."""
        if self.history[-1].index == index:
            return self.history[-1].q.copy()
        entries = list(self.history)
        later = entries[next(i for i, e in enumerate(entries) if e.index == index):]
        q, w = np.empty_like(later[0].q), np.empty_like(later[0].w)
        _smooth_back(np.stack([e.q for e in later]), np.stack([e.w for e in later]), np.stack([e.cov for e in later]),
                     np.stack([e.q_pred for e in later]), np.stack([e.w_pred for e in later]),
                     np.stack([e.cov_pred for e in later]), np.array([e.dt_s for e in later]), q, w)
        return q


def _predicted_cov(cov: np.ndarray, dt_s: float) -> np.ndarray:
    """``F P Fᵀ`` with ``F = [[1, dt], [0, 1]]`` for each ``[2, 2]`` of ``cov [R, 2, 2]``."""
    f = np.array([[1.0, dt_s], [0.0, 1.0]])
    return f @ cov @ f.T


@njit(cache=True)
def _kalman_step(q0, w0, cov_pred, z, r2, dt, gate, q_pred, q, w, cov):  # pragma: no cover - numba
    """Predict each joint from ``q0 [R, 4]``, ``w0 [R, 3]`` over ``dt`` s (``cov_pred [R, 2, 2]``: the
    predicted covariance), update with ``z [R, 4]`` of noise ``r2 [R]`` (rad²): into ``q_pred``,
    ``q``, ``w`` and ``cov``."""
    step = np.empty(3)
    turn = np.empty(4)
    y = np.empty(3)
    for j in range(q0.shape[0]):
        for a in range(3):
            step[a] = w0[j, a] * dt
        quat_exp_into(step, turn)
        quat_mul_into(q0[j], turn, q_pred[j])
        quat_relative_log_into(q_pred[j], z[j], y)
        s = cov_pred[j, 0, 0] + r2[j]
        d2 = (y[0] * y[0] + y[1] * y[1] + y[2] * y[2]) / s
        if d2 > gate:
            s = cov_pred[j, 0, 0] + r2[j] * d2 / gate
        k0, k1 = cov_pred[j, 0, 0] / s, cov_pred[j, 1, 0] / s
        for a in range(3):
            step[a] = k0 * y[a]
            w[j, a] = w0[j, a] + k1 * y[a]
        quat_exp_into(step, turn)
        quat_mul_into(q_pred[j], turn, q[j])
        norm = np.sqrt(q[j, 0] ** 2 + q[j, 1] ** 2 + q[j, 2] ** 2 + q[j, 3] ** 2)
        for a in range(4):
            q[j, a] /= norm
        cov[j, 0, 0] = cov_pred[j, 0, 0] - k0 * k0 * s
        cov[j, 0, 1] = cov_pred[j, 0, 1] - k0 * k1 * s
        cov[j, 1, 0] = cov[j, 0, 1]
        cov[j, 1, 1] = cov_pred[j, 1, 1] - k1 * k1 * s


@njit(cache=True)
def _smooth_back(q_f, w_f, cov_f, q_pred, w_pred, cov_pred, dt, q_out, w_out):  # pragma: no cover - numba
    """Rauch–Tung–Striebel from the last of ``n`` frames back to the first: ``q_f [n, R, 4]``,
    ``w_f [n, R, 3]``, ``cov_f [n, R, 2, 2]`` filtered; ``q_pred``, ``w_pred``, ``cov_pred`` each frame's
    prediction from the one before, ``dt [n]`` its step (s). The first frame's smoothed rotations and
    angular velocities into ``q_out [R, 4]``, ``w_out [R, 3]``."""
    n, joints = q_f.shape[0], q_f.shape[1]
    dq = np.empty(3)
    step = np.empty(3)
    turn = np.empty(4)
    for j in range(joints):
        qs = q_f[n - 1, j].copy()
        ws = w_f[n - 1, j].copy()
        for k in range(n - 2, -1, -1):
            h = dt[k + 1]
            # C = P_f Fᵀ P_pred⁻¹ (2 × 2)
            a00 = cov_f[k, j, 0, 0] + h * cov_f[k, j, 0, 1]
            a01 = cov_f[k, j, 0, 1]
            a10 = cov_f[k, j, 1, 0] + h * cov_f[k, j, 1, 1]
            a11 = cov_f[k, j, 1, 1]
            p00, p01 = cov_pred[k + 1, j, 0, 0], cov_pred[k + 1, j, 0, 1]
            p10, p11 = cov_pred[k + 1, j, 1, 0], cov_pred[k + 1, j, 1, 1]
            det = p00 * p11 - p01 * p10
            c00, c01 = (a00 * p11 - a01 * p10) / det, (a01 * p00 - a00 * p01) / det
            c10, c11 = (a10 * p11 - a11 * p10) / det, (a11 * p00 - a10 * p01) / det
            quat_relative_log_into(q_pred[k + 1, j], qs, dq)
            for a in range(3):
                dw = ws[a] - w_pred[k + 1, j, a]
                step[a] = c00 * dq[a] + c01 * dw
                ws[a] = w_f[k, j, a] + c10 * dq[a] + c11 * dw
            quat_exp_into(step, turn)
            quat_mul_into(q_f[k, j], turn, qs)
        q_out[j] = qs
        w_out[j] = ws
