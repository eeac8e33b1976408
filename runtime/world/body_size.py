"""A person's body: its size from the floor (a camera at a known height) and its own bone proportions
(:class:`BoneLengths`).

One camera cannot tell a small person near it from a tall one further away: the image fixes
the body only up to a scale ``k`` about the camera centre. A flat floor at a known distance
below the camera (``--camera-height``) fixes it: the lowest ankle of a standing or walking
person sits :data:`~mocapdb.core.skeleton.ANKLE_HEIGHT_M` (times the body scale) above the floor.

The floor's normal in the view frame is the world's up seen by the camera (:class:`CameraTilt`).
Per frame, with ``u`` that normal and ``a`` the lower ankle (view frame, metres, body scale ``s``)::

    k (u·a) + H = ANKLE_HEIGHT_M · s · k    ⇒    k = H / (ANKLE_HEIGHT_M · s − u·a)

and ``s·k`` is that frame's estimate of the body scale. The track's scale is the median of its
estimates so far (jumps and frames with both feet off the floor are a minority), weighed against
the people's heights by how far the camera's tilt error can move it (:class:`FloorScale`), and
clipped to bodies 0.5–2.5 m tall. Assumes a level floor, at least one foot on it most of the time, and a
camera roll/pitch that does not change during the track.

One body (:class:`BoneLengths`) serves the 2D fit and the files: their rotations are the fit's, and
only the fit's skeleton gives back the joints the stream sent. It takes what the keypoints
consistently measure, which is the input's convention whether anatomy agrees or not (mocap hip-joint
centres 0.09–0.10 m apart, against the universal skeleton's 0.20 m).
The exception is a bone of the stature chain (thigh, shank, torso, neck→nose): the proportions are
rescaled to the assumed stature through that chain, so an implausible one there would resize every
other bone; such a bone is not believed (a head-top keypoint; ``data_specs/stream_output.md``).
"""
from __future__ import annotations

from collections import deque

import numpy as np
from numba import njit

from mocapdb.core.anthropometry import PROPORTION_COVARIANCE, STATURE_SD
from mocapdb.core.kernels import quat_mul_into
from mocapdb.core.skeleton import (
    ANKLE_HEIGHT_M,
    KP,
    MEASURED_BONE_NAMES,
    MEASURED_BONES,
    UNIVERSAL_HEIGHT_M,
    stature_m,
    universal_bone_lengths_m,
)

MIN_SAMPLES = 6        # frames before the floor's estimate replaces the starting scale
WINDOW = 240           # the median runs over the last this many frames
SCALE_RANGE = (0.5 / UNIVERSAL_HEIGHT_M, 2.5 / UNIVERSAL_HEIGHT_M)
_ANKLES = (KP["r_ankle"], KP["l_ankle"])
R_HIP, L_HIP = KP["r_hip"], KP["l_hip"]
TILT_SD_DEG = 3.0  # the least error of CameraTilt's estimate (rendered walks; pitch and roll, degrees)


class CameraTilt:
    """One track's estimate of the world's up direction in the view frame (the camera's pitch and roll).

    The database poses are upright (only turned about the vertical), so the rotation the
    refinement adds to a retrieved root is, on average, the camera's tilt: each frame gives the
    retrieved root's up axis carried by that rotation, and their mean is the estimate. The next
    frames' retrieved roots are tilted by it before the fit, so its prior stops pulling upright.
    """

    def __init__(self) -> None:
        self.up_sum = np.zeros(3)
        self.count = 0
        self._scratch = np.empty((3, 4))

    @property
    def up(self) -> np.ndarray:
        """Unit world up in the view frame (``[0, 1, 0]`` before any frame)."""
        norm = np.linalg.norm(self.up_sum)
        return self.up_sum / norm if norm > 0 else np.array([0.0, 1.0, 0.0])

    @property
    def roll_rad(self) -> float:
        """The camera's roll this estimate gives (radians; positive when the world's up leans to the
        image's left, as :attr:`~mocapdb.runtime.world.fuse.World.roll_deg`), shrunk towards 0 by the least
        error of the estimate (:data:`TILT_SD_DEG`): a roll within it is taken as none (shrinking by the
        frames' spread, :attr:`sd_deg`, gave back most of the gain on the real take)."""
        up = self.up
        roll = float(np.arctan2(-up[0], up[1]))
        return float(np.sign(roll) * max(abs(roll) - np.radians(TILT_SD_DEG), 0.0))

    def seed(self, up: np.ndarray, frames: int) -> None:
        """Start from ``up`` (view frame, unit) as ``frames`` frames' worth of observations."""
        self.up_sum[:] = frames * np.asarray(up, dtype=np.float64)
        self.count = frames

    def tilt_root(self, root_upright: np.ndarray, out: np.ndarray) -> None:
        """``out`` = the upright root quaternion turned by the estimated tilt (view frame)."""
        _tilt_into(self.up_sum, root_upright, self._scratch[0], out)

    def update(self, root_refined: np.ndarray, root_upright: np.ndarray) -> None:
        """Add one frame: root quaternions (view frame) after the fit and as retrieved (untilted)."""
        _add_up_observation(root_refined, root_upright, self._scratch, self.up_sum)
        self.count += 1

    @property
    def sd_deg(self) -> float:
        """The estimate's error (degrees): :data:`TILT_SD_DEG`, or the frames' angular spread about
        their mean (RMS) when larger. A pose the database does not hold (a jump, a balance) leans
        the fitted root; its frames then disagree, and their mean is off by about as much (rendered
        jumps: spread 14°, error 13°; walks: 3-6°, 1-7°)."""
        if self.count < 2:
            return TILT_SD_DEG
        mean_length = min(float(np.linalg.norm(self.up_sum)) / self.count, 1.0)  # 1 − mean length ≈ mean(θ²)/2
        return max(TILT_SD_DEG, float(np.degrees(np.sqrt(2.0 * (1.0 - mean_length)))))


@njit(cache=True)
def _tilt_into(up_sum, root, tilt, out):
    """``out = t ⊗ root``, ``t`` the smallest rotation taking y to ``up_sum`` (identity if zero)."""
    norm = np.sqrt(up_sum[0] ** 2 + up_sum[1] ** 2 + up_sum[2] ** 2)
    if norm == 0.0:
        out[:] = root
        return
    ux, uy, uz = up_sum[0] / norm, up_sum[1] / norm, up_sum[2] / norm
    half = np.sqrt((1.0 + uy) ** 2 + uz * uz + ux * ux)  # (1 + y·u, y × u), normalised
    tilt[0], tilt[1], tilt[2], tilt[3] = (1.0 + uy) / half, uz / half, 0.0, -ux / half
    quat_mul_into(tilt, root, out)


@njit(cache=True)
def _add_up_observation(refined, upright, scratch, up_sum):
    """``up_sum += R(refined) R(upright)ᵀ y``: the upright root's up axis carried by the fit."""
    conj = scratch[0]
    conj[0], conj[1], conj[2], conj[3] = upright[0], -upright[1], -upright[2], -upright[3]
    quat_mul_into(refined, conj, scratch[1])
    w, x, y, z = scratch[1]
    up_sum[0] += 2 * (x * y - w * z)
    up_sum[1] += 1 - 2 * (x * x + z * z)
    up_sum[2] += 2 * (y * z + w * x)


class FloorScale:
    """Running estimate of one track's body scale from its feet (see the module docstring), with
    the people's heights as a prior.

    A frame's estimate is only as good as the camera's tilt: an error δ moves the floor under a
    person ``Z`` metres away by ``δ Z``, a share ``δ Z / C`` of the camera height ``C``. The track's
    estimate (the median of its frames) is therefore combined in log space with the stature prior
    (:data:`~mocapdb.core.anthropometry.STATURE_SD` about 1.75 m), its own SD taken as the tilt's
    (:attr:`CameraTilt.sd_deg`) × the median ``Z / C`` of its frames.
    """

    def __init__(self, camera_height_m: float):
        if not 0.1 <= camera_height_m <= 50.0:
            raise ValueError(f"camera height must be between 0.1 and 50 m, not {camera_height_m}")
        self.camera_height_m = camera_height_m
        self.samples: deque[float] = deque(maxlen=WINDOW)
        self.leverage: deque[float] = deque(maxlen=WINDOW)  # depth over the floor's distance

    def update(self, up: np.ndarray, joints_view_m: np.ndarray, scale: float, tilt_sd_deg: float = TILT_SD_DEG
               ) -> float:
        """Add one frame; returns the track's scale (``scale`` until enough frames were seen).

        ``up``: the world's up in the view frame and ``tilt_sd_deg`` its error (:class:`CameraTilt`);
        ``joints_view_m [15, 3]``: the refined keypoints at body scale ``scale``.
        """
        lower = min(_ANKLES, key=lambda k: float(up @ joints_view_m[k]))
        denominator = ANKLE_HEIGHT_M * scale - float(up @ joints_view_m[lower])
        if denominator > 0.1:
            self.samples.append(scale * self.camera_height_m / denominator)
            self.leverage.append(-float(joints_view_m[lower, 2]) / denominator)
        if len(self.samples) < MIN_SAMPLES:
            return scale
        floor_sd = np.radians(tilt_sd_deg) * float(np.median(self.leverage))
        weight = STATURE_SD ** 2 / (STATURE_SD ** 2 + floor_sd ** 2)  # of the floor's estimate against the prior
        return float(np.clip(np.exp(weight * np.log(np.median(self.samples))), *SCALE_RANGE))


# 2D samples of each measured bone: (keypoint a, keypoint b, bone) over the 15 keypoints (the pelvis
# is the midpoint of the hips, seen when both are).
_SAMPLE_PAIRS = [(KP[a], KP[b], i) for i, pairs in enumerate(MEASURED_BONES.values()) for a, b in pairs]
_PAIR_A = np.array([a for a, _, _ in _SAMPLE_PAIRS])
_PAIR_B = np.array([b for _, b, _ in _SAMPLE_PAIRS])
_PAIR_BONE = np.array([i for _, _, i in _SAMPLE_PAIRS])
_UNIVERSAL_BONES = universal_bone_lengths_m()
_PRIOR_PRECISION = np.linalg.inv(PROPORTION_COVARIANCE)


class BoneLengths:
    """One track's own bone proportions, from its 2D keypoints over the take (causal, running).

    A bone seen nearly parallel to the image plane shows its length: where the retrieved pose (the
    database's 3D, independent of the bones being fitted; placed at the fitted root) puts a bone's
    direction within :data:`IN_PLANE` of the image plane (``c`` = the share of its unit direction
    across the viewing ray), the sample is ``L = |x_b − x_a| · Z / (f · c)`` (pixels, the bone's
    depth ``Z``, metres), in the track's body scale. Per bone the log of L over the universal bone is kept
    (the last :data:`CAPACITY` samples); the estimate combines each bone's median with the
    anthropometric prior (:mod:`mocapdb.core.anthropometry`, correlated bones) as a Gaussian in log
    space, each median weighted as ``min(n, CAPACITY) / DECORRELATION`` independent samples of SD
    :data:`SAMPLE_SD`, and is rescaled to 1.75 m stature: the body's size stays what the track
    assumes (a given height, the floor, or 1.75 m); only its proportions are measured.

    A median of the stature chain (:data:`SIZE_BONES`) is judged as a proportion first
    (:func:`believed_bones`): one further from the prior's than its people's, joint conventions' and
    own spread allow (a head keypoint on top of the head: neck→nose 1.6×) is not believed and gets
    no weight, so the prior's value stands for that bone and it does not shrink the rest through the
    stature. Other bones are always believed (module docstring, "One body").
    """

    IN_PLANE = 0.9
    CAPACITY = 600
    DECORRELATION = 4.0   # consecutive frames are far from independent
    SAMPLE_SD = 0.10      # one sample's error in log length (detector noise, retrieval direction)
    UPDATE_EVERY = 8      # frames between estimates while the body settles (the first SETTLING_FRAMES) …
    SETTLING_FRAMES = 48
    UPDATE_EVERY_SETTLED = 24  # … and after

    def __init__(self) -> None:
        self.samples = np.zeros((len(MEASURED_BONE_NAMES), self.CAPACITY))
        self.counts = np.zeros(len(MEASURED_BONE_NAMES), dtype=np.int64)
        self.proportions_m = _UNIVERSAL_BONES.copy()  # the estimate, at 1.75 m stature
        self._frames = 0

    def add(self, points_px: np.ndarray, confidence: np.ndarray, retrieved_view_m: np.ndarray,
            focal_px: float, scale: float) -> bool:
        """Add one frame; returns whether the estimate changed. ``points_px [14, 2]``, ``confidence
        [14]`` (0: unseen), the retrieved pose's keypoints at the fitted root ``[15, 3]`` (view frame)."""
        _add_samples(points_px, confidence, retrieved_view_m, float(focal_px), float(scale),
                     self.IN_PLANE, _PAIR_A, _PAIR_B, _PAIR_BONE, _UNIVERSAL_BONES, self.samples, self.counts)
        self._frames += 1
        every = self.UPDATE_EVERY if self._frames <= self.SETTLING_FRAMES else self.UPDATE_EVERY_SETTLED
        if self._frames % every:
            return False
        self.proportions_m = self.estimate()
        return True

    def estimate(self) -> np.ndarray:
        """Bone lengths ``[8]`` (metres at 1.75 m stature) from the samples so far and the prior:
        the believed medians (:func:`believed_bones`) weighed against the prior."""
        n = np.minimum(self.counts, self.CAPACITY)
        medians = _medians(self.samples, n)
        precision = n / self.DECORRELATION / self.SAMPLE_SD ** 2
        weight = np.diag(np.where(believed_bones(medians, precision), precision, 0.0))
        log_factor = np.linalg.solve(_PRIOR_PRECISION + weight, weight @ medians)
        lengths = _UNIVERSAL_BONES * np.exp(log_factor)
        return lengths * (UNIVERSAL_HEIGHT_M / stature_m(lengths))


PLAUSIBLE_SD = 3.0    # a bone's proportion further from the prior's than this many SDs is not believed
CONVENTION_SD = 0.10  # log length: where skeletons and detectors put a joint (CMU's shank: +0.20 at one stature)
MIN_OTHERS = 3        # measured other bones needed to judge a bone's proportion
# The bones judged: the stature chain, through which a bone sets every other bone's size. Widths and
# arm bones set no other bone's length; whatever they measure is the input's convention.
SIZE_BONES = stature_m(np.eye(len(MEASURED_BONE_NAMES))) > 0


def believed_bones(medians: np.ndarray, precision: np.ndarray) -> np.ndarray:
    """Per bone ``[8]``, whether its median log factor (``medians``, weight ``precision``: 0 when
    unmeasured) is believed: measured, and, for :data:`SIZE_BONES`, its proportion (the median minus
    the body's common size, the median of the other measured bones' medians) within
    :data:`PLAUSIBLE_SD` SDs of the prior's. The SD is that of the bone minus the others' mean when
    each bone varies as people do (``PROPORTION_COVARIANCE``), by joint conventions
    (:data:`CONVENTION_SD`) and by its median's error (``1 / precision``). Bones with fewer than
    :data:`MIN_OTHERS` measured others are believed."""
    measured = precision > 0
    others = measured[None, :] & ~np.eye(len(medians), dtype=bool)
    judged = measured & SIZE_BONES & (others.sum(axis=1) >= MIN_OTHERS)
    believed = measured.copy()
    if not judged.any():
        return believed
    rows = others[judged]
    k, row = rows.sum(axis=1), np.arange(len(rows))
    ordered = np.sort(np.where(rows, medians, np.inf), axis=1)  # the others' medians first, in order
    common = 0.5 * (ordered[row, (k - 1) // 2] + ordered[row, k // 2])
    contrast = np.eye(len(medians))[judged] - rows / k[:, None]  # the bone minus the others' mean
    noise = 1.0 / np.where(measured, precision, np.inf)
    spread = PROPORTION_COVARIANCE + np.diag(noise + CONVENTION_SD ** 2)
    sd = np.sqrt(np.einsum("ij,jk,ik->i", contrast, spread, contrast))
    believed[judged] = np.abs(medians[judged] - common) <= PLAUSIBLE_SD * sd
    return believed


@njit(cache=True)
def _add_samples(points_px, confidence, retrieved, focal_px, scale, in_plane, pair_a, pair_b, pair_bone,
                 universal, samples, counts) -> None:
    """One frame's bone-length samples into ``samples [8, CAPACITY]`` (ring buffers, ``counts``):
    see :class:`BoneLengths`. Keypoint index 14 (the pelvis) is the hips' midpoint in 2D."""
    capacity = samples.shape[1]
    for i in range(pair_a.shape[0]):
        a, b = pair_a[i], pair_b[i]
        xa, ya, ca = _keypoint_2d(points_px, confidence, a)
        xb, yb, cb = _keypoint_2d(points_px, confidence, b)
        if ca <= 0.0 or cb <= 0.0:
            continue
        d = retrieved[b] - retrieved[a]
        d_norm = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        mid = (retrieved[a] + retrieved[b]) / 2.0
        mid_norm = np.sqrt(mid[0] * mid[0] + mid[1] * mid[1] + mid[2] * mid[2])
        depth = -mid[2]
        if d_norm < 1e-9 or mid_norm < 1e-9 or depth <= 0.1:
            continue
        along = (d[0] * mid[0] + d[1] * mid[1] + d[2] * mid[2]) / (d_norm * mid_norm)
        across = np.sqrt(max(1.0 - along * along, 0.0))
        if across < in_plane:
            continue
        length = np.sqrt((xb - xa) ** 2 + (yb - ya) ** 2) * depth / (focal_px * across)
        if length <= 0.0:
            continue
        bone = pair_bone[i]
        samples[bone, counts[bone] % capacity] = np.log(length / (scale * universal[bone]))
        counts[bone] += 1


@njit(cache=True)
def _keypoint_2d(points_px, confidence, k):
    """Pixel x, y and confidence of keypoint ``k`` (14: the hips' midpoint, seen if both are)."""
    if k < points_px.shape[0]:
        return points_px[k, 0], points_px[k, 1], confidence[k]
    c = min(confidence[R_HIP], confidence[L_HIP])
    return (points_px[R_HIP, 0] + points_px[L_HIP, 0]) / 2.0, (points_px[R_HIP, 1] + points_px[L_HIP, 1]) / 2.0, c


@njit(cache=True)
def _medians(samples, n):
    """Per row of ``samples [B, C]``, the median of its first ``n[b]`` values (0 when none)."""
    out = np.zeros(samples.shape[0])
    for b in range(samples.shape[0]):
        if n[b] > 0:
            out[b] = np.median(samples[b, :n[b]])
    return out
