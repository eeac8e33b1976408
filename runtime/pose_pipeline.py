"""One person's pose from one detection: retrieve → choose → refine → smooth.

:class:`PosePipeline` holds the database, its search index, the refiner and the engine's
parameters; given a detection and its track's memory (:class:`~mocapdb.runtime.track_state.TrackState`)
it searches the database's projections, makes the temporal choice (Eq. 2), refines the yaw, fits
the pose to the image, smooths it and records it in the track. It knows nothing of other tracks
(those are :mod:`mocapdb.runtime.track_book`'s). Frames: :mod:`mocapdb.runtime.engine`.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from numba import njit

from mocapdb.core.formats.database import DatabaseError, MotionDatabase
from mocapdb.core.geometry import matrix_to_quat, normalize_pose_2d, yaw_matrix
from mocapdb.core.outputs import CAMERA_FROM_VIEW, Match, PersonPose
from mocapdb.core.search_rules import clusters_searched_for, subclusters_searched_for
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D, N_RIG_JOINTS, PELVIS, UNIVERSAL_HEIGHT_M, pose_from_rotations
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.frame_people import Detection
from mocapdb.runtime.head_pose import face_world
from mocapdb.runtime.mesh_head import NO_HEAD_POINTS
from mocapdb.runtime.refine import JointLimits, Refiner, WorldBones
from mocapdb.runtime.search import SearchIndex, search_clustered, search_exact, yaw_offset
from mocapdb.runtime.temporal import temporal_costs, yaw_quaternion, yawed_rotations
from mocapdb.runtime.track_state import NO_EXTREMITIES, NO_HANDS, TrackState
from mocapdb.runtime.world.detector_prior import (
    FIT_BONES,
    FIT_END,
    FIT_START,
    NO_FIT_BONES,
    balance_verticals,
    candidate_costs,
    database_bones,
    level,
    view_joints,
    weighted_bones,
)

R_HIP, L_HIP = KP["r_hip"], KP["l_hip"]  # numba freezes them as constants
ROLL_SEARCH_DEG = np.arange(-40.0, 40.1, 10.0)  # a new track's first keypoints are searched turned by each roll
ROLL_SEED_MARGIN = 0.5  # the best roll seeds the track's estimate where its match is this much nearer than none's
ROLL_SEED_FRAMES = 3    # ... as this many frames' worth of the fit's estimate
MIN_ROLL_SEARCH_POINTS = 8  # visible keypoints a roll search needs


class PosePipeline:
    """Retrieval, temporal choice, refinement and smoothing over one database, for one person at a time."""

    def __init__(self, db: MotionDatabase, config: EngineConfig):
        self.db = db
        self.config = config
        self.index = SearchIndex.from_database(db)
        self.n_clusters = config.n_clusters or clusters_searched_for(db.n_clusters)  # i
        self.subclusters = config.subclusters or subclusters_searched_for(db.n_projections)
        self.db_quats = np.ascontiguousarray(db.quaternions)
        self.clip_first = db.clip_first_frame[db.frame_clip]
        self.yaws_deg = np.asarray(db.meta["yaws_deg"], dtype=np.float64)
        self.yaw_quats = matrix_to_quat(yaw_matrix(self.yaws_deg))
        _check_frame_major(db)
        self.n_yaws = len(self.yaws_deg)
        self.window_weights = np.asarray(config.window_weights, dtype=np.float64)
        weights = config.joint_weights or (1.0,) * N_RIG_JOINTS
        if len(weights) != N_RIG_JOINTS:
            raise ValueError(f"joint_weights needs {N_RIG_JOINTS} values, got {len(weights)}")
        self.joint_weights = np.asarray(weights, dtype=np.float64)
        self.refiner = Refiner(config.refinement, JointLimits.from_rotations(self.db_quats)) if config.refine else None
        # the detector's world landmarks go with the refinement: without it the engine is the published method
        self.db_bones = database_bones(db.positions) if config.world_prior > 0 and config.refine else None
        self.world_fit = config.refinement.world if config.refine else 0.0

    def warm_up(self, points_px: np.ndarray, confidence: np.ndarray) -> None:
        """Run every compiled kernel on a pose ``[14, 2]`` px (two frames of a throw-away track)."""
        state = TrackState(-1, 0, self.config, len(self.window_weights))
        for i in range(2):
            self._person(state, Detection(i, i / self.config.fps, points_px, confidence, NO_EXTREMITIES))

    def pose(self, state: TrackState, detection: Detection) -> PersonPose:
        """The pose of one detection of the track whose memory is ``state``, recorded in it."""
        if state.keypoints is not None:
            d = detection
            detection = replace(d, points_px=state.keypoints(d.points_px, d.confidence, d.t_s))
        return self._person(state, detection)

    def search(self, query: np.ndarray, visible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The candidates' projection rows and Eq. 1 distances for a normalised 2D pose ``query``."""
        cfg = self.config
        if cfg.search == "exact":
            return search_exact(self.index, query, visible, self.n_clusters * cfg.per_cluster)
        return search_clustered(self.index, query, visible, self.n_clusters, cfg.per_cluster, cfg.grid_descents,
                                self.subclusters)

    def _person(self, state: TrackState, d: Detection) -> PersonPose:
        """Retrieve, refine, smooth and record one detection (its keypoints already cleaned)."""
        rerank, fit_world = self._world(state, d)
        bones = None if fit_world is None else np.column_stack([fit_world.directions, fit_world.weights])
        if bones is not None:
            state.verticals.extend(balance_verticals(bones[None], state.up))
        quats, root_view, match = self._retrieve(state, d.points_px, d.confidence > 0, rerank)
        if self.refiner is not None:
            root_view = self._fit(self.refiner, state, quats, root_view, d, fit_world)
        if not self.config.translation:
            root_view = np.zeros(3)
        state.remember(quats)
        fit = None
        face_world_m = face_world(d.world_m, d.extremities_world_m)
        if self.config.keep_take:
            fit = (quats.copy(), root_view.copy(), np.column_stack([d.points_px, d.confidence]), d.extremities,
                   NO_FIT_BONES if bones is None else bones, face_world_m,
                   NO_HANDS if d.hands_px is None else d.hands_px, NO_HEAD_POINTS if d.mesh_px is None else d.mesh_px)
        if self.config.smoothing:
            quats = state.rotations(quats, d.t_s)
            root_view = state.root(root_view, d.t_s)
        shapes = None if d.blend_shapes is None else state.blend_shapes(d.blend_shapes, d.t_s)
        state.record(d.frame_index, d.t_s, quats, root_view, fit)
        joints_view = pose_from_rotations(quats[None], root_view[None], state.scale, state.offsets_m)[0]
        return PersonPose(state.recording.track, joints_view * CAMERA_FROM_VIEW, quats,
                          root_view * CAMERA_FROM_VIEW, match, state.scale * UNIVERSAL_HEIGHT_M,
                          state.proportions_m * state.scale, up_view=state.up,
                          keypoints_px=np.column_stack([d.points_px, d.confidence]), extremities_px=d.extremities,
                          face_world_m=face_world_m, hands_px=d.hands_px, blend_shapes=shapes, mesh_px=d.mesh_px)

    def _world(self, state: TrackState, d: Detection
               ) -> tuple[tuple[np.ndarray, np.ndarray] | None, WorldBones | None]:
        """The detector's 3D of ``d`` (:mod:`mocapdb.runtime.world.detector_prior`) as the retrieval's world
        bones and weights (levelled by the track's tilt; None unless ``world_prior``) and the fit's
        (the view frame; None unless ``refinement.world``); each bone weighted by its confidence, its
        agreement with the frame before and the weight asked for."""
        if (self.db_bones is None and self.world_fit <= 0) or d.world_m is None:
            return None, None
        joints, conf = view_joints(d.world_m, d.points_px, d.confidence, self.config.focal_px, self.config.center_px)
        previous = state.world_joints if state.world_frame == d.frame_index - 1 else None
        state.world_joints, state.world_frame = joints, d.frame_index
        rerank = fit = None
        if self.db_bones is not None:
            up = state.tilt.up
            bones, weights = weighted_bones(level(joints, up), conf, None if previous is None else level(previous, up))
            rerank = bones, self.config.world_prior * weights
        if self.world_fit > 0:
            bones, weights = weighted_bones(joints, conf, previous, FIT_BONES)
            fit = WorldBones(FIT_START, FIT_END, bones, self.world_fit * weights)
        return rerank, fit

    def _retrieve(self, state: TrackState, points_px: np.ndarray, visible: np.ndarray,
                  world: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, Match]:
        """The method's pose: search, Eq. 2 choice (with ``world``, the world bones and their weights:
        plus the candidates' disagreement with them), yaw refinement. Returns its rotations ``[R, 4]``
        (root turned by the yaw), the root seen at the image's size for the track's body scale,
        and the match. The database's projections are upright: a rolled camera's keypoints are first
        turned upright about the mid-hip by the track's roll estimate (:func:`upright_px`)."""
        if self.config.upright_search:
            if self.refiner is not None and state.tilt.count == 0:
                self._seed_roll(state, points_px, visible)
            points_px = upright_px(points_px, visible, state.tilt.roll_rad)
        query, _, _ = normalize_pose_2d(points_px, visible)
        rows, dist = self.search(query, visible)
        extra = None
        if world is not None and self.db_bones is not None:
            frames = rows // self.n_yaws
            extra = candidate_costs(self.db_bones, frames, self.yaws_deg[rows % self.n_yaws], world[0], world[1])
        best = self._choose(state, rows, dist, extra)
        row = int(rows[best])
        f, v = divmod(row, self.n_yaws)  # rows are frame-major
        yaw_deg = self._refined_yaw(f, v, query, visible)
        quats = yawed_rotations(self.db_quats, f, yaw_quaternion(yaw_deg))
        root_view = self._root_view(f, yaw_deg, points_px, visible) * state.scale
        clip = int(self.db.frame_clip[f])
        return quats, root_view, Match(self.db.clip_name[clip], int(self.db.frame_index[f]), yaw_deg, float(dist[best]))

    def _seed_roll(self, state: TrackState, points_px: np.ndarray, visible: np.ndarray) -> None:
        """A new track's roll estimate from its first keypoints: the turn among :data:`ROLL_SEARCH_DEG`
        whose nearest candidate is nearest, where it beats no turn by :data:`ROLL_SEED_MARGIN`. The fit's
        estimate alone starts level, so a rolled camera's first second is searched tilted, and the
        poses retrieved then lean to make up the rest, which holds the estimate short."""
        if visible.sum() < MIN_ROLL_SEARCH_POINTS:
            return
        nearest = np.array([np.min(self.search(normalize_pose_2d(upright_px(points_px, visible, np.radians(r)),
                                                                 visible)[0], visible)[1], initial=np.inf)
                            for r in ROLL_SEARCH_DEG])
        best = int(np.argmin(nearest))
        if nearest[best] < (1.0 - ROLL_SEED_MARGIN) * nearest[np.argmin(np.abs(ROLL_SEARCH_DEG))]:
            roll = np.radians(ROLL_SEARCH_DEG[best])
            state.tilt.seed(np.array([-np.sin(roll), np.cos(roll), 0.0]), ROLL_SEED_FRAMES)

    def _fit(self, refiner: Refiner, state: TrackState, quats: np.ndarray, root_view: np.ndarray,
             d: Detection, world: WorldBones | None = None) -> np.ndarray:
        """Refine ``quats`` (in place) and the root against the keypoints (and ``world``'s bones);
        with a floor, update the track's body scale. Returns the root (view frame, metres)."""
        focal_px = self.config.focal_px
        upright_root = quats[0].copy()
        state.tilt.tilt_root(upright_root, quats[0])
        retrieved = quats.copy()
        refiner(quats, root_view, state.scale, d.points_px, d.confidence, retrieved,
                state.previous(d.frame_index), focal_px, self.config.center_px, state.offsets_m, world)
        state.tilt.update(quats[0], upright_root)
        state.measure_bones(d.points_px, d.confidence, retrieved, root_view, focal_px)
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

    def _choose(self, state: TrackState, rows: np.ndarray, dist: np.ndarray, extra: np.ndarray | None = None) -> int:
        """Index into ``rows`` of the candidate to use (Eq. 2, or Eq. 1 at a track's start), ``extra``
        (per candidate) added."""
        added = 0.0 if extra is None else extra
        if state.n_history == 0:
            return int(np.argmin(dist + added))
        costs = temporal_costs(self.db_quats, self.clip_first, self.yaw_quats, rows // self.n_yaws,
                               rows % self.n_yaws, state.history, state.n_history,
                               self.window_weights, self.joint_weights)
        return int(np.argmin(costs + self.config.weight_2d * dist + added))

    def _root_view(self, frame: int, yaw_deg: float, points_px: np.ndarray, visible: np.ndarray) -> np.ndarray:
        """Pelvis position in the view frame for a 1.75 m body, from the image by a pinhole model."""
        return root_from_image(self.db.positions[frame], yaw_deg, points_px, visible,
                               self.config.focal_px, *self.config.center_px)


def upright_px(points_px: np.ndarray, visible: np.ndarray, roll_rad: float) -> np.ndarray:
    """Keypoints ``[14, 2]`` (pixels, y down) turned about their mid-hip (the visible hips', else the
    visible points' mean) so that a world up leaning ``roll_rad`` to the image's left (the camera's
    roll, as :attr:`~mocapdb.runtime.world.fuse.World.roll_deg`) points up the image."""
    if roll_rad == 0.0 or not visible.any():
        return points_px
    hips = [k for k in (R_HIP, L_HIP) if visible[k]]
    centre = points_px[hips].mean(axis=0) if hips else points_px[visible].mean(axis=0)
    c, s = np.cos(roll_rad), np.sin(roll_rad)
    return (points_px - centre) @ np.array([[c, s], [-s, c]]) + centre


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
