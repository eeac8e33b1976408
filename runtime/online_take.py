"""The online whole take: the whole-take fit's ideas (:mod:`mocapdb.runtime.take`) in the live loop,
per track, at a fixed lag of ``L`` frames (``--lag-frames``; 0 allowed: causal).

When frame ``t`` arrives, frame ``t − L`` is written, each person in it through these steps
(:class:`OnlineTrack`; settings :class:`OnlineParams`):

1. **Rotations and root, filtered.** The engine's own 1€ filters are off (the per-frame fits come
   in). The rotations: per joint a Kalman filter at constant angular velocity in the tangent space
   about its prediction, each frame's fit weighed by its keypoints' confidence (a frame whose side labels
   lie exchanged against the recent frames', :func:`~mocapdb.runtime.side_labels.exchanged_now`, as
   unseen: a detector's flip), and with ``L > 0`` a
   fixed-lag Rauch–Tung–Striebel smoother back from frame ``t``
   (:class:`~mocapdb.runtime.rotation_kalman.RotationKalman`; ``rotation_noise``): it predicts
   instead of delaying, so at ``L = 0`` a turning joint is not dragged behind what the keypoints show,
   and each frame of lag adds evidence. The root: the per-frame roots of frames ``t − L … t + L``
   give a zero-phase Gaussian mean (the whole take's response: it smooths twice at
   ``smoothing_hz``, before and after its re-fit, so one Gaussian √2 as wide), then the whole take's
   root model as a causal Kalman filter (:class:`~mocapdb.runtime.root_filter.RootFilter`: precise
   across the viewing ray, loose along it, smooth; a pop's pull capped).
2. **Foot contacts with hysteresis.** Each foot's image speed (box heights per second: the Theil–Sen
   slope of its keypoints over the frames around it, at most :data:`CONTACT_WINDOW_S` and only as far
   ahead as the lag reaches, which a detector's one-frame left/right swap does not move) is its
   heel's and big toe's, the faster of the two, where the layout gives them, else its ankle's. A foot
   is planted when it is slower than ``planted_box_per_s`` and within ``planted_height_m`` of the
   lower ankle (along the track's estimated up), and stays planted until it is faster than
   ``release_factor`` times that, or rises ``release_factor`` times that height above the other foot
   while its image is no longer still (faster than ``planted_box_per_s``): a lag-0 fit that raises a
   foot the image shows still (a pose retrieved with the legs' depth wrong) does not lift it. Where
   both feet's heels and toes are seen, the whole take's carrying rule
   (:func:`~mocapdb.runtime.foot_contacts.planted_ankles`): while the other foot swings (its heel and
   toe both faster than ``planted_box_per_s``) the foot whose ankle is the slower carries the body,
   and its ankle's speed is held to ``carrying_box_per_s`` instead (``release_factor`` times that to
   stay planted): a foot under the body's weight drifts in the image more than an idle one; and its
   flat-foot rule: a foot whose heel and toe are still while the other's are not carries the body,
   and is planted (and kept) whatever the fit's heights. A speed needs 3 frames: a track's first frame
   seen in the image presumes the person standing on the lower foot (and any within
   ``planted_height_m``), planted at once at full weight (no output before it to blend from), kept
   until the speeds can be measured and then as a new contact would be.
3. **The root carried by the planted foot.** When a foot is planted its ankle's place becomes its
   anchor; while a foot is planted the root is where its anchor puts it (both planted: the mean),
   blended in and out with the feet's IK weights (rising and falling over ``blend_s``, eased by a
   smoothstep: a foot planted or lifted never makes the root jump); the difference to the
   per-frame root is kept as a correction that fades with time constant ``settle_s`` once no foot
   carries the body. A planted anchor follows the per-frame evidence at most
   ``anchor_follow_mps``: a depth error cannot hold it forever, and it slides no faster than that.
   The root so carried moves with every shake of the legs' rotations (the anchor less the ankle),
   so it goes through one more constant-velocity Kalman filter (:class:`RootFilter`,
   ``carried_root_sd_m`` across the viewing ray and, as the whole take's contacts, looser along it:
   ``carried_root_depth_m``, the legs' depth being the pose's least sure); its pull is kept level,
   and the root so pulled is moved into every planted leg's reach of its anchor, by the leg's IK
   weight of the way (:meth:`OnlineTrack._steadied`).
4. **A planted foot locked in place**: the legs turned by the whole take's two-bone IK
   (:func:`~mocapdb.runtime.take.plant_feet`) onto their anchors, the weight blended in and out over
   ``blend_s``. The floor (reported, not enforced) is the median height of the last anchors along
   the track's current up, less the ankle's height above the sole.
5. **Per-joint speed limits**: no rig joint turns faster than its limit (:data:`JOINT_SPEED_DEG_S`,
   degrees per second; the local rotation is slerped back towards the previous frame's) and the
   root moves no faster than ``root_speed_mps``.
6. **Feet, hands and head** (given the camera: heels, big toes, knuckles, face points): the humanoid
   rig's end joints measured as the whole take measures them, smoothed as the rotations, an unseen one
   held, then eased to rest (:mod:`mocapdb.runtime.online_ends`).
The body's size is the engine's per frame (its own proportions, settling as they are measured;
1.75 m tall unless ``--subject-height`` or ``--camera-height``), eased in over ``body_ease_s``
(:meth:`OnlineTrack._eased_body`): the engine re-measures it in steps, which would move every joint
at once. The world's size of each person (:mod:`mocapdb.runtime.world.fuse`) reaches the track files
only.

Each extra frame of lag gives the rotations' smoother and the root's window more frames after the
one written and lets the contacts see further ahead. Cost: O(window) per person and frame (a few
forward kinematics, one two-leg IK, ``L`` smoother steps).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from mocapdb.core.geometry import quat_turned_towards
from mocapdb.core.outputs import CAMERA_FROM_VIEW, PersonPose
from mocapdb.core.skeleton import (
    ANKLE_HEIGHT_M,
    KP,
    RIG_JOINTS,
    UNIVERSAL_HEIGHT_M,
    body_offsets_m,
    pose_from_rotations,
    universal_bone_lengths_m,
)
from mocapdb.runtime.filters import OneEuroParams
from mocapdb.runtime.foot_contacts import ANKLES, CONTACT_WINDOW_S, HEELS, TOES
from mocapdb.runtime.online_ends import OnlineEnds
from mocapdb.runtime.online_fingers import OnlineFingers
from mocapdb.runtime.root_filter import RESTART_GAP_S, RootFilter
from mocapdb.runtime.rotation_kalman import MIN_CONFIDENCE, RotationKalman, RotationNoise, joint_confidence
from mocapdb.runtime.side_labels import BODY_PAIRS, LABEL_WINDOW_S, exchanged_now
from mocapdb.runtime.take import plant_feet
from mocapdb.runtime.take_params import TakeParams

Frame = tuple[int, float, list[PersonPose]]  # frame index, time (s), the people in it

# The fastest each rig joint's local rotation may turn (degrees per second): above what people do
# (knee and elbow extension in kicking and throwing reach 1,500-2,300 °/s, the trunk 600-1,000 °/s),
# below a retrieval's one-frame pop (a 90° flip in 1/60 s is 5,400 °/s).
JOINT_SPEED_DEG_S = {"pelvis": 900.0, "spine": 900.0, "neck": 900.0, "r_hip": 1400.0, "l_hip": 1400.0,
                     "r_knee": 2000.0, "l_knee": 2000.0, "r_shoulder": 1800.0, "l_shoulder": 1800.0,
                     "r_elbow": 2300.0, "l_elbow": 2300.0}
# The end joints' and fingers' causal filter (L = 0; online_ends, online_fingers): the 1€ filter of
# retrieved poses (runtime.filters) with its still-joint cut-off halved
CAUSAL_ROTATIONS = OneEuroParams(min_cutoff_hz=0.5, beta=0.3)
FLOOR_SAMPLES = 31  # the floor: the median height of this many last anchors
UNIVERSAL_BONES_M = universal_bone_lengths_m()   # [8] metres, 1.75 m: a pose without its own bones
HIPS, KNEES = (KP["r_hip"], KP["l_hip"]), (KP["r_knee"], KP["l_knee"])
REACH_PASSES = 3   # the root moved into both planted legs' reach in turn this many times


@dataclass(frozen=True)
class OnlineParams:
    """The online whole take's settings (module docstring); lengths in metres, times in seconds."""

    lag_frames: int = 0
    smoothing_hz: float = 4.0
    causal_rotations: OneEuroParams = CAUSAL_ROTATIONS
    planted_box_per_s: float = 0.25
    carrying_box_per_s: float = TakeParams.carrying_box_per_s
    release_factor: float = 2.0
    planted_height_m: float = 0.05
    blend_s: float = 0.08
    settle_s: float = 0.4
    anchor_follow_mps: float = 0.02
    root_speed_mps: float = 6.0
    carried_root_sd_m: float = 0.02
    carried_root_depth_m: float = TakeParams.contact_depth_m
    body_ease_s: float = 0.05
    rotation_noise: RotationNoise = RotationNoise()

    def __post_init__(self) -> None:
        positive = (self.smoothing_hz, self.planted_box_per_s, self.planted_height_m, self.blend_s, self.settle_s,
                    self.root_speed_mps, self.carried_root_sd_m, self.carried_root_depth_m, self.body_ease_s)
        if self.lag_frames < 0 or self.release_factor < 1 or self.anchor_follow_mps < 0 \
                or self.carrying_box_per_s < self.planted_box_per_s \
                or not all(np.isfinite(v) and v > 0 for v in positive):
            raise ValueError(f"online take settings out of range: {self}")


class OnlineTake:
    """Frames in, the same frames out ``lag_frames`` later, every person through the online whole
    take (module docstring). ``fps``: the input's frame rate (Hz)."""

    def __init__(self, fps: float, params: OnlineParams = OnlineParams(),
                 camera_px: tuple[float, float, float] | None = None):
        if not fps > 0:
            raise ValueError("the online take needs a positive frame rate")
        self.fps, self.params, self.camera_px = float(fps), params, camera_px
        self.lag = params.lag_frames
        self.frames: deque[Frame] = deque()
        self.tracks: dict[int, OnlineTrack] = {}

    def push(self, index: int, time_s: float, poses: list[PersonPose]) -> list[Frame]:
        """Add one frame; returns the frames now due (at most one)."""
        self.frames.append((index, time_s, poses))
        for pose in poses:
            if pose.track not in self.tracks:
                self.tracks[pose.track] = OnlineTrack(self.fps, self.params, self.camera_px)
            self.tracks[pose.track].add(index, pose)
        if len(self.frames) <= self.lag:
            return []
        return [self._due()]

    def flush(self) -> list[Frame]:
        """The frames not yet written (the last ``lag_frames`` at the end of the input)."""
        out = []
        while self.frames:
            out.append(self._due())
        return out

    def _due(self) -> Frame:
        index, time_s, poses = self.frames.popleft()
        people = [self.tracks[p.track].output(index, p) for p in poses]
        horizon = index - 4 * int(self.fps)  # a track unseen for 4 s has ended: forget it
        for track in [t for t, state in self.tracks.items() if state.last_index < horizon]:
            del self.tracks[track]
        return index, time_s, people


@dataclass
class _Feet:
    """The contact state of both feet (right, left)."""

    planted: np.ndarray = field(default_factory=lambda: np.zeros(2, dtype=bool))
    progress: np.ndarray = field(default_factory=lambda: np.zeros(2))  # into the contact, 0 … 1, linear in time
    weight: np.ndarray = field(default_factory=lambda: np.zeros(2))    # IK weight: the progress eased (smoothstep)
    anchor: np.ndarray = field(default_factory=lambda: np.full((2, 3), np.nan))  # view frame, metres
    placed: deque = field(default_factory=lambda: deque(maxlen=FLOOR_SAMPLES))  # the last anchors [3] (view frame)
    presumed: bool = False   # planted as the track began, before its feet's speeds could be measured


class OnlineTrack:
    """One track's online whole take: its recent per-frame poses and what the steps carry over."""

    def __init__(self, fps: float, params: OnlineParams, camera_px: tuple[float, float, float] | None = None):
        self.fps, self.params = fps, params
        # the whole take smooths twice at smoothing_hz (before and after its re-fit): one Gaussian √2 as wide
        self.sigma_frames = np.sqrt(2.0) * fps / (2.0 * np.pi * params.smoothing_hz)
        self.ends = None if camera_px is None else OnlineEnds(fps, params.lag_frames, self.sigma_frames,
                                                              params.causal_rotations, camera_px)
        self.fingers: OnlineFingers | None = None   # made at the track's first frame with a hand seen
        self.half_window = max(round(CONTACT_WINDOW_S * fps / 2), 1)
        self.recent: dict[int, PersonPose] = {}
        self.boxes: deque[float] = deque(maxlen=int(2 * fps))
        self.last_index = -1
        self.feet = _Feet()
        self.correction = np.zeros(3)       # output root − per-frame root (view frame, metres)
        self.previous: tuple[int, np.ndarray, np.ndarray] | None = None  # index, rotations, root of the last output
        self.body: tuple[int, np.ndarray] | None = None   # index, [2, 9] the eased body's two stages (_eased_body)
        self.root = RootFilter(fps)  # the whole take's root model, causal
        self.carried = RootFilter(fps, TakeParams(root_across_m=params.carried_root_sd_m,
                                                  root_depth_m=params.carried_root_depth_m))
        self.rotations = RotationKalman(fps, params.lag_frames, params.rotation_noise)
        self.label_frames = max(round(LABEL_WINDOW_S * fps), 3)
        self.labelled: deque[np.ndarray] = deque(maxlen=self.label_frames)   # the recent frames' keypoints
        self.max_turn = np.radians([JOINT_SPEED_DEG_S[j] for j in RIG_JOINTS]) / fps  # radians per frame

    def add(self, index: int, pose: PersonPose) -> None:
        """One frame's per-frame pose of the track."""
        self.recent[index] = pose
        self.last_index = index
        self.rotations.add(index, pose.quaternions, self._confidence(pose.keypoints_px))
        if self.ends is not None:
            self.ends.add(index, pose)
        if pose.hands_px is not None and (self.fingers is not None or np.isfinite(pose.hands_px).any()):
            if self.fingers is None:
                self.fingers = OnlineFingers(self.fps, self.params.lag_frames, self.sigma_frames,
                                             self.params.causal_rotations)
            self.fingers.add(index, pose.hands_px)
        if pose.keypoints_px is not None:
            seen = pose.keypoints_px[pose.keypoints_px[:, 2] > 0, 1]
            if len(seen) > 1:
                self.boxes.append(float(np.ptp(seen)))
        oldest = index - 2 * max(self.params.lag_frames, self.half_window) - 1
        for old in [i for i in self.recent if i < oldest]:
            del self.recent[old]

    def _confidence(self, keypoints_px: np.ndarray | None) -> np.ndarray:
        """``[R]`` the rig joints' confidence in this frame's fit (:func:`joint_confidence`); a frame whose
        side labels lie exchanged against the recent frames' (:func:`~mocapdb.runtime.side_labels.exchanged_now`,
        once half its window is seen) was fitted to a detector's flip: each joint counts as unseen."""
        confidence = joint_confidence(keypoints_px)
        if keypoints_px is None:
            return confidence
        if 2 * len(self.labelled) >= self.label_frames and \
                exchanged_now(np.array(self.labelled), keypoints_px, BODY_PAIRS).any():
            confidence = np.minimum(confidence, MIN_CONFIDENCE)
        self.labelled.append(keypoints_px)
        return confidence

    def output(self, index: int, pose: PersonPose) -> PersonPose:
        """The pose of frame ``index`` (whose per-frame pose is ``pose``) through the steps."""
        dt = 1.0 / self.fps
        height_m, bones_m = self._eased_body(index, pose)
        scale = height_m / UNIVERSAL_HEIGHT_M
        offsets = body_offsets_m(bones_m / scale)
        quats = self.rotations.estimate(index)
        evidence_root = self._smoothed_root(index)
        up = np.array([0.0, 1.0, 0.0]) if pose.up_view is None else np.asarray(pose.up_view, dtype=np.float64)
        body = pose_from_rotations(quats[None], np.zeros((1, 3)), scale, offsets)[0]   # about the root
        ankles = body[list(ANKLES)]
        self._contacts(index, ankles @ up, scale)
        root = self._steadied(index, self._carried_root(evidence_root, ankles, up, scale, dt), body, up)
        quats, root = self._speed_limited(index, quats, root)
        feet = self.feet
        if feet.weight.any():
            quats = plant_feet(quats[None], root[None], scale, offsets, feet.weight[None], feet.anchor[None])[0]
        self.previous = (index, quats, root)
        joints = pose_from_rotations(quats[None], root[None], scale, offsets)[0]
        floor = float(np.median(np.array(feet.placed) @ up)) - ANKLE_HEIGHT_M * scale if feet.placed else None
        ends, seen = (None, None) if self.ends is None else self.ends.output(index, quats, feet.weight, up)
        fingers, hands = (None, None) if self.fingers is None else self.fingers.output(index)
        return replace(pose, joints_m=joints * CAMERA_FROM_VIEW, quaternions=quats, root_m=root * CAMERA_FROM_VIEW,
                       height_m=height_m, bones_m=None if pose.bones_m is None else bones_m, up_view=up,
                       floor_offset_m=floor, contacts=(bool(feet.planted[0]), bool(feet.planted[1])),
                       end_quaternions=ends, end_seen=None if seen is None else tuple(bool(s) for s in seen),
                       finger_quaternions=fingers, fingers_seen=None if hands is None else (bool(hands[0]),
                                                                                            bool(hands[1])))

    def _eased_body(self, index: int, pose: PersonPose) -> tuple[float, np.ndarray]:
        """The body's height (m) and bone lengths ``[8]`` (m; the universal body's scaled where the pose
        has none) at frame ``index``: the engine's, which it re-measures every few frames in steps, through
        two exponentials of time constant ``body_ease_s`` (critically damped: a step eases in without a
        jump in speed, so a re-measured body shakes no joint)."""
        bones = UNIVERSAL_BONES_M * (pose.height_m / UNIVERSAL_HEIGHT_M) if pose.bones_m is None \
            else np.asarray(pose.bones_m, dtype=np.float64)
        target = np.concatenate([[pose.height_m], bones])
        if self.body is None or (index - self.body[0]) / self.fps > RESTART_GAP_S:
            stages = np.stack([target, target])
        else:
            alpha = 1.0 - np.exp(-(index - self.body[0]) / (self.fps * self.params.body_ease_s))
            stages = self.body[1].copy()
            stages[0] += alpha * (target - stages[0])
            stages[1] += alpha * (stages[0] - stages[1])
        self.body = (index, stages)
        return float(stages[1, 0]), stages[1, 1:]

    def _smoothed_root(self, index: int) -> np.ndarray:
        """Step 1's root ``[3]`` (view frame) of frame ``index``: the window's Gaussian mean through
        the root filter."""
        lag = self.params.lag_frames
        near = [i for i in range(index - lag, index + lag + 1) if i in self.recent]
        w = np.exp(-0.5 * ((np.array(near) - index) / self.sigma_frames) ** 2)
        mean = w @ np.array([self.recent[i].root_m for i in near]) * CAMERA_FROM_VIEW / w.sum()
        return self.root(index, mean)

    def _contacts(self, index: int, ankle_heights_m: np.ndarray, scale: float) -> None:
        """Step 2: each foot planted or not at frame ``index`` (hysteresis; module docstring). A track's
        first frame seen in the image presumes it standing on its lower foot (and any within
        ``planted_height_m``), kept until its feet's speeds can be measured and then as a new contact."""
        feet, height_m = self.feet, self.params.planted_height_m * scale
        above = ankle_heights_m - ankle_heights_m.min()
        if self.previous is None:
            feet.planted = (above <= height_m) & (self.recent[index].keypoints_px is not None)
            feet.presumed = True
            return
        speeds = self._foot_speeds(index)
        if speeds is None:                       # too few frames to measure: only a presumed contact stays
            feet.planted &= feet.presumed
            return
        kept, new = _contact_tests(speeds, above, height_m, self.params)
        feet.planted = np.where(feet.planted & ~feet.presumed, kept, new)   # a presumed contact: tested afresh
        feet.presumed = False

    def _foot_speeds(self, index: int) -> np.ndarray | None:
        """Each foot's ankle, heel and big toe image speeds ``[3, 2]`` (rows; right, left; box heights per
        second, inf where not seen) at frame ``index``: the Theil–Sen slopes over the contact window
        (:func:`_robust_speeds`); None with fewer than 3 frames in it."""
        h = self.half_window
        near = [i for i in range(index - h, index + min(h, self.params.lag_frames) + 1)
                if i in self.recent and self.recent[i].keypoints_px is not None]
        if len(near) < 3:
            return None
        points = np.array([_foot_points(self.recent[i]) for i in near])     # [n, 6, 3]: ankles, heels, toes
        speeds = _robust_speeds(np.array(near, dtype=np.float64), points)
        return (speeds * self.fps / max(np.median(self.boxes), 1.0)).reshape(3, 2)

    def _carried_root(self, evidence_root: np.ndarray, ankles: np.ndarray, up: np.ndarray, scale: float,
                      dt: float) -> np.ndarray:
        """Step 3: the root (view frame) carried by the planted feet; anchors set and followed."""
        p, feet = self.params, self.feet
        free = evidence_root + self.correction
        for k in range(2):
            if feet.planted[k] and feet.progress[k] == 0.0:   # a new contact: its anchor where the ankle is
                feet.anchor[k] = free + ankles[k]
                feet.placed.append(feet.anchor[k].copy())
        feet.progress = np.clip(feet.progress + np.where(feet.planted, dt, -dt) / p.blend_s, 0.0, 1.0)
        if self.previous is None:     # a track's first frame: no output before it to blend from
            feet.progress = feet.planted.astype(np.float64)
        feet.weight = feet.progress ** 2 * (3.0 - 2.0 * feet.progress)
        carrying = feet.weight > 0
        if not carrying.any():
            self.correction *= np.exp(-dt / p.settle_s)
            return evidence_root + self.correction
        w = feet.weight[carrying]
        carried = w @ (feet.anchor[carrying] - ankles[carrying]) / w.sum()
        share = float(w.max())
        root = (1.0 - share) * free + share * carried
        self.correction = root - evidence_root
        planted = np.flatnonzero(feet.planted)
        step = evidence_root + ankles[planted] - feet.anchor[planted]
        length = np.linalg.norm(step, axis=-1, keepdims=True)
        feet.anchor[planted] += step * np.minimum(1.0, p.anchor_follow_mps * dt / np.maximum(length, 1e-12))
        return root

    def _steadied(self, index: int, root: np.ndarray, body: np.ndarray, up: np.ndarray) -> np.ndarray:
        """Step 3's root ``[3]`` (view frame, m) through :attr:`carried`, a filter of the carried root
        (``carried_root_sd_m`` across the viewing ray, ``carried_root_depth_m`` along it): the legs'
        rotations that carry the root shake it no more. Its pull is level (a planted leg reaches no
        higher); the root so pulled is then moved towards each planted anchor until the leg (thigh +
        shank of ``body [15, 3]``, the joints about the root) reaches it from the hip, by the leg's IK
        weight of the way (a foot blending in or out limits the root as much as it carries it: no jump
        when it starts or ends): a straight leg's root keeps the level pull and lowers by the little
        it takes (a pull ``d`` across a leg of length ``L``: ``L − √(L² − d²)``)."""
        pull = self.carried(index, root) - root
        pulled = root + pull - (pull @ up) * up
        feet = self.feet
        carrying = np.flatnonzero(feet.weight > 0)
        if not len(carrying):
            return pulled
        hips, knees, ankles = (body[list(j)][carrying] for j in (HIPS, KNEES, ANKLES))
        anchors, weights = feet.anchor[carrying], feet.weight[carrying]
        reach = np.linalg.norm(knees - hips, axis=-1) + np.linalg.norm(ankles - knees, axis=-1)
        reach = np.maximum(reach, np.linalg.norm(root + hips - anchors, axis=-1))   # never less than carried
        over = np.maximum(np.linalg.norm(pulled + hips - anchors, axis=-1) - reach, 0.0)
        radius = reach + (1.0 - weights) * over          # the leg's weight of the way into its reach
        root = pulled
        for _ in range(REACH_PASSES):
            for hip, anchor, limit in zip(hips, anchors, radius):
                leg = root + hip - anchor
                length = float(np.linalg.norm(leg))
                if length > limit:
                    root = root + (limit / length - 1.0) * leg
        self.carried.constrain(root)
        return root

    def _speed_limited(self, index: int, quats: np.ndarray, root: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Step 5: ``quats`` and ``root`` moved from the previous output no faster than the limits."""
        previous = self.previous
        if previous is not None and 0 < index - previous[0] <= 2:
            frames = index - previous[0]
            prev_q, prev_root = previous[1], previous[2]
            quats = quat_turned_towards(prev_q, quats, self.max_turn * frames)
            root = prev_root + _clamped(root - prev_root, self.params.root_speed_mps * frames / self.fps)
        return quats, root


def _contact_tests(speeds: np.ndarray, above_m: np.ndarray, height_m: float, p: OnlineParams
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Step 2's tests per foot ``[2]`` (right, left): a planted foot kept, a foot newly planted; from
    the feet's ankle, heel and big toe image speeds ``speeds [3, 2]`` (box heights per second, inf where
    not seen), their heights above the lower ankle ``above_m [2]`` and the planted height ``height_m``
    (metres, at the body's size)."""
    ankle, heel, toe = speeds
    ends = np.isfinite(heel) & np.isfinite(toe)
    speed = np.where(ends, np.maximum(heel, toe), ankle)     # flat: heel and toe both still
    swinging = ends & (np.minimum(heel, toe) >= p.planted_box_per_s)   # heel and toe both moving
    carrying = ends & swinging[::-1] & (ankle <= ankle[::-1])   # the slower foot while the other swings
    supported = ends & ends[::-1] & (speed[::-1] >= p.planted_box_per_s)   # the other foot seen, not flat
    f, low = p.release_factor, above_m <= height_m
    still = speed <= f * p.planted_box_per_s
    risen = (above_m > f * height_m) & (speed >= p.planted_box_per_s)   # its image moving
    kept = (still | (carrying & (ankle <= f * p.carrying_box_per_s))) & (~risen | (supported & still))
    new = ((speed < p.planted_box_per_s) & (low | supported)) | (low & carrying & (ankle < p.carrying_box_per_s))
    return kept, new


def _clamped(v: np.ndarray, limit: float) -> np.ndarray:
    """``v`` shortened to length ``limit`` if longer."""
    length = float(np.linalg.norm(v))
    return v * (limit / length) if length > limit else v


def _foot_points(pose: PersonPose) -> np.ndarray:
    """``[6, 3]`` the right and left ankle, heel and big toe of a pose's keypoints (x, y px, confidence)."""
    kp = pose.keypoints_px
    ends = pose.extremities_px
    assert kp is not None
    feet = np.zeros((4, 3)) if ends is None else ends[[HEELS[0], HEELS[1], TOES[0], TOES[1]]]
    return np.vstack([kp[list(ANKLES)], feet])


@njit(cache=True)
def _robust_speeds(frames: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Per point of ``points [n, K, 3]`` (x, y px, confidence) over ``frames [n]``, its speed (px per
    frame): the Theil–Sen slope of its seen positions (per axis the median of the slopes between every
    two of them), which a detector's swap or stray in fewer than about 3 in 10 frames does not move;
    inf with fewer than 3 seen."""
    n, k = points.shape[0], points.shape[1]
    out = np.full(k, np.inf)
    slopes = np.empty((n * (n - 1) // 2, 2))
    for p in range(k):
        m = 0
        for i in range(n):
            for j in range(i + 1, n):
                if points[i, p, 2] > 0 and points[j, p, 2] > 0:
                    slopes[m] = (points[j, p, :2] - points[i, p, :2]) / (frames[j] - frames[i])
                    m += 1
        if m >= 3:   # 3 pairs: 3 seen positions
            out[p] = np.hypot(np.median(slopes[:m, 0]), np.median(slopes[:m, 1]))
    return out
