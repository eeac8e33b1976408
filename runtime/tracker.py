"""Associates the people detected in successive frames into tracks with stable ids.

Each frame's detections (14 OpenPose keypoints per person, see :mod:`mocapdb.core.skeleton`) are
matched to the tracks by a scale-free cost, gated, and solved with the Hungarian algorithm;
confirmed tracks are matched first, tentative ones then take what is left. A track predicts its
keypoints by a constant velocity (of the joints it shares with each new detection, smoothed), so
brief dropouts and people crossing paths keep their ids.

Lifecycle: an unmatched detection starts a tentative track (that detection is its first hit);
``min_hits`` consecutive hits confirm it and give it the next id (ids only increase and are never
reused); a tentative track that misses a frame is dropped; a confirmed track unmatched for more
than ``max_missing`` frames ends. The update that confirms a track also gives its detections in the
``min_hits - 1`` frames before (:attr:`TrackUpdate.earlier`), so that a caller can take the track
from its first detection although it reports it from its confirmation. New tracks are created left
to right (then top to bottom) by box centre, so ids do not depend on the order of the detections in
the input.

Limits (:meth:`Tracker.update`'s ``max_tracks``, ``max_new``): while ``max_tracks`` tracks (tentative
included) live on, a further detection starts no track; a tentative track with enough hits waits,
unconfirmed and without output, while confirming it would exceed ``max_new``. Both are counted.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np
from numba import njit
from scipy.optimize import linear_sum_assignment

from mocapdb.core.skeleton import N_KEYPOINTS_2D

_BOX_SHIFT = np.array([[1.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, -1.0]])  # (dx, dy) -> signed box
_GATED = 1e6  # cost of a gated pair: finite, so the solver stays feasible; such pairs are dropped


@dataclass(frozen=True)
class TrackerConfig:
    """Association and lifecycle settings.

    ``min_confidence``: a joint is visible when its confidence exceeds this (0 = missing).
    ``iou_weight``: weight of ``1 - IoU`` of the visible-joint boxes, added to the mean joint
    distance in units of the track's box size. ``max_cost``: the gate; pairs above never match.
    ``velocity_smoothing``: weight of each new velocity measurement (exponential smoothing).
    """

    min_hits: int = 2
    max_missing: int = 10
    min_joints: int = 6
    min_confidence: float = 0.0
    iou_weight: float = 0.5
    max_cost: float = 1.0
    velocity_smoothing: float = 0.5


@dataclass
class TrackUpdate:
    """Outcome of one frame.

    ``assignments``: ``(track_id, detection index)`` of every confirmed track matched this frame
    (including one confirmed on this frame), by track id. ``started``/``ended``: track ids.
    ``earlier``: per track confirmed this frame, its detection indices in the ``min_hits - 1`` frames
    before, oldest first (the hits that made it; a track that waited for ``max_new``: the last ones).
    ``over_max_tracks``/``over_max_new``: detections not tracked because of either limit.
    """

    assignments: list[tuple[int, int]] = field(default_factory=list)
    started: list[int] = field(default_factory=list)
    earlier: dict[int, list[int]] = field(default_factory=dict)
    ended: list[int] = field(default_factory=list)
    over_max_tracks: int = 0
    over_max_new: int = 0


@dataclass
class _People:
    """Keypoints of several people and the signed boxes of their visible joints."""

    points: np.ndarray   # [N, 14, 2] pixels, 0 where not visible
    visible: np.ndarray  # [N, 14] bool
    box: np.ndarray      # [N, 4] (min x, min y, -max x, -max y): one min-reduction finds it and
                         # an element-wise maximum of two is their intersection

    @classmethod
    def of(cls, points: np.ndarray, visible: np.ndarray) -> _People:
        masked, box = _masked_boxes(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(visible))
        return cls(masked, visible, box)

    def moved(self, shift: np.ndarray) -> _People:
        """The same people translated by ``shift [N, 2]`` pixels."""
        return _People(self.points + shift[:, None], self.visible, self.box + shift @ _BOX_SHIFT)


@dataclass
class _Tracks(_People):
    """All live tracks as parallel arrays, rows in creation order; keypoints of the last match."""

    ids: np.ndarray        # [T] int, -1 while tentative
    velocity: np.ndarray   # [T, 2] pixels/s
    t_s: np.ndarray        # [T] time of the last match
    hits: np.ndarray       # [T] consecutive matches
    gain: np.ndarray       # [T] weight of the next velocity measurement (1 for the first)
    missing: np.ndarray    # [T] frames since the last match
    detection: np.ndarray  # [T] detection matched this frame, -1 if none
    inputs: np.ndarray     # [T, H] input indices of the last H matches (H = min_hits), oldest first; -1: none

    @classmethod
    def start(cls, people: _People, detection: np.ndarray, t_s: float, inputs: np.ndarray, hits: int) -> _Tracks:
        """New tentative tracks of ``detection`` (input indices ``inputs``), keeping ``hits`` matches."""
        n = len(detection)
        recent = np.full((n, hits), -1, dtype=np.int64)
        recent[:, -1] = inputs
        return cls(people.points, people.visible, people.box, np.full(n, -1), np.zeros((n, 2)),
                   np.full(n, float(t_s)), np.ones(n, dtype=np.int64), np.ones(n), np.zeros(n, dtype=np.int64),
                   detection, recent)

    @classmethod
    def empty(cls, hits: int) -> _Tracks:
        none = np.zeros(0, dtype=np.int64)
        return cls.start(_People.of(np.zeros((0, N_KEYPOINTS_2D, 2)), np.zeros((0, N_KEYPOINTS_2D), dtype=bool)),
                         none, 0.0, none, hits)

    def take(self, rows: np.ndarray) -> _Tracks:
        return _Tracks(*(getattr(self, f.name)[rows] for f in fields(self)))

    def extend(self, other: _Tracks) -> _Tracks:
        return _Tracks(*(np.concatenate([getattr(self, f.name), getattr(other, f.name)]) for f in fields(self)))


class Tracker:
    """Tracks people across frames; see the module docstring for the rules."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        self._hits_kept = max(self.config.min_hits, 1)
        self._tracks = _Tracks.empty(self._hits_kept)
        self._next_id = 0
        self._t_s = -np.inf  # time of the last frame

    @property
    def active_ids(self) -> list[int]:
        """Ids of the confirmed tracks still alive (matched recently enough), ascending."""
        ids = self._tracks.ids
        return ids[ids >= 0].tolist()

    def update(self, points: np.ndarray, confidence: np.ndarray, t_s: float, max_tracks: int = 0,
               max_new: int | None = None) -> TrackUpdate:
        """Associate one frame: ``points [P, 14, 2]`` pixels, ``confidence [P, 14]``, time in seconds.

        Times should increase; a frame whose time does not is still associated but leaves the
        tracks' velocities unchanged. Detections with fewer than ``min_joints`` visible joints are
        ignored (detection indices in the result still refer to the input). ``max_tracks``: tracks
        alive at once (0: no limit); ``max_new``: tracks that may be confirmed now (None: any).
        """
        cfg = self.config
        visible = np.asarray(confidence).reshape(-1, N_KEYPOINTS_2D) > cfg.min_confidence
        kept = (visible.sum(axis=1) >= cfg.min_joints).nonzero()[0]
        points = np.asarray(points, dtype=np.float64).reshape(-1, N_KEYPOINTS_2D, 2)
        if len(points) != len(visible):
            raise ValueError(f"{len(points)} keypoint sets but {len(visible)} confidence rows")
        if len(kept) < len(visible):
            points, visible = points[kept], visible[kept]
        dets = _People.of(points, visible)
        rows, cols = self._match(dets, t_s)
        over_max_tracks = self._advance(rows, cols, dets, kept, t_s, max_tracks)
        self._t_s = max(self._t_s, t_s)
        started, earlier, over_max_new = self._confirm(max_new)
        tr = self._tracks
        assigned = ((tr.ids >= 0) & (tr.detection >= 0)).nonzero()[0]  # rows, hence ids, ascending
        assignments = list(zip(tr.ids[assigned].tolist(), kept[tr.detection[assigned]].tolist()))
        return TrackUpdate(assignments, started, earlier, self._prune(), over_max_tracks, over_max_new)

    def finish(self) -> list[int]:
        """End every track (end of stream); returns the ids of the confirmed ones."""
        ended = self.active_ids
        self._tracks = _Tracks.empty(self._hits_kept)
        self._t_s = -np.inf
        return ended

    def _match(self, dets: _People, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Matched ``(track rows, detection columns)`` by ascending row; confirmed tracks choose first."""
        tr = self._tracks
        predicted = tr.moved(tr.velocity * (t_s - tr.t_s)[:, None])  # constant velocity
        cost = _cost(predicted, dets, self.config)
        confirmed = tr.ids >= 0
        if confirmed.all():
            return _assign(cost)
        first, second = confirmed.nonzero()[0], (~confirmed).nonzero()[0]
        rows, cols = _assign(cost[first])
        free = np.ones(len(dets.points), dtype=bool)
        free[cols] = False
        free = free.nonzero()[0]
        rows2, cols2 = _assign(cost[np.ix_(second, free)])
        rows, cols = np.concatenate([first[rows], second[rows2]]), np.concatenate([cols, free[cols2]])
        order = np.argsort(rows)
        return rows[order], cols[order]

    def _advance(self, rows: np.ndarray, cols: np.ndarray, dets: _People, inputs: np.ndarray, t_s: float,
                 max_tracks: int) -> int:
        """Move matched tracks to their detections (input indices ``inputs``), age the others, start
        tracks for the rest (while fewer than ``max_tracks`` live on); returns how many detections got
        no track for that limit."""
        tr = self._tracks
        _advance_matched(tr.points, tr.visible, tr.box, tr.t_s, tr.velocity, tr.gain, tr.hits, tr.missing,
                         tr.detection, rows, cols, dets.points, dets.visible, dets.box, t_s,
                         t_s > self._t_s, self.config.velocity_smoothing)
        tr.inputs[rows] = np.column_stack([tr.inputs[rows, 1:], inputs[cols]])
        if len(cols) == len(dets.points):
            return 0
        new = np.ones(len(dets.points), dtype=bool)
        new[cols] = False
        new = new.nonzero()[0]
        centre = dets.box[new, :2] - dets.box[new, 2:]  # twice the box centre
        new = new[np.lexsort((centre[:, 1], centre[:, 0]))]  # left to right: input order is irrelevant
        n_new = len(new)
        if max_tracks:
            staying = (tr.detection >= 0) | ((tr.ids >= 0) & (tr.missing <= self.config.max_missing))
            new = new[:max(max_tracks - int(staying.sum()), 0)]
        if len(new):
            self._tracks = tr.extend(_Tracks.start(_People(dets.points[new], dets.visible[new], dets.box[new]),
                                                   new, t_s, inputs[new], self._hits_kept))
        return n_new - len(new)

    def _confirm(self, max_new: int | None) -> tuple[list[int], dict[int, list[int]], int]:
        """Give ids, in creation order, to matched tentative tracks with enough hits, at most
        ``max_new`` of them; returns their ids, their earlier detections (:attr:`TrackUpdate.earlier`)
        and how many wait."""
        tr = self._tracks
        rows = ((tr.ids < 0) & (tr.hits >= self.config.min_hits) & (tr.detection >= 0)).nonzero()[0]
        waiting = 0 if max_new is None else max(len(rows) - max_new, 0)
        rows = rows[:len(rows) - waiting]
        tr.ids[rows] = np.arange(self._next_id, self._next_id + len(rows))
        self._next_id += len(rows)
        ids = tr.ids[rows].tolist()
        return ids, {i: [d for d in tr.inputs[r, :-1].tolist() if d >= 0] for i, r in zip(ids, rows)}, waiting

    def _prune(self) -> list[int]:
        """Drop expired confirmed tracks and unmatched tentative ones; returns the expired ids."""
        tr = self._tracks
        expired = (tr.ids >= 0) & (tr.missing > self.config.max_missing)
        dropped = expired | ((tr.ids < 0) & (tr.detection < 0))
        if not dropped.any():
            return []
        ended = tr.ids[expired].tolist()
        self._tracks = tr.take(~dropped)
        return ended


def _cost(tracks: _People, dets: _People, cfg: TrackerConfig) -> np.ndarray:
    """Cost ``[T, D]``: mean distance of shared joints / track box size + ``iou_weight (1 - IoU)``.

    The box size is its height, or its width if larger (a lying person). Pairs above the gate,
    or sharing no visible joint, cost ``_GATED``.
    """
    return _cost_kernel(tracks.points, tracks.visible, tracks.box, dets.points, dets.visible, dets.box,
                        cfg.iou_weight, cfg.max_cost)


@njit(cache=True)
def _advance_matched(points, visible, box, t_last, velocity, gain, hits, missing, detection, rows, cols,
                     d_points, d_visible, d_box, t_s, update_velocity, smoothing):
    """In place: tracks ``rows`` take detections ``cols``; every other track ages by a frame.

    The velocity measurement is the mean shift of the joints visible in both, per second; a
    frame whose time did not advance leaves velocities as they are.
    """
    detection[:] = -1
    missing += 1
    for n in range(rows.shape[0]):
        r, c = rows[n], cols[n]
        detection[r] = c
        if update_velocity:
            shift_x, shift_y, shared = 0.0, 0.0, 0
            for k in range(points.shape[1]):
                if visible[r, k] and d_visible[c, k]:
                    shift_x += d_points[c, k, 0] - points[r, k, 0]
                    shift_y += d_points[c, k, 1] - points[r, k, 1]
                    shared += 1
            per_s = 1.0 / ((t_s - t_last[r]) * max(shared, 1))
            velocity[r, 0] += gain[r] * (shift_x * per_s - velocity[r, 0])
            velocity[r, 1] += gain[r] * (shift_y * per_s - velocity[r, 1])
            gain[r] = smoothing
        points[r], visible[r], box[r] = d_points[c], d_visible[c], d_box[c]
        t_last[r] = t_s
        hits[r] += 1
        missing[r] = 0


@njit(cache=True)
def _masked_boxes(points, visible):
    """Points with invisible joints zeroed, and the signed boxes of the visible ones."""
    masked = np.zeros_like(points)
    box = np.full((points.shape[0], 4), np.inf)
    for n in range(points.shape[0]):
        for k in range(points.shape[1]):
            if visible[n, k]:
                x, y = points[n, k, 0], points[n, k, 1]
                masked[n, k, 0], masked[n, k, 1] = x, y
                box[n, 0], box[n, 1] = min(box[n, 0], x), min(box[n, 1], y)
                box[n, 2], box[n, 3] = min(box[n, 2], -x), min(box[n, 3], -y)
    return masked, box


@njit(cache=True)
def _cost_kernel(t_points, t_visible, t_box, d_points, d_visible, d_box, iou_weight, max_cost):
    cost = np.full((t_points.shape[0], d_points.shape[0]), _GATED)
    for i in range(t_points.shape[0]):
        t_w, t_h = -(t_box[i, 0] + t_box[i, 2]), -(t_box[i, 1] + t_box[i, 3])
        scale = max(max(t_w, t_h), 1.0)
        for j in range(d_points.shape[0]):
            total, shared = 0.0, 0
            for k in range(t_points.shape[1]):
                if t_visible[i, k] and d_visible[j, k]:
                    total += np.hypot(t_points[i, k, 0] - d_points[j, k, 0], t_points[i, k, 1] - d_points[j, k, 1])
                    shared += 1
            if shared == 0:
                continue
            # Signed boxes: the element-wise maximum is the intersection, minus its width/height.
            over_w = min(max(t_box[i, 0], d_box[j, 0]) + max(t_box[i, 2], d_box[j, 2]), 0.0)
            over_h = min(max(t_box[i, 1], d_box[j, 1]) + max(t_box[i, 3], d_box[j, 3]), 0.0)
            inter = over_w * over_h
            d_w, d_h = -(d_box[j, 0] + d_box[j, 2]), -(d_box[j, 1] + d_box[j, 3])
            union = t_w * t_h + d_w * d_h - inter
            c = total / (shared * scale) + iou_weight * (1.0 - inter / max(union, 1e-9))
            if c <= max_cost:
                cost[i, j] = c
    return cost


def _assign(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hungarian assignment of a gated cost matrix without the gated pairs, as (rows, cols)."""
    rows, cols = linear_sum_assignment(cost)
    ok = cost[rows, cols] < _GATED
    return rows[ok], cols[ok]
