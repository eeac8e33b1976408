"""One track's memory in the engine: its last skeletons, its body (scale, own proportions, camera
tilt, floor scale), its filters, its recording, and whether its keypoints ever moved
(:class:`StillnessCheck`)."""
from __future__ import annotations

from collections import deque

import numpy as np
from numba import njit

from mocapdb.core.face_shapes import BlendSmoother
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.outputs import TrackRecording
from mocapdb.core.skeleton import (
    N_KEYPOINTS_2D,
    N_RIG_JOINTS,
    NODE_OFFSETS_M,
    UNIVERSAL_HEIGHT_M,
    body_offsets_m,
    pose_from_rotations,
    universal_bone_lengths_m,
)
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.filters import KeypointFilter, OneEuroFilter, QuaternionOneEuroFilter
from mocapdb.runtime.head_pose import NO_FACE_WORLD
from mocapdb.runtime.mesh_head import NO_HEAD_POINTS
from mocapdb.runtime.world.body_size import BoneLengths, CameraTilt, FloorScale
from mocapdb.runtime.world.detector_prior import MIN_VERTICAL_FRAMES, VERTICAL_WINDOW_S

# A person's heels, toes and knuckles when its layout has none: all missing
NO_EXTREMITIES = np.column_stack([np.full((len(EXTREMITIES), 2), np.nan), np.zeros(len(EXTREMITIES))])
NO_HANDS = np.full((2, 21, 3), np.nan, dtype=np.float32)   # a person's hands when none is seen (x, y, z px)


class TrackState:
    """Per-track memory: last reconstructed skeletons, filters, recording."""

    def __init__(self, track: int, frame: int, config: EngineConfig, window: int):
        self.history = np.zeros((window, N_RIG_JOINTS, 4))  # last reconstructed rotations, newest first
        self.n_history = 0
        self.scale = (config.subject_height_m or UNIVERSAL_HEIGHT_M) / UNIVERSAL_HEIGHT_M  # body size
        self.bones = BoneLengths() if config.refine and config.own_body else None  # own proportions
        self.proportions_m = universal_bone_lengths_m()  # bone lengths at 1.75 m stature
        self.offsets_m = NODE_OFFSETS_M                  # the rig's rest offsets for them
        self.tilt = CameraTilt()
        self.keypoints = KeypointFilter(config.keypoint_filter, N_KEYPOINTS_2D) if config.keypoint_filter else None
        self.stillness = StillnessCheck()
        self.max_fill = max(int(config.max_gap_s * config.fps), 0)
        self.floor = None
        if config.camera_height_m is not None and config.subject_height_m is None:
            self.floor = FloorScale(config.camera_height_m)
        rotation_params, root_params = config.one_euro_params()
        self.rotations = QuaternionOneEuroFilter(rotation_params)
        self.root = OneEuroFilter(root_params)
        self.blend_shapes = BlendSmoother()   # the face's blend shapes, fast attack (face_shapes)
        self.recording = TrackRecording(track, frame)
        self.last_frame = frame - 1
        self.world_joints: np.ndarray | None = None   # the detector's 3D (view frame) of the last frame with it
        self.world_frame = -2                         # … and that frame
        # the body's vertical in the detector's 3D over the last frames (view frame): the stream's up
        self.verticals: deque[np.ndarray] = deque(maxlen=max(int(VERTICAL_WINDOW_S * config.fps), 1))

    @property
    def up(self) -> np.ndarray:
        """The world's up in the view frame as this track shows it now: the median of the body's
        recent verticals in the detector's 3D (:func:`~mocapdb.runtime.world.detector_prior.balance_verticals`)
        once there are :data:`~mocapdb.runtime.world.detector_prior.MIN_VERTICAL_FRAMES`, else the fit's tilt
        estimate."""
        if len(self.verticals) < MIN_VERTICAL_FRAMES:
            return self.tilt.up
        median = np.median(np.array(self.verticals), axis=0)
        return median / np.linalg.norm(median)

    def remember(self, quats: np.ndarray) -> None:
        """Push this frame's (unsmoothed) rotations onto the history window."""
        self.history[1:] = self.history[:-1]
        self.history[0] = quats
        self.n_history = min(self.n_history + 1, len(self.history))

    def previous(self, frame: int) -> np.ndarray | None:
        """The last reconstructed rotations if they belong to the frame just before ``frame``."""
        return self.history[0] if self.n_history and self.last_frame == frame - 1 else None

    def record(self, frame: int, t_s: float, quats: np.ndarray, root_view: np.ndarray,
               fit: tuple[np.ndarray, ...] | None = None) -> None:
        """Append this frame, holding the last pose over any frames the track missed; ``fit``: the
        unfiltered rotations and root, the keypoints ``[14, 3]``, the heels, toes and knuckles
        ``[8, 3]`` (x, y px, confidence) and the world bones the fit used ``[B, 4]`` (direction,
        weight; :data:`~mocapdb.runtime.world.detector_prior.FIT_BONES`) and the face's world landmarks ``[11, 3]``
        (:func:`~mocapdb.runtime.head_pose.face_world`), the hands' points ``[2, 21, 3]`` (x, y, z px,
        float32; NaN: absent) and the face mesh's head vertices ``[N_HEAD, 3]`` (x, y, z px, float32; NaN:
        absent; :func:`~mocapdb.runtime.mesh_head.head_vertices`), kept for the whole-take fit (missed
        frames get the last fit and no keypoint, world landmark, hand nor mesh)."""
        rec = self.recording
        if not len(rec):
            rec.first_frame, rec.first_s = frame, t_s
        rec.last_s = t_s
        for _ in range(min(frame - self.last_frame - 1, self.max_fill) if len(rec) else 0):
            held = rec.frames.last()
            if "keypoints" in held:
                held.update(keypoints=np.zeros_like(held["keypoints"]), extremities=NO_EXTREMITIES,
                            world_bones=np.zeros_like(held["world_bones"]), face_world_m=NO_FACE_WORLD,
                            hands_px=NO_HANDS, mesh_px=NO_HEAD_POINTS)
            rec.frames.append(**held)
        row: dict[str, np.ndarray | float] = dict(quaternions=quats, root_view_m=root_view, scales=self.scale)
        if fit is not None:
            row.update(fit_quaternions=fit[0], fit_root_view_m=fit[1], keypoints=fit[2], extremities=fit[3],
                       world_bones=fit[4], face_world_m=fit[5],
                       hands_px=fit[6], mesh_px=fit[7])
            rec.up_view, rec.up_sd_deg = self.tilt.up, self.tilt.sd_deg
        rec.frames.append(**row)
        rec.proportions_m = self.proportions_m
        self.last_frame = frame

    def measure_bones(self, points_px: np.ndarray, confidence: np.ndarray, retrieved: np.ndarray,
                      root_view: np.ndarray, focal_px: float) -> None:
        """Add one frame to the bone estimate: the retrieved rotations ``[R, 4]`` at the fitted root."""
        if self.bones is None:
            return
        pose = pose_from_rotations(retrieved, root_view, self.scale, self.offsets_m)[0]
        if self.bones.add(points_px, confidence, pose, focal_px, self.scale):
            self.proportions_m = self.bones.proportions_m
            self.offsets_m = body_offsets_m(self.proportions_m)


STATIC_RANGE = 0.05  # a track is static if no keypoint ever moved more than this × its box height
STATIC_MIN_S = 1.0   # … over at least this long


class StillnessCheck:
    """Whether a track's input keypoints ever moved: per joint, the range of positions seen.

    A detection that never moves nor changes shape (a poster, a statue, a false positive at the
    image edge) is static when, after :data:`STATIC_MIN_S`, no joint's range of positions exceeds
    :data:`STATIC_RANGE` of its first box height. (Measured on the bundled Pose2Sim sample: the
    false detection at the image edge 3.8 %, the balancing person 133 %.)
    """

    def __init__(self) -> None:
        self.lo = np.full((N_KEYPOINTS_2D, 2), np.inf)
        self.hi = np.full((N_KEYPOINTS_2D, 2), -np.inf)
        self.box_px = 0.0
        self.first_s: float | None = None
        self.last_s = 0.0

    def add(self, points_px: np.ndarray, visible: np.ndarray, t_s: float) -> None:
        if self.first_s is None:
            self.first_s = t_s
            self.box_px = float(np.ptp(points_px[visible, 1]))
        self.last_s = t_s
        _widen_range(self.lo, self.hi, points_px, visible)

    @property
    def static(self) -> bool:
        if self.first_s is None or self.last_s - self.first_s < STATIC_MIN_S:
            return False
        seen = np.isfinite(self.lo[:, 0])
        moved = np.linalg.norm(self.hi[seen] - self.lo[seen], axis=-1).max()
        return bool(moved <= STATIC_RANGE * max(self.box_px, 1.0))


@njit(cache=True)
def _widen_range(lo, hi, points, visible) -> None:
    """Per visible keypoint, stretch ``[lo, hi]`` (per axis) to include ``points``."""
    for k in range(points.shape[0]):
        if visible[k]:
            for a in range(2):
                lo[k, a] = min(lo[k, a], points[k, a])
                hi[k, a] = max(hi[k, a], points[k, a])
