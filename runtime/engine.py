"""The per-frame engine: people's 2D keypoints → tracked, retrieved, smoothed 3D skeletons.

One code path serves `mocapdb reconstruct` (files) and `mocapdb live` (streams). Frames
(``data_specs/stream_output.md``):

* **view frame** (right-handed, metres): x to the image's right, y up, z towards the camera.
  The matched database skeleton turned by its yaw lives here (the database camera looks along
  −z); BVH output and the stored quaternions use it.
* **camera-aligned frame** (the JSON ``joints``/``root``): x right, y up, z away from the camera
  (the view frame with z negated); the origin is the camera centre when the root translation is
  estimated, otherwise the pelvis.

Its parameters: :mod:`mocapdb.runtime.engine_config`; each track's memory (skeletons, body,
filters, recording, stillness): :mod:`mocapdb.runtime.track_state`.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numba import njit

from mocapdb.core.formats.database import DatabaseError, MotionDatabase
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import matrix_to_quat, normalize_pose_2d, yaw_matrix
from mocapdb.core.outputs import CAMERA_FROM_VIEW, Match, PersonPose, TrackRecording
from mocapdb.core.search_rules import clusters_searched_for, subclusters_searched_for
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D, N_RIG_JOINTS, PELVIS, UNIVERSAL_HEIGHT_M, pose_from_rotations
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.refine import JointLimits, Refiner
from mocapdb.runtime.search import SearchIndex, search_clustered, search_exact, yaw_offset
from mocapdb.runtime.temporal import temporal_costs, yaw_quaternion, yawed_rotations
from mocapdb.runtime.track_state import NO_EXTREMITIES, TrackState
from mocapdb.runtime.tracker import Tracker, TrackUpdate

R_HIP, L_HIP = KP["r_hip"], KP["l_hip"]  # numba freezes them as constants
MIN_EXTENT_PX = 4.0  # a person whose confident keypoints span less is skipped (degenerate)


def _extremities(person: Person, threshold: float) -> np.ndarray:
    """A person's heels, toes and knuckles ``[8, 3]`` (x px, y px, confidence), those below
    ``threshold`` missing (confidence 0, as the 14 keypoints); all missing without any."""
    if person.extremities is None:
        return NO_EXTREMITIES
    keep = person.extremities[:, 2] >= threshold
    return np.where(keep[:, None], person.extremities, NO_EXTREMITIES)


@njit(cache=True)
def _extent_px(points, visible) -> float:
    """The larger side (pixels) of the box of the visible keypoints (0 with none)."""
    lo_x = lo_y = np.inf
    hi_x = hi_y = -np.inf
    for k in range(points.shape[0]):
        if visible[k]:
            lo_x, hi_x = min(lo_x, points[k, 0]), max(hi_x, points[k, 0])
            lo_y, hi_y = min(lo_y, points[k, 1]), max(hi_y, points[k, 1])
    return max(hi_x - lo_x, hi_y - lo_y, 0.0)


@dataclass
class EngineStats:
    frames: int = 0
    person_frames: int = 0
    skipped_people: int = 0  # detections with too few confident joints or no hip
    degenerate_people: int = 0  # detections whose confident keypoints span less than MIN_EXTENT_PX
    tracks_started: int = 0
    gaps: int = 0            # jumps in time or frame number that ended every track
    over_max_tracks: int = 0  # detections not tracked: TrackLimits.max_tracks tracks were alive
    over_max_new: int = 0     # detections not tracked: TrackLimits.max_new_per_min reached


class NewTrackWindow:
    """When the tracks of the last 60 s were confirmed, to hold their number to a limit."""

    def __init__(self) -> None:
        self.times: deque[float] = deque()

    def allowed(self, limit: int, now_s: float) -> int | None:
        """How many tracks may be confirmed at ``now_s`` (None: no limit)."""
        if not limit:
            return None
        while self.times and self.times[0] <= now_s - 60.0:
            self.times.popleft()
        return max(limit - len(self.times), 0)

    def add(self, n: int, limit: int, now_s: float) -> None:
        if limit:
            self.times.extend([now_s] * n)


class Engine:
    """Retrieval engine over one database; call :meth:`step` per frame, :meth:`finish` at the end."""

    def __init__(self, db: MotionDatabase, config: EngineConfig | None = None):
        self.db = db
        self.config = config or EngineConfig()
        cfg = self.config
        self.index = SearchIndex.from_database(db)
        self.n_clusters = cfg.n_clusters or clusters_searched_for(db.n_clusters)  # i
        self.subclusters = cfg.subclusters or subclusters_searched_for(db.n_projections)
        self.db_quats = np.ascontiguousarray(db.quaternions)
        self.clip_first = db.clip_first_frame[db.frame_clip]
        self.yaws_deg = np.asarray(db.meta["yaws_deg"], dtype=np.float64)
        self.yaw_quats = matrix_to_quat(yaw_matrix(self.yaws_deg))
        _check_frame_major(db)
        self.n_yaws = len(self.yaws_deg)
        self.window_weights = np.asarray(cfg.window_weights, dtype=np.float64)
        weights = cfg.joint_weights or (1.0,) * N_RIG_JOINTS
        if len(weights) != N_RIG_JOINTS:
            raise ValueError(f"joint_weights needs {N_RIG_JOINTS} values, got {len(weights)}")
        self.joint_weights = np.asarray(weights, dtype=np.float64)
        self.tracker = Tracker(cfg.tracker)
        self.refiner = Refiner(cfg.refinement, JointLimits.from_rotations(self.db_quats)) if cfg.refine else None
        self.center_px = (cfg.image_size[0] / 2.0, cfg.image_size[1] / 2.0)
        self.tracks: dict[int, TrackState] = {}
        self.finished: list[TrackRecording] = []
        self.stats = EngineStats()
        self._new_tracks = NewTrackWindow()
        self._last_seen: tuple[int, float] | None = None
        # the last frames' usable people (index, time, points, confidences, extremities), for tracks
        # confirmed later
        self._recent: deque[tuple[int, float, np.ndarray, np.ndarray, np.ndarray]] = deque(
            maxlen=max(cfg.tracker.min_hits - 1, 0))
        self._warm_up()

    def _warm_up(self) -> None:
        """Run every compiled kernel once on a database pose, so the first real frame is not slow."""
        points = self.index.pose(0).astype(np.float64) * 400.0 + 500.0
        conf = np.ones(N_KEYPOINTS_2D)
        Tracker(self.config.tracker).update(points[None], conf[None], 0.0)
        state = TrackState(-1, 0, self.config, len(self.window_weights))
        for i in range(2):
            self._person(state, points, conf, NO_EXTREMITIES, i, i / self.config.fps)

    # -- per frame -------------------------------------------------------------------------
    def step(self, frame: KeypointFrame, now_s: float | None = None) -> list[PersonPose]:
        """Process one frame; returns the poses of the confirmed tracks seen in it (a track confirmed
        now records its detections of the frames before too, without returning them). ``now_s``: the
        clock of the new-track limit (seconds; default the frame's time)."""
        cfg = self.config
        t_s = frame.time_s if frame.time_s is not None else frame.index / cfg.fps
        self._end_tracks_after_a_gap(frame.index, t_s)
        self.stats.frames += 1
        people = [p for p in frame.people if self._usable(p)]
        self.stats.skipped_people += len(frame.people) - len(people)
        points = np.array([p.points_px for p in people]).reshape(-1, N_KEYPOINTS_2D, 2)
        conf = np.array([p.confidence for p in people]).reshape(-1, N_KEYPOINTS_2D)
        conf = np.where(conf >= cfg.confidence_threshold, conf, 0.0)
        extremities = np.array([_extremities(p, cfg.confidence_threshold) for p in people]).reshape(
            -1, len(EXTREMITIES), 3)
        update = self._track(points, conf, t_s, t_s if now_s is None else now_s)
        for track in update.ended:
            self._end(track)
        poses = []
        for track, det in update.assignments:
            state = self.tracks.get(track)
            if state is None:
                state = self._start(track, update.earlier.get(track, []), frame.index)
            poses.append(self._detected(state, points[det], conf[det], extremities[det], frame.index, t_s))
        self.stats.person_frames += len(poses)
        self._recent.append((frame.index, t_s, points, conf, extremities))
        return poses

    def _start(self, track: int, earlier: list[int], frame_index: int) -> TrackState:
        """A track confirmed on frame ``frame_index``, its ``earlier`` detections (the frames before,
        :attr:`TrackUpdate.earlier`) already recorded: its recording starts at its first detection,
        the stream at its confirmation."""
        frames = list(self._recent)[len(self._recent) - len(earlier):] if earlier else []
        first = frames[0][0] if frames else frame_index
        state = self.tracks[track] = TrackState(track, first, self.config, len(self.window_weights))
        if self.config.keep_take and self.refiner is not None:
            state.recording.camera_px = (self.config.focal_px, *self.center_px)
        self.stats.tracks_started += 1
        for (index, t_s, points, conf, extremities), det in zip(frames, earlier):
            self._detected(state, points[det], conf[det], extremities[det], index, t_s)
        return state

    def _detected(self, state: TrackState, points_px: np.ndarray, conf: np.ndarray, extremities: np.ndarray,
                  frame_index: int, t_s: float) -> PersonPose:
        """The pose of one detection ``[14, 2]`` px (heels, toes, knuckles ``[8, 3]``) of a track, recorded."""
        state.stillness.add(points_px, conf > 0, t_s)
        person_px = points_px if state.keypoints is None else state.keypoints(points_px, conf, t_s)
        return self._person(state, person_px, conf, extremities, frame_index, t_s)

    def _track(self, points: np.ndarray, conf: np.ndarray, t_s: float, now_s: float) -> TrackUpdate:
        """The tracker's update within the limits, counting what they held back."""
        limits = self.config.limits
        allowed = self._new_tracks.allowed(limits.max_new_per_min, now_s)
        update = self.tracker.update(points, conf, t_s, limits.max_tracks, allowed)
        self._new_tracks.add(len(update.started), limits.max_new_per_min, now_s)
        self.stats.over_max_tracks += update.over_max_tracks
        self.stats.over_max_new += update.over_max_new
        return update

    def _end_tracks_after_a_gap(self, frame_index: int, t_s: float) -> None:
        """A jump of more than ``max_gap_s`` ends every track, so a time (or, for frames without
        one, a frame number) far in the future costs one frame, not the frames in between."""
        last = self._last_seen
        self._last_seen = (frame_index, t_s)
        if last is not None and t_s - last[1] > self.config.max_gap_s:
            self.stats.gaps += 1
            self._end_all()

    def _usable(self, person: Person) -> bool:
        vis = person.confidence >= self.config.confidence_threshold
        if int(vis.sum()) < self.config.min_joints or not (vis[R_HIP] or vis[L_HIP]):
            return False
        if _extent_px(person.points_px, vis) < MIN_EXTENT_PX:  # all at one point: no size, no depth
            self.stats.degenerate_people += 1
            return False
        return True

    def _person(self, state: TrackState, points_px: np.ndarray, confidence: np.ndarray, extremities: np.ndarray,
                frame_index: int, t_s: float) -> PersonPose:
        quats, root_view, match = self._retrieve(state, points_px, confidence > 0)
        if self.refiner is not None:
            root_view = self._fit(state, quats, root_view, points_px, confidence, frame_index)
        if not self.config.translation:
            root_view = np.zeros(3)
        state.remember(quats)
        fit = None
        if self.config.keep_take:
            fit = (quats.copy(), root_view.copy(), np.column_stack([points_px, confidence]), extremities)
        if self.config.smoothing:
            quats = state.rotations(quats, t_s)
            root_view = state.root(root_view, t_s)
        state.record(frame_index, t_s, quats, root_view, fit)
        joints_view = pose_from_rotations(quats[None], root_view[None], state.scale, state.offsets_m)[0]
        return PersonPose(state.recording.track, joints_view * CAMERA_FROM_VIEW, quats,
                          root_view * CAMERA_FROM_VIEW, match, state.scale * UNIVERSAL_HEIGHT_M,
                          state.proportions_m * state.scale)

    def _retrieve(self, state: TrackState, points_px: np.ndarray,
                  visible: np.ndarray) -> tuple[np.ndarray, np.ndarray, Match]:
        """The method's pose: search, Eq. 2 choice, yaw refinement. Returns its rotations ``[R, 4]``
        (root turned by the yaw), the root seen at the image's size for the track's body scale,
        and the match."""
        query, _, _ = normalize_pose_2d(points_px, visible)
        rows, dist = self._search(query, visible)
        best = self._choose(state, rows, dist)
        row = int(rows[best])
        f, v = divmod(row, self.n_yaws)  # rows are frame-major
        yaw_deg = self._refined_yaw(f, v, query, visible)
        quats = yawed_rotations(self.db_quats, f, yaw_quaternion(yaw_deg))
        root_view = self._root_view(f, yaw_deg, points_px, visible) * state.scale
        clip = int(self.db.frame_clip[f])
        return quats, root_view, Match(self.db.clip_name[clip], int(self.db.frame_index[f]), yaw_deg, float(dist[best]))

    def _fit(self, state: TrackState, quats: np.ndarray, root_view: np.ndarray, points_px: np.ndarray,
             confidence: np.ndarray, frame_index: int) -> np.ndarray:
        """Refine ``quats`` (in place) and the root against the keypoints; with a floor, update the
        track's body scale. Returns the root (view frame, metres)."""
        upright_root = quats[0].copy()
        state.tilt.tilt_root(upright_root, quats[0])
        retrieved = quats.copy()
        self.refiner(quats, root_view, state.scale, points_px, confidence, retrieved,
                     state.previous(frame_index), self.config.focal_px, self.center_px, state.offsets_m)
        state.tilt.update(quats[0], upright_root)
        state.measure_bones(points_px, confidence, retrieved, root_view, self.config.focal_px)
        if state.floor is not None:
            joints = pose_from_rotations(quats[None], root_view[None], state.scale, state.offsets_m)[0]
            scale = state.floor.update(state.tilt.up, joints, state.scale, state.tilt.sd_deg)
            root_view = root_view * (scale / state.scale)
            state.scale = scale
        return root_view

    def _refined_yaw(self, frame: int, yaw: int, query: np.ndarray, visible: np.ndarray) -> float:
        """The matched yaw, refined between the database's yaws unless turned off (degrees)."""
        if not self.config.refine_yaw or len(self.yaws_deg) < 3:
            return float(self.yaws_deg[yaw])
        return float(self.yaws_deg[yaw]) + yaw_offset(self.index, frame, yaw, self.yaws_deg, query, visible)

    def _search(self, query: np.ndarray, visible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        if cfg.search == "exact":
            return search_exact(self.index, query, visible, self.n_clusters * cfg.per_cluster)
        return search_clustered(self.index, query, visible, self.n_clusters, cfg.per_cluster, cfg.grid_descents,
                                self.subclusters)

    def _choose(self, state: TrackState, rows: np.ndarray, dist: np.ndarray) -> int:
        """Index into ``rows`` of the candidate to use (Eq. 2, or Eq. 1 at a track's start)."""
        if state.n_history == 0:
            return int(np.argmin(dist))
        costs = temporal_costs(self.db_quats, self.clip_first, self.yaw_quats, rows // self.n_yaws,
                               rows % self.n_yaws, state.history, state.n_history,
                               self.window_weights, self.joint_weights)
        return int(np.argmin(costs + self.config.weight_2d * dist))

    def _root_view(self, frame: int, yaw_deg: float, points_px: np.ndarray, visible: np.ndarray) -> np.ndarray:
        """Pelvis position in the view frame for a 1.75 m body, from the image by a pinhole model."""
        return root_from_image(self.db.positions[frame], yaw_deg, points_px, visible,
                               self.config.focal_px, *self.center_px)

    def _end(self, track: int) -> None:
        state = self.tracks.pop(track, None)
        if state is not None and len(state.recording):
            state.recording.static = state.stillness.static
            self.finished.append(state.recording)

    def _end_all(self) -> None:
        for track in self.tracker.finish():
            self._end(track)
        for track in list(self.tracks):
            self._end(track)

    def open_recordings(self) -> list[TrackRecording]:
        """The recordings of the tracks still open (``static`` says whether they are so far)."""
        for state in self.tracks.values():
            state.recording.static = state.stillness.static
        return [s.recording for s in self.tracks.values() if len(s.recording)]

    def cut_recordings(self, max_frames: int) -> list[TrackRecording]:
        """The recordings of open tracks that reached ``max_frames`` frames (``static`` set so far),
        each replaced by an empty one (next ``part``): no recording grows beyond ``max_frames``."""
        cut = []
        for state in self.tracks.values():
            rec = state.recording
            if len(rec) >= max_frames:
                rec.static = state.stillness.static
                state.recording = TrackRecording(rec.track, state.last_frame + 1, part=rec.part + 1,
                                                 camera_px=rec.camera_px)
                cut.append(rec)
        return cut

    def pop_finished(self) -> list[TrackRecording]:
        """The recordings of the tracks ended since the last call; the engine forgets them."""
        done, self.finished = self.finished, []
        return done

    def finish(self) -> list[TrackRecording]:
        """End every track; returns the recordings not yet popped (ended earlier or now), by track id."""
        self._end_all()
        return sorted(self.finished, key=lambda r: r.track)


def _check_frame_major(db: MotionDatabase) -> None:
    """Projections must be frame-major (row = frame × yaws + yaw), as the builder writes them."""
    n = len(db.meta["yaws_deg"])
    if db.proj_yaw is None:  # loaded from its search index, which holds one projection per frame and yaw
        return
    if db.n_projections != db.n_frames * n or not np.array_equal(db.proj_yaw[:n], np.arange(n)):
        raise DatabaseError("projections are not one per (frame, yaw) in frame-major order; rebuild the database")


@njit(cache=True)
def root_from_image(positions_m, yaw_deg, points_px, visible, focal_px, cx, cy) -> np.ndarray:
    """The pelvis in the view frame (metres) seen at the image's pelvis with the image's size.

    Depth = focal × (box diagonal of the matched skeleton's visible joints turned by its yaw, in
    the image plane, metres) / (box diagonal of the visible keypoints, pixels); then x, y from the
    pelvis pixel through the pinhole model (principal point cx, cy).
    """
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    yaw_mat = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # as geometry.yaw_matrix
    lo_m, hi_m = np.full(2, np.inf), np.full(2, -np.inf)
    lo_px, hi_px = np.full(2, np.inf), np.full(2, -np.inf)
    pelvis, n_hips = np.zeros(2), 0
    for k in range(N_KEYPOINTS_2D):
        if not visible[k]:
            continue
        rel = positions_m[k] - positions_m[PELVIS]
        for a in range(2):
            turned = yaw_mat[a, 0] * rel[0] + yaw_mat[a, 1] * rel[1] + yaw_mat[a, 2] * rel[2]
            lo_m[a], hi_m[a] = min(lo_m[a], turned), max(hi_m[a], turned)
            lo_px[a], hi_px[a] = min(lo_px[a], points_px[k, a]), max(hi_px[a], points_px[k, a])
        if k == R_HIP or k == L_HIP:
            pelvis += points_px[k]
            n_hips += 1
    extent_px = max(np.sqrt(np.sum((hi_px - lo_px) ** 2)), 1e-6)
    depth = focal_px * np.sqrt(np.sum((hi_m - lo_m) ** 2)) / extent_px
    pelvis /= max(n_hips, 1)
    return np.array([(pelvis[0] - cx) * depth / focal_px, -(pelvis[1] - cy) * depth / focal_px, -depth])
