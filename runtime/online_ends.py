"""The online take's end joints: the humanoid rig's feet, hands and head
(:data:`~mocapdb.core.skeleton.END_JOINTS`) turned per frame of the stream, as the whole take turns
them in the track files (:func:`mocapdb.runtime.take.end_rotations`, :func:`~mocapdb.runtime.take.head_rotation`).

Per track (:class:`OnlineEnds`), per frame:

1. **Measured** on the frame's per-frame pose as the whole take measures them: the feet's heel → big toe
   and the hands' wrist → mid-knuckles directions (:func:`~mocapdb.runtime.end_joints.measured_candidates`,
   each one's depth the end of the cheapest path so far: :class:`~mocapdb.runtime.end_branches.BranchPath`),
   the head's rotation relative to the chest (:func:`~mocapdb.runtime.head_pose.chest_relative_head`; with
   the detector's world landmarks of the face as its prior where the frame has them, but the default face
   model: the whole take's own face pattern is a median over the take's frames; fitted to the face mesh
   where ``mesh_px`` gives one, with the person's face from the track's first meshes:
   :class:`~mocapdb.runtime.mesh_head.MeshModel`), kept as a global rotation (the per-frame chest's times
   it) and taken against the output's chest after smoothing. Where the hand landmark
   model saw a hand (``hands_px``), its palm (:func:`~mocapdb.runtime.hand_pose.palm_frames`) gives the
   hand's direction and, by its thumb side, the palm's twist about it
   (:func:`~mocapdb.runtime.hand_pose.hand_twist_deg`), as in the whole take; the thumb side is smoothed
   with the directions (from the rest palm's before it is seen), the twist eased in and out as an end joint.
2. **Smoothed**: lag 0, a causal 1€ filter (the online take's ``causal_rotations``, the head on frames the mesh
   fixed :data:`MESH_HEAD_FILTER`, a hand the hand model saw :data:`HAND_MODEL_FILTER`; the directions as
   vectors, the head as a quaternion; the rig's own rotations have a Kalman filter instead,
   :mod:`mocapdb.runtime.rotation_kalman`), a foot not planted whose measured direction is steady the
   constant-angular-velocity Kalman filter (:class:`DirectionKalman`: it predicts instead of delaying), blended
   in by the foot's steadiness (:class:`SteadyFeet`); lag ``L``, the Gaussian mean of the frames ``t − L … t + L``
   measured. A planted foot is laid flat on the floor, blended in
   with its IK weight, and once it has stood :data:`PLANTED_SETTLE_S` keeps its heading (the mean since,
   followed at most :data:`PLANTED_FOLLOW_DEG_S`): its ankle is held in place, so is the ball of the foot.
   Every foot is rolled about its direction until its lateral axis lies level on the floor
   (:func:`~mocapdb.runtime.end_joints.levelled_feet`), as in the whole take.
3. **Unseen**: an end joint keeps its last value for :data:`HOLD_S`, then eases to rest (the identity,
   where the rig puts it unturned) over :data:`EASE_S` (smoothstep); seen again, or seen first, it eases
   in from there over :data:`EASE_S`. Every frame says which end joints were measured (``end_seen``). The
   mesh's share of the head (every component carried, else ``head_pose.HEAD_GAINS``) eases alike
   (``mesh_head.HOLD_S``, ``EASE_S``), from the track's first frame without easing.
4. **Speed limits**: no end joint's local rotation turns faster than :data:`END_SPEED_DEG_S`.

Cost: one face fit and a few forward kinematics of one frame per person and frame.
"""
from __future__ import annotations

from collections import deque
from typing import NamedTuple

import numpy as np

from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.geometry import matrix_to_quat, quat_conj, quat_mul, quat_to_matrix, quat_turned_towards, slerp
from mocapdb.core.outputs import CAMERA_FROM_VIEW, PersonPose
from mocapdb.core.skeleton import (
    END_JOINTS,
    RIG_JOINTS,
    UNIVERSAL_HEIGHT_M,
    body_offsets_m,
    global_rotations,
    swing_matrices,
)
from mocapdb.runtime.end_branches import BranchPath
from mocapdb.runtime.end_joints import (
    end_frames,
    end_locals,
    knuckle_thumb_sides,
    levelled_feet,
    measured_candidates,
    sign_references,
    standing_directions,
    wrist_depths_m,
)
from mocapdb.runtime.filters import OneEuroFilter, OneEuroParams, QuaternionOneEuroFilter
from mocapdb.runtime.foot_contacts import HEELS, TOES
from mocapdb.runtime.hand_pose import (
    HAND_BASES,
    hand_points_view,
    hand_twist_deg,
    palm_frames,
    shortest_turn_axes,
    smoothstep,
    steadiness,
    twisted,
)
from mocapdb.runtime.head_pose import chest_relative_head, face_points, head_local
from mocapdb.runtime.mesh_head import EASE_S as MESH_EASE_S
from mocapdb.runtime.mesh_head import HOLD_S as MESH_HOLD_S
from mocapdb.runtime.mesh_head import MeshModel, mesh_observations
from mocapdb.runtime.rotation_kalman import ACCEL_FRAME_S, MIN_CONFIDENCE, RotationKalman, RotationNoise

HOLD_S = 0.5   # an end joint unseen this long keeps its last value (the whole take interpolates such gaps)
EASE_S = 0.3   # then it turns to rest over this long; seen (again), it turns from there to its measure as long
STEADY_WINDOW_S = 1.0   # a hand's twist from the knuckles, a foot's filter, chosen by its scatter over its last
                        # measures this long (hand_pose.steadiness)
# The fastest each end joint's local rotation may turn (degrees per second; END_JOINTS order), as the rig
# joint it hangs from (online_take.JOINT_SPEED_DEG_S): feet the knees', hands the elbows', the head the neck's
END_SPEED_DEG_S = np.array([2000.0, 2000.0, 2300.0, 2300.0, 900.0])
# A planted foot's heading follows its measure at most this fast (degrees per second): about the online
# take's anchor following of 2 cm/s at the ball of the foot, 14 cm ahead of the ankle
PLANTED_FOLLOW_DEG_S = 8.0
# ... once it has stood this long (seconds), the mean since then; before, the measure as it comes (the first
# frames still carry the smoothing's transient: held from the first, a foot misread as it landed stayed
# misread for seconds)
PLANTED_SETTLE_S = 0.5
# The head's causal filter on frames the face mesh fixed (else the end joints' ``causal``): the mesh's head
# is measured within about a degree, so it is smoothed lightly. Chosen on the gate's clips and bodies with
# the mesh rendered (tools/eval_ends.py --face-mesh; the only head truth here): cut-off / beta 0.5 / 0.3 →
# 2.0 / 2.0 took the stream's head where the mesh is seen from 3.9° to 1.5° (exact) and 4.3° to 1.7° (noisy),
# its acceleration from 0.5 to 0.7 and 1.5 to 2.1 deg/frame² (the truth's 1.0; unfiltered 1.1 and 3.5;
# tools/eval_end_filter.py --end head)
MESH_HEAD_FILTER = OneEuroParams(min_cutoff_hz=2.0, beta=2.0)
# The hands' directions and thumb sides where the hand landmark model saw the hand (else ``causal``), chosen
# alike with the hands' 21 points rendered (tools/eval_end_filter.py --end hands --hand-points 21): 0.5 / 0.3
# → 1.5 / 1.0 took the stream's hands from 13.1° to 7.0° (exact) and 15.1° to 10.8° (noisy), their
# acceleration from 2.9 to 3.3 and 9.6 to 16.7 deg/frame² (the truth's 3.3; unfiltered 3.8° and 12.1°)
HAND_MODEL_FILTER = OneEuroParams(min_cutoff_hz=1.5, beta=1.0)
# A foot's direction (heel → big toe) at lag 0 where it is steady and the foot not planted: the
# constant-angular-velocity Kalman filter (DirectionKalman), its white angular acceleration the feet's RMS per
# tangent axis in real motion (rad/s²: their global rotations in the 61 CMU clips of ../shared/data/cmu_bvh at
# 24 fps, left and right pooled), the measure's SD at confidence 1 FOOT_FIT_SD_DEG (degrees) ...
FOOT_ACCEL_RAD_S2 = 48.2
FOOT_FIT_SD_DEG = 5.0
# ... all of it where the direction scatters this much a frame or less (degrees; hand_pose.steadiness of the
# unit direction's components in degrees), the 1€ filter's from UNSTEADY_FOOT_DEG, linearly between; the share
# moves at most 1 per EASE_S. Chosen on the database's own clips (002_02, 002_07, 006_10; replayed streams as
# tools/eval_end_filter.py --end feet, 3 yaws; exact / noisy 2D, median geodesic): the 1€ alone 9.87° / 12.02°,
# the Kalman alone 8.53° / 14.44°; thresholds 2/4 … 8/16° all 8.52–8.55° / 12.01–12.05° (12/20: 12.24° noisy);
# the fit's SD 2.5 / 5 / 10 / 20° 8.04 / 8.17 / 8.53 / 9.14° exact. A planted foot keeps the 1€'s (it held
# the Kalman's landing turn: the real take's planted balls slid 6.8 → 10.4 cm/s at lag 0; 6.7 so, the database
# clips' exact 8.17 → 8.78°)
STEADY_FOOT_DEG, UNSTEADY_FOOT_DEG = 4.0, 8.0
_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
_N_ENDS = len(END_JOINTS)
_SPINE, _NECK = RIG_JOINTS.index("spine"), RIG_JOINTS.index("neck")
# the feet's and hands' directions and the palms' thumb sides [6, 3], the head [4]; NaN: unseen
Measure = tuple[np.ndarray, np.ndarray]


class Sources(NamedTuple):
    """What gave a frame's measure besides the pose: whether the face mesh fixed the head, which hands' thumb
    sides the hand model gave ``[2]``, the twist ``[2]`` (degrees) of those the pose's knuckles gave (NaN:
    none), whose scatter says how much of it to keep (:func:`~mocapdb.runtime.hand_pose.steadiness`), and the
    feet's confidence ``[2]`` (:func:`foot_confidence`)."""

    from_mesh: bool
    by_hand_model: np.ndarray
    knuckle_twist_deg: np.ndarray
    feet_confidence: np.ndarray


NO_SOURCES = Sources(False, np.zeros(2, bool), np.full(2, np.nan), np.ones(2))


def measure(pose: PersonPose, camera_px: tuple[float, float, float], branches: BranchPath, time_s: float,
            face: MeshModel) -> tuple[Measure, Sources]:
    """The feet's and hands' directions and the palms' thumb sides ``[6, 3]`` (view frame, unit; each foot's and
    hand's depth the end of the track's cheapest path so far, ``branches``, to which this frame at ``time_s`` is
    added; a hand's the palm's where the hand model saw it, else its thumb side the pose's knuckles':
    :func:`~mocapdb.runtime.end_joints.knuckle_thumb_sides`) and the head's global rotation ``[4]`` (view frame:
    the per-frame chest's times the head's relative to it, so a mesh's head carries none of the chest's noise)
    of one per-frame ``pose``, seen by the pinhole ``camera_px`` (focal, cx, cy: pixels); NaN where its
    keypoints do not give them; and their :class:`Sources` (the person's ``face``, to which the frame's mesh is
    added)."""
    unseen = np.full((6, 3), np.nan), np.full(4, np.nan)
    keypoints, extremities = pose.keypoints_px, pose.extremities_px
    if keypoints is None or extremities is None or len(extremities) < len(EXTREMITIES):
        return unseen, NO_SOURCES
    scale = pose.height_m / UNIVERSAL_HEIGHT_M
    offsets = None if pose.bones_m is None else body_offsets_m(pose.bones_m / scale)
    quats, root = pose.quaternions[None], (pose.root_m * CAMERA_FROM_VIEW)[None]
    candidates = measured_candidates(quats, root, scale, offsets, keypoints[None], extremities[None], camera_px)
    directions = branches.step(time_s, candidates[0], sign_references(quats)[0])[0]
    palms = np.full((2, 3, 3), np.nan) if pose.hands_px is None else palm_frames(hand_points_view(
        np.asarray(pose.hands_px, dtype=np.float64)))
    by_hand_model = np.isfinite(palms[:, 1]).all(axis=-1)
    directions[2:] = np.where(np.isfinite(palms[:, 0]), palms[:, 0], directions[2:])
    thumb_sides, knuckle_twist = _knuckles(quats, root, scale, offsets, directions[2:], extremities, camera_px)
    thumb_sides = np.where(by_hand_model[:, None], palms[:, 1], thumb_sides)
    directions = np.vstack([directions, thumb_sides])
    face_world_m = None if pose.face_world_m is None else pose.face_world_m[None]
    if pose.mesh_px is not None:
        face.add(pose.mesh_px)
    model = face.model(scale)
    mesh = None if model is None or pose.mesh_px is None else (mesh_observations(pose.mesh_px[None]), model)
    head, from_mesh = chest_relative_head(quats, root, scale, offsets, face_points(keypoints[None], extremities[None]),
                                          camera_px, face_world_m, mesh)
    return ((directions, quat_mul(matrix_to_quat(global_rotations(quats)[0, _SPINE]), head[0])),
            Sources(bool(from_mesh[0]), by_hand_model, np.where(by_hand_model, np.nan, knuckle_twist),
                    foot_confidence(extremities)))


def foot_confidence(extremities_px: np.ndarray) -> np.ndarray:
    """``[2]`` each foot's confidence in a frame's ``extremities_px [E, 3]`` (x, y px, confidence): its heel's
    and big toe's mean, at least :data:`~mocapdb.runtime.rotation_kalman.MIN_CONFIDENCE`."""
    conf = np.nan_to_num(np.asarray(extremities_px, dtype=np.float64)[:, 2], nan=0.0)
    return np.clip(0.5 * (conf[list(HEELS)] + conf[list(TOES)]), MIN_CONFIDENCE, 1.0)


def _knuckles(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None,
              hand_directions: np.ndarray, extremities: np.ndarray, camera_px: tuple[float, float, float]
              ) -> tuple[np.ndarray, np.ndarray]:
    """The hands' thumb sides ``[2, 3]`` the pose's knuckles give (:func:`~mocapdb.runtime.end_joints.
    knuckle_thumb_sides`) on one frame's pose (``quats [1, R, 4]``, ``root_m [1, 3]``, body ``scale`` and
    ``offsets_m``) with its hands' ``hand_directions [2, 3]``, and the twist ``[2]`` (degrees) each gives the
    hand about its shortest turn; NaN where not measured or beyond the forearm's reach."""
    parents, reference = end_frames(quats)
    swings = end_locals(parents[:, 2:], reference[:, 2:], hand_directions[None])
    sides = knuckle_thumb_sides(hand_directions[None], extremities[None], camera_px,
                                wrist_depths_m(quats, root_m, scale, offsets_m), scale,
                                shortest_turn_axes(parents[:, 2:], swings)[..., 1])
    twist = hand_twist_deg(parents[:, 2:], swings, sides)[0]
    return np.where(np.isfinite(twist)[:, None], sides[0], np.nan), twist


class EaseToRest:
    """Step 3 for ``count`` items seen or not frame by frame at ``fps``: each unseen item keeps its last value
    ``hold_s`` seconds, then eases to rest over ``ease_s``; seen (again, or first) it eases in as long."""

    def __init__(self, count: int, fps: float, hold_s: float, ease_s: float) -> None:
        self.fps, self.hold_s, self.ease_s = fps, hold_s, ease_s
        self.progress = np.zeros(count)   # into the measured value: 0 (rest) … 1, linear in time
        self.unseen_s = np.zeros(count)   # seconds since each was last seen

    def weight(self, seen: np.ndarray) -> np.ndarray:
        """``[count]`` this frame's share of the measured value against rest (0 … 1, smoothstep), given which
        items are ``seen [count]`` in it."""
        dt = 1.0 / self.fps
        self.unseen_s = np.where(seen, 0.0, self.unseen_s + dt)
        easing = np.where(seen, 1.0, np.where(self.unseen_s > self.hold_s, -1.0, 0.0))
        self.progress = np.clip(self.progress + easing * dt / self.ease_s, 0.0, 1.0)
        return smoothstep(self.progress)


class DirectionKalman:
    """Directions (unit, view frame) at lag 0 through :class:`~mocapdb.runtime.rotation_kalman.RotationKalman`'s
    constant-angular-velocity model, so prediction replaces the delay of a low-pass: each direction is the
    rotation carrying z onto it, measured as the last estimate turned onto the frame's direction by the
    shortest turn (the twist about it is never measured and never seen), its noise SD ``fit_sd_rad`` over the
    frame's confidence, its white angular acceleration ``accel_rad_s2`` (RMS per tangent axis, rad/s²). Each
    direction is its own filter, updated on the frames it is seen (a gap of ``RESTART_GAP_S`` starts it anew)."""

    def __init__(self, count: int, fps: float, accel_rad_s2: float, fit_sd_rad: float) -> None:
        spectral = np.array([accel_rad_s2 ** 2 * ACCEL_FRAME_S])
        self.filters = [RotationKalman(fps, 0, RotationNoise(fit_sd_rad=fit_sd_rad), spectral) for _ in range(count)]
        self.rotations = np.tile(_IDENTITY, (count, 1))   # each direction's last estimate, as a rotation

    def __call__(self, index: int, directions: np.ndarray, confidence: np.ndarray) -> np.ndarray:
        """``[count, 3]`` the estimates at frame ``index`` given its measured ``directions [count, 3]`` (unit;
        NaN: unseen, that one's estimate kept; z before any is seen) of ``confidence [count]`` (0 … 1)."""
        seen = np.isfinite(directions).all(axis=-1)
        current = quat_to_matrix(self.rotations)[:, :, 2]
        turns = matrix_to_quat(swing_matrices(current, np.where(seen[:, None], directions, current)))
        measured = quat_mul(turns, self.rotations)
        for row in np.flatnonzero(seen):
            self.filters[row].add(index, measured[row:row + 1], confidence[row:row + 1])
            self.rotations[row] = self.filters[row].estimate(index)[0]
        return quat_to_matrix(self.rotations)[:, :, 2]


class SteadyFeet:
    """The feet's directions at lag 0 (frames at ``fps``): each foot's 1€ filter's blended with its
    :class:`DirectionKalman`'s by the foot's steadiness over its last :data:`STEADY_WINDOW_S` of measures
    (:func:`~mocapdb.runtime.hand_pose.steadiness` of the unit direction in degrees: all the Kalman's at a
    frame-to-frame scatter of :data:`STEADY_FOOT_DEG` or less, none from :data:`UNSTEADY_FOOT_DEG`; none while
    the foot is planted), its share moving at most 1 per :data:`EASE_S`: both filters run on every frame, so a
    change of share makes no step."""

    def __init__(self, fps: float) -> None:
        self.fps = fps
        self.kalman = DirectionKalman(2, fps, FOOT_ACCEL_RAD_S2, np.radians(FOOT_FIT_SD_DEG))
        self.measures: list[deque[np.ndarray]] = [deque(maxlen=max(round(STEADY_WINDOW_S * fps), 1)) for _ in range(2)]
        self.share = np.zeros(2)   # each foot's share of the Kalman's direction (0 … 1)

    def __call__(self, index: int, measured: np.ndarray, smoothed: np.ndarray, confidence: np.ndarray,
                 planted: np.ndarray) -> np.ndarray:
        """``[2, 3]`` the feet's directions at frame ``index`` (not yet normalised) given their ``measured [2, 3]``
        (unit; NaN: unseen) of ``confidence [2]`` (0 … 1), the 1€ filter's ``smoothed [2, 3]`` and which feet
        are ``planted [2]``."""
        for foot in np.flatnonzero(np.isfinite(measured).all(axis=-1)):
            self.measures[foot].append(measured[foot])
        quick = self.kalman(index, measured, confidence)
        steady = np.array([steadiness(np.degrees(np.array(measures)).reshape(-1, 3), STEADY_FOOT_DEG,
                                      UNSTEADY_FOOT_DEG) for measures in self.measures])
        step = 1.0 / (EASE_S * self.fps)
        self.share += np.clip(np.where(planted, 0.0, steady) - self.share, -step, step)
        return (1.0 - self.share[:, None]) * smoothed + self.share[:, None] * quick


class OnlineEnds:
    """One track's end joints in the online take (module docstring). ``fps``: frames per second;
    ``lag_frames``, ``sigma_frames``: the online take's lag and Gaussian (frames); ``causal``: its 1€
    filter at lag 0; ``camera_px``: focal, cx, cy (pixels)."""

    def __init__(self, fps: float, lag_frames: int, sigma_frames: float, causal: OneEuroParams,
                 camera_px: tuple[float, float, float]) -> None:
        self.fps, self.lag, self.sigma_frames, self.camera_px = fps, lag_frames, sigma_frames, camera_px
        self.measured: dict[int, Measure] = {}
        self.sources: dict[int, Sources] = {}     # what gave each measured frame's head and thumb sides
        self.knuckle_twists: list[deque[float]] = [deque(maxlen=max(round(STEADY_WINDOW_S * fps), 1)) for _ in range(2)]
        # how much of each hand's twist from the pose's knuckles to keep: its steadiness over those (hand_pose)
        self.knuckles_kept = np.zeros(2)
        self.feet_filter = SteadyFeet(fps)        # the feet's Kalman filter where steady (lag 0)
        self.face = MeshModel()                   # the person's face from the first meshes (mesh_head)
        self.mesh_ease = EaseToRest(1, fps, MESH_HOLD_S, MESH_EASE_S)   # the mesh's share of the head
        self.direction_filter = OneEuroFilter(causal)
        self.hand_model_filter = OneEuroFilter(HAND_MODEL_FILTER)   # the rows the hand model measured
        self.causal = causal
        self.head_filter = QuaternionOneEuroFilter(causal)
        self.held: Measure | None = None          # the last smoothed values (what an unseen end keeps)
        self.ease = EaseToRest(_N_ENDS, fps, HOLD_S, EASE_S)
        self.palm_ease = EaseToRest(2, fps, HOLD_S, EASE_S)   # the palms' twist (a hand's direction: ``ease``)
        self.branches = BranchPath(4)             # the feet's and hands' depths (end_branches)
        self.previous: tuple[int, np.ndarray] | None = None   # index and end rotations [5, 4] of the last output
        self.planted = np.full((2, 3), np.nan)    # each planted foot's direction (view frame); NaN: not planted
        self.planted_sum = np.zeros((2, 3))       # the sum of its standing directions since it settled
        self.planted_frames = np.zeros(2)         # frames since each foot was put down

    def add(self, index: int, pose: PersonPose) -> None:
        """One frame's per-frame pose of the track: measured, kept while the window needs it."""
        self.measured[index], self.sources[index] = measure(pose, self.camera_px, self.branches,
                                                            index / self.fps, self.face)
        for hand, twist in enumerate(self.sources[index].knuckle_twist_deg):
            if np.isfinite(twist):
                self.knuckle_twists[hand].append(twist)
        self.knuckles_kept = np.array([steadiness(np.array(twists, dtype=np.float64))
                                       for twists in self.knuckle_twists])
        for old in [i for i in self.measured if i < index - 2 * self.lag - 1]:
            del self.measured[old], self.sources[old]

    def output(self, index: int, quats: np.ndarray, plant_weights: np.ndarray, up: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """The end joints' local rotations ``[5, 4]`` (:data:`~mocapdb.core.skeleton.END_JOINTS`) of frame
        ``index`` on the output rotations ``quats [R, 4]``, the feet flat by ``plant_weights [2]`` on the
        floor of normal ``up`` (view frame), and which were seen ``[5]``."""
        parents, reference = end_frames(quats[None])
        thumb_sides = np.einsum("hij,hj->hi", parents[0, 2:], HAND_BASES[:, :, 1])     # the palms' at rest
        chest, neck = matrix_to_quat(global_rotations(quats[None])[0, [_SPINE, _NECK]])
        rest = (np.vstack([reference[0], thumb_sides]), neck)   # the head at rest on the neck: the neck's rotation
        directions, head, seen, palm_seen = self._smoothed(index, rest, plant_weights)
        flat = plant_weights[:, None]
        directions[:2] = (1.0 - flat) * directions[:2] + flat * self._planted(standing_directions(directions[:2], up),
                                                                              plant_weights)
        locals_ = levelled_feet(parents, end_locals(parents, reference, directions[None, :4]), up)[0]
        twist = np.nan_to_num(hand_twist_deg(parents[:, 2:], locals_[None, 2:], directions[None, 4:])[0])
        sources = self.sources.get(index, NO_SOURCES)
        kept = np.where(sources.by_hand_model, 1.0, self.knuckles_kept)
        locals_[2:] = twisted(locals_[None, 2:], twist[None] * (self.palm_ease.weight(palm_seen) * kept)[None])[0]
        mesh_seen = np.array([sources.from_mesh])
        if self.previous is None:                 # a track's first frame: nothing shown before, no easing
            self.mesh_ease.progress[:] = mesh_seen
        mesh_weight = self.mesh_ease.weight(mesh_seen)
        relative = quat_mul(quat_conj(chest), head)                              # against the output's chest
        ends = np.vstack([locals_, head_local(quats[None], relative[None], mesh_weight)])
        ends *= np.where(ends[:, :1] < 0, -1.0, 1.0)
        ends = slerp(np.tile(_IDENTITY, (_N_ENDS, 1)), ends, self.ease.weight(seen))
        ends = np.where(np.isfinite(ends).all(axis=-1, keepdims=True), ends, _IDENTITY)   # a degenerate pose: rest
        if self.previous is not None and 0 < index - self.previous[0] <= 2:
            limit = np.radians(END_SPEED_DEG_S) * (index - self.previous[0]) / self.fps
            ends = quat_turned_towards(self.previous[1], ends, limit)
        self.previous = (index, ends)
        return ends, seen

    def _planted(self, standing: np.ndarray, plant_weights: np.ndarray) -> np.ndarray:
        """``[2, 3]`` the feet's directions: ``standing [2, 3]``, but for a foot planted (``plant_weights [2]``
        above 0) longer than :data:`PLANTED_SETTLE_S` the mean of its standing directions since then, followed
        no faster than :data:`PLANTED_FOLLOW_DEG_S`."""
        planted = (plant_weights > 0)[:, None]
        self.planted_frames = np.where(planted[:, 0], self.planted_frames + 1, 0)
        settled = (self.planted_frames > PLANTED_SETTLE_S * self.fps)[:, None]
        self.planted_sum = np.where(settled, self.planted_sum + standing, 0.0)
        mean = np.where(settled, self.planted_sum, standing)
        mean /= np.linalg.norm(mean, axis=-1, keepdims=True)
        held = np.where(np.isnan(self.planted), mean, self.planted)
        angle = np.arccos(np.clip(np.sum(held * mean, axis=-1), -1.0, 1.0))
        limit = np.where(settled[:, 0], np.radians(PLANTED_FOLLOW_DEG_S) / self.fps, np.pi)
        followed = slerp(held, mean, np.minimum(1.0, limit / np.maximum(angle, 1e-12)))
        self.planted = np.where(planted, followed, np.nan)
        return np.where(planted, followed, standing)

    def _smoothed(self, index: int, rest: Measure, plant_weights: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step 2 at frame ``index``: the directions and thumb sides ``[6, 3]``, the head ``[4]``, which ends were
        seen ``[5]`` and which palms ``[2]``; one not seen keeps its held value (``rest`` before it was ever seen)."""
        directions, head = self.measured.get(index, (np.full((6, 3), np.nan), np.full(4, np.nan)))
        rows_seen = np.asarray(np.isfinite(directions).all(axis=-1))
        seen = np.append(rows_seen[:4], np.isfinite(head).all())
        held = rest if self.held is None else self.held
        if self.lag == 0:
            given = np.where(rows_seen[:, None], directions, held[0])
            sources = self.sources.get(index, NO_SOURCES)
            quick = sources.by_hand_model | (rows_seen[4:] & (self.knuckles_kept >= 0.5))
            by_model = np.concatenate([[False, False], quick, quick])
            measured = directions[:2]
            directions = np.where(by_model[:, None], self.hand_model_filter(given, index / self.fps),
                                  self.direction_filter(given, index / self.fps))
            directions[:2] = self.feet_filter(index, measured, directions[:2], sources.feet_confidence,
                                              plant_weights > 0)
            self.head_filter.params = MESH_HEAD_FILTER if sources.from_mesh else self.causal
            head = self.head_filter(np.where(seen[4], head, held[1])[None], index / self.fps)[0]
        else:
            directions, head = self._window_mean(index, held)
        directions = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
        self.held = (directions, head)
        return directions.copy(), head, seen, rows_seen[4:]

    def _window_mean(self, index: int, held: Measure) -> Measure:
        """The Gaussian means of the directions and the head over the frames measured in ``index`` ± lag;
        ``held`` where none is."""
        near = [i for i in range(index - self.lag, index + self.lag + 1) if i in self.measured]
        weights = np.exp(-0.5 * ((np.array(near) - index) / self.sigma_frames) ** 2)
        directions = np.array([self.measured[i][0] for i in near])          # [n, 6, 3]
        heads = np.array([self.measured[i][1] for i in near])               # [n, 4]
        heads = np.where((np.sum(heads * held[1], axis=-1) < 0)[:, None], -heads, heads)
        return _mean_or(directions, weights, held[0]), _mean_or(heads, weights, held[1])


def _mean_or(values: np.ndarray, weights: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Per item of ``values [n, ...]`` (NaN: unseen) the ``weights [n]`` mean of its seen values, normalised
    along the last axis; ``fallback`` where none is seen."""
    seen = np.isfinite(values).all(axis=-1)                                 # [n, ...]
    w = np.where(seen, weights.reshape((-1,) + (1,) * (seen.ndim - 1)), 0.0)
    total = (w[..., None] * np.nan_to_num(values)).sum(axis=0)
    norm = np.linalg.norm(total, axis=-1, keepdims=True)
    return np.where(norm > 1e-9, total / np.maximum(norm, 1e-12), fallback)

