"""A frame's people as the engine takes them: the usable ones (enough confident joints, a hip, some
extent) as arrays, confidences below the threshold zeroed, and one person's detection."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from mocapdb.core.face_shapes import blend_shapes
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.mesh_head import head_vertices
from mocapdb.runtime.track_state import NO_EXTREMITIES, NO_HANDS

R_HIP, L_HIP = KP["r_hip"], KP["l_hip"]
MIN_EXTENT_PX = 4.0  # a person whose confident keypoints span less is skipped (degenerate)


@dataclass(frozen=True)
class Detection:
    """One person in one frame: keypoints ``[14, 2]`` px, their confidences ``[14]`` (0: missing),
    heels, toes, knuckles and face points ``[E, 3]`` (x px, y px, confidence), the detector's world
    landmarks ``[14, 3]`` and ``[E, 3]`` (``Person.world_m``, ``Person.extremities_world_m``; None without)
    and the hands' points ``[2, 21, 3]`` (x, y, z px; NaN: absent; :func:`hand_points`; None without)."""

    frame_index: int
    t_s: float
    points_px: np.ndarray
    confidence: np.ndarray
    extremities: np.ndarray
    world_m: np.ndarray | None = None
    extremities_world_m: np.ndarray | None = None
    hands_px: np.ndarray | None = None
    blend_shapes: np.ndarray | None = None   # [3] face_shapes.BLEND_SHAPES (NaN: no face this frame; None: no faces)
    mesh_px: np.ndarray | None = None   # [N_HEAD, 3] the face mesh's head vertices (mesh_head; NaN: none; None: none)


@dataclass(frozen=True)
class FramePeople:
    """A frame's usable people ``[N, ...]`` (as :class:`Detection`), and how many were skipped:
    ``skipped`` all, ``degenerate`` those among them whose keypoints span less than MIN_EXTENT_PX."""

    frame_index: int
    t_s: float
    points_px: np.ndarray    # [N, 14, 2]
    confidence: np.ndarray   # [N, 14]
    extremities: np.ndarray  # [N, 8, 3]
    skipped: int = 0
    degenerate: int = 0
    world_m: tuple[np.ndarray | None, ...] = ()   # per person, its world landmarks [14, 3] or None
    extremities_world_m: tuple[np.ndarray | None, ...] = ()   # per person, its extremities' [E, 3] or None
    hands_px: tuple[np.ndarray, ...] = ()   # per person, its hands' points [2, 21, 3] (hand_points)
    blend_shapes: tuple[np.ndarray | None, ...] = ()   # per person, its face's blend shapes [3] or None
    mesh_px: tuple[np.ndarray | None, ...] = ()   # per person, its face mesh's head vertices [N_HEAD, 3] or None

    def detection(self, person: int) -> Detection:
        """The ``person``-th usable person's detection."""
        return Detection(self.frame_index, self.t_s, self.points_px[person], self.confidence[person],
                         self.extremities[person], self.world_m[person] if self.world_m else None,
                         self.extremities_world_m[person] if self.extremities_world_m else None,
                         self.hands_px[person] if self.hands_px else None,
                         self.blend_shapes[person] if self.blend_shapes else None,
                         self.mesh_px[person] if self.mesh_px else None)


def usable_people(frame: KeypointFrame, config: EngineConfig) -> FramePeople:
    """The people of ``frame`` the engine can use, at the frame's time (default ``index / fps``)."""
    threshold = config.confidence_threshold
    t_s = frame.time_s if frame.time_s is not None else frame.index / config.fps
    kinds = [_kind(p, config) for p in frame.people]
    people = [p for p, kind in zip(frame.people, kinds) if kind == "usable"]
    points = np.array([p.points_px for p in people]).reshape(-1, N_KEYPOINTS_2D, 2)
    conf = np.array([p.confidence for p in people]).reshape(-1, N_KEYPOINTS_2D)
    conf = np.where(conf >= threshold, conf, 0.0)
    extremities = np.array([_extremities(p, threshold) for p in people]).reshape(-1, len(EXTREMITIES), 3)
    return FramePeople(frame.index, t_s, points, conf, extremities, len(frame.people) - len(people),
                       kinds.count("degenerate"), tuple(p.world_m for p in people),
                       tuple(p.extremities_world_m for p in people), tuple(hand_points(p) for p in people),
                       tuple(None if p.face is None else blend_shapes(p.face[:, :2]) for p in people),
                       tuple(None if p.face is None else head_vertices(p.face) for p in people))


def _kind(person: Person, config: EngineConfig) -> str:
    """"usable", "skipped" (too few confident joints or no hip) or "degenerate" (all at one point)."""
    vis = person.confidence >= config.confidence_threshold
    if int(vis.sum()) < config.min_joints or not (vis[R_HIP] or vis[L_HIP]):
        return "skipped"
    if _extent_px(person.points_px, vis) < MIN_EXTENT_PX:  # all at one point: no size, no depth
        return "degenerate"
    return "usable"


def _extremities(person: Person, threshold: float) -> np.ndarray:
    """A person's heels, toes and knuckles ``[8, 3]`` (x px, y px, confidence), those below
    ``threshold`` missing (confidence 0, as the 14 keypoints); all missing without any."""
    if person.extremities is None:
        return NO_EXTREMITIES
    keep = person.extremities[:, 2] >= threshold
    return np.where(keep[:, None], person.extremities, NO_EXTREMITIES)


def hand_points(person: Person) -> np.ndarray:
    """A person's hands ``[2, 21, 3]`` (right, left; x, y, z px, float32: what the whole take needs), a hand
    with any point missing (confidence 0, or no depth) absent: all NaN; :data:`NO_HANDS` without hands."""
    if person.hands is None:
        return NO_HANDS
    points = person.hands[..., :3]
    found = (person.hands[..., 3] > 0).all(axis=-1) & np.isfinite(points).all(axis=(-2, -1))
    return np.where(found[:, None, None], points, np.nan).astype(np.float32)


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
