"""The camera from the room's lines (issue 51, item 1): vanishing points of the line segments
``detect`` found outside the people (:class:`~mocapdb.core.formats.scene.SceneLines`).

Lines parallel in the world meet in the image at their vanishing point, the image of their common
direction. The vertical's vanishing point is the world's up seen by the camera: its pitch and roll.
Two orthogonal directions' points ``v₁``, ``v₂`` (pixels about the principal point, taken as the
image's centre) fix the focal length: their rays are orthogonal, ``v₁ · v₂ + f² = 0``.

* **Points by RANSAC** (:func:`ransac_point`): hypotheses are the crossings of random pairs of
  segments (drawn by length); a segment supports a point when the line from its mid-point to the
  point is within :data:`INLIER_DEG` of its own direction (works for points at infinity); the best
  supported (summed length) is refined by least squares (:func:`fit_point`: the homogeneous point
  closest to the inliers' lines, weighted by length) at ever tighter thresholds
  (:data:`REFINE_DEG`). The :data:`MAX_POINTS` strongest are found one after another, each on the
  segments the others left, each with :data:`MIN_INLIERS` segments a frame.
* **Which point is the vertical** (:meth:`SceneVanishing.tilt`): of those, the nearest within a
  cone about a prior up (:class:`SceneEvidence`: the people's, :data:`PEOPLE_CONE_DEG`; without
  people the image's up, :data:`LEVEL_CONE_DEG`). Floor lines receding towards the horizon meet
  90° from the up.
* **The up** (:meth:`SceneVanishing._manhattan_up`): the direction lying in the vertical segments'
  planes through the camera and square to up to two horizontal points (a room's walls: RANSAC
  within :data:`HORIZON_CONE_DEG` of square), fitted together. A floor edge receding straight
  ahead looks vertical in the image; pointing at a horizontal point, it does not count for the
  vertical. On the balancing take's camera 2 the vertical point alone read the pitch 13.1° for a
  true 18.2°, the joint fit 18.2°.
* **Uncertainty**: a bootstrap (:data:`BOOTSTRAP`) of the vertical's segments and the horizontal
  points' draws, each draw as many segments as one frame holds (a still camera's frames repeat
  the same lines: they are not new evidence); the tilt's SD is the draws' spread in pitch and
  roll, with the focal's error and :data:`SYSTEMATIC_DEG` in quadrature (door frames and shelves
  are not perfectly vertical, LSD's angles ~0.5°).
* **The focal** (:meth:`SceneVanishing.focal`): the focal that makes three of the points' rays
  most nearly orthogonal (a log grid), kept when their RMS angle off orthogonal is within
  :data:`ORTHOGONAL_TOL_DEG` and the focal inside :data:`FOCAL_RANGE`; its SD from the draws.

Costs: :data:`HYPOTHESES` per point against at most 15 000 segments (60 frames × 256), vectorised:
0.1 s (one sampled frame) to 2.1 s (60 frames) a take, once, at the world's fit.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from mocapdb.core.formats.scene import SceneLines

INLIER_DEG = 1.5            # a segment within this of the direction to the point supports it
REFINE_DEG = (1.5, 1.0, 0.75, 0.75)  # the refits' inlier thresholds, ever tighter (lines' noise: ~0.5°)
HYPOTHESES = 400            # RANSAC hypotheses per point
MIN_INLIERS = 8             # segments a frame a point needs (6-7.5 gave wrong verticals on turned real frames)
MAX_POINTS = 4              # vanishing points looked for (a room: the vertical, two walls, one more)
MAX_HORIZONTAL = 2          # horizontal points fitted with the vertical (two walls)
HORIZON_CONE_DEG = 15.0     # a horizontal point's ray within this of square to the vertical's first fit
HORIZON_TOL_DEG = 5.0       # and within this of square to the joint fit, or it is dropped
LINE_SD_DEG = 0.5           # a segment's angle error out of its true direction (LSD on real frames: ~0.5° median)
MIN_POINT_SD_DEG = 0.1      # a horizontal point's direction is known no better than this
PEOPLE_CONE_DEG = 30.0      # the vertical's ray within this of the people's up (theirs is off up to ~22°)
LEVEL_CONE_DEG = 40.0       # without people, within this of the image's up (a camera tilted less)
BOOTSTRAP = 64              # draws for the points' uncertainty
SYSTEMATIC_DEG = 0.7        # the lines' own error, in quadrature with the draws' spread (degrees)
ORTHOGONAL_TOL_DEG = 1.0    # RMS angle off orthogonal of the three rays at the best focal (real rooms: 0.5-0.8°)
FOCAL_RANGE = (0.3, 5.0)    # the focal (pixels) over the image's long side
_FOCAL_GRID = np.exp(np.linspace(np.log(FOCAL_RANGE[0]), np.log(FOCAL_RANGE[1]), 801))


@dataclass(frozen=True)
class VanishingPoint:
    """A vanishing point: ``point`` the homogeneous unit 3-vector in the scene's normalised image
    coordinates (pixels about the image's centre over half its long side), its bootstrap draws
    ``draws [B, 3]`` (same sign as ``point``) and the segments that support it (their count over the
    frames: ``per_frame``)."""

    point: np.ndarray
    draws: np.ndarray
    inliers: int
    per_frame: float


@dataclass(frozen=True)
class SceneTilt:
    """The world's up the scene shows: ``up`` (unit, view frame: x right, y up, z towards the
    viewer), its pitch and roll (degrees, as :class:`~mocapdb.runtime.world.fuse.World` defines
    them) and their errors (degrees), and the vertical's segments (count over the frames)."""

    up: np.ndarray
    pitch_deg: float
    roll_deg: float
    pitch_sd_deg: float
    roll_sd_deg: float
    segments_per_frame: float


@dataclass(frozen=True)
class SceneFocal:
    """The focal length the scene's orthogonal vanishing points give (pixels) and its SD (pixels)."""

    focal_px: float
    sd_px: float


def normalised_segments(scene: SceneLines) -> tuple[np.ndarray, np.ndarray, float]:
    """The scene's segments ``[N, 4]`` in normalised coordinates (pixels about the image's centre
    over half its long side), their lengths in those units, and that half side (pixels)."""
    width, height = scene.image_size
    half = max(width, height) / 2.0
    seg = (scene.all_segments() - np.array([width, height, width, height]) / 2.0) / half
    return seg, np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]), half


def segment_lines(segments: np.ndarray) -> np.ndarray:
    """Homogeneous lines ``[N, 3]`` through segments ``[N, 4]``, scaled so their normal (a, b) is unit."""
    p = np.column_stack([segments[:, :2], np.ones(len(segments))])
    q = np.column_stack([segments[:, 2:], np.ones(len(segments))])
    lines = np.cross(p, q)
    return lines / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)


def angle_to_points_deg(segments: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``[H, N]`` the angle (degrees, 0-90) between each segment ``[N, 4]`` and the line from its
    mid-point to each homogeneous point ``points [H, 3]`` (a point at infinity: its direction)."""
    mid = 0.5 * (segments[:, :2] + segments[:, 2:])
    d = segments[:, 2:] - segments[:, :2]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    ux = points[:, None, 0] - points[:, None, 2] * mid[None, :, 0]
    uy = points[:, None, 1] - points[:, None, 2] * mid[None, :, 1]
    sine = np.abs(d[None, :, 0] * uy - d[None, :, 1] * ux) / np.maximum(np.hypot(ux, uy), 1e-12)
    return np.degrees(np.arcsin(np.clip(sine, 0.0, 1.0)))


def fit_point(lines: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The homogeneous unit point ``[3]`` (or ``[B, 3]`` for ``weights [B, N]``) nearest the lines
    ``[N, 3]`` in the weighted least-squares sense: the smallest eigenvector of ``Σ w l lᵀ``."""
    scatter = np.einsum("...n,ni,nj->...ij", weights, lines, lines)
    return np.linalg.eigh(scatter)[1][..., :, 0]


def ransac_point(segments: np.ndarray, lengths: np.ndarray, rng: np.random.Generator,
                 accept=None) -> tuple[np.ndarray, np.ndarray] | None:
    """The best supported vanishing point of ``segments [N, 4]`` (:func:`angle_to_points_deg` within
    :data:`INLIER_DEG`, support their summed ``lengths``) among hypotheses (crossings of pairs drawn
    by length) that ``accept`` lets through (a function of points ``[H, 3]`` → bool ``[H]``; None:
    all), refined on its inliers (:data:`REFINE_DEG`): the point (homogeneous unit) and its
    inliers' mask; None with fewer than two segments."""
    if len(segments) < 2:
        return None
    lines = segment_lines(segments)
    pairs = rng.choice(len(segments), size=(HYPOTHESES, 2), p=lengths / lengths.sum())
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    hyp = np.cross(lines[pairs[:, 0]], lines[pairs[:, 1]])
    norm = np.linalg.norm(hyp, axis=1, keepdims=True)
    hyp = hyp[norm[:, 0] > 1e-12] / norm[norm[:, 0] > 1e-12]   # one line drawn twice crosses nowhere
    if accept is not None:
        hyp = hyp[accept(hyp)]
    if not len(hyp):
        return None
    support = ((angle_to_points_deg(segments, hyp) < INLIER_DEG) * lengths).sum(axis=1)
    point = hyp[int(np.argmax(support))]
    for threshold in REFINE_DEG:
        inliers = angle_to_points_deg(segments, point[None])[0] < threshold
        if inliers.sum() < 2:
            return None
        point = _same_sign(fit_point(lines[inliers], lengths[inliers]), point)
    return point, angle_to_points_deg(segments, point[None])[0] < REFINE_DEG[-1]


def _same_sign(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``points [..., 3]`` flipped where needed to point the way of ``reference [3]``."""
    return points * np.where(points @ reference < 0, -1.0, 1.0)[..., None]


def bootstrap_points(segments: np.ndarray, lengths: np.ndarray, point: np.ndarray, frames: int,
                     rng: np.random.Generator) -> np.ndarray:
    """:data:`BOOTSTRAP` refits ``[B, 3]`` of a point on its inliers ``segments``, each a draw (with
    replacement) of as many segments as one of the ``frames`` holds on average."""
    lines = segment_lines(segments)
    size = max(round(len(segments) / max(frames, 1)), 2)
    picks = rng.integers(0, len(segments), size=(BOOTSTRAP, size))
    weights = np.zeros((BOOTSTRAP, len(segments)))
    np.add.at(weights, (np.repeat(np.arange(BOOTSTRAP), size), picks.ravel()), lengths[picks.ravel()])
    return _same_sign(fit_point(lines, weights), point)


def ray_view(points: np.ndarray, half_px: float, focal_px: float) -> np.ndarray:
    """Unit view-frame rays ``[..., 3]`` (x right, y up, z towards the viewer) of homogeneous points
    ``[..., 3]`` in normalised coordinates, for a focal ``focal_px`` (pixels; ``half_px`` the
    normalisation), signed so their y is not negative."""
    k = half_px / focal_px
    ray = np.stack([points[..., 0] * k, -points[..., 1] * k, -points[..., 2]], axis=-1)
    ray = ray / np.linalg.norm(ray, axis=-1, keepdims=True)
    return ray * np.where(ray[..., 1:2] < 0, -1.0, 1.0)


def pitch_roll_deg(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pitch and roll (degrees) of view-frame ups ``[..., 3]`` (:class:`~mocapdb.runtime.world.fuse.World`'s
    definitions: pitch ``atan2(n_z, n_y)``, roll ``atan2(−n_x, n_y)``)."""
    return (np.degrees(np.arctan2(up[..., 2], up[..., 1])), np.degrees(np.arctan2(-up[..., 0], up[..., 1])))


def _orthogonal_focal(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For triples of homogeneous points ``[B, 3, 3]`` (normalised by half the long side), the focal
    of :data:`_FOCAL_GRID` (over the long side) making their rays most nearly orthogonal ``[B]``
    and the RMS angle off orthogonal there (degrees) ``[B]``."""
    f = _FOCAL_GRID[:, None, None] * 2.0                                         # over half the side
    xy = points[None, :, :, :2] / f[..., None]
    rays = np.concatenate([xy, np.broadcast_to(points[None, :, :, 2:], xy.shape[:-1] + (1,))], axis=-1)  # [G, B, 3, 3]
    rays = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    cos = np.stack([(rays[..., i, :] * rays[..., j, :]).sum(-1) for i, j in ((0, 1), (0, 2), (1, 2))], axis=-1)
    off = np.degrees(np.arcsin(np.clip(np.abs(cos), 0.0, 1.0)))                  # [G, B, 3]
    rms = np.sqrt((off ** 2).mean(axis=-1))
    at = np.argmin(rms, axis=0)
    return _FOCAL_GRID[at], rms[at, np.arange(rms.shape[1])]


@dataclass(frozen=True)
class SceneVanishing:
    """A take's line segments (normalised coordinates: pixels about the image's centre over
    ``half_px``, half its long side; their lengths; the frames they came from) and their strongest
    vanishing points (:data:`MAX_POINTS`, found one after another on the segments the earlier ones
    left)."""

    segments: np.ndarray
    lengths: np.ndarray
    half_px: float
    frames: int
    points: tuple[VanishingPoint, ...]

    def focal(self) -> SceneFocal | None:
        """The focal (pixels) making three of the points' rays most nearly orthogonal (a room's
        vertical and two walls), with its SD over the bootstrap draws; None where no three points
        are orthogonal within :data:`ORTHOGONAL_TOL_DEG` at a focal inside :data:`FOCAL_RANGE`."""
        triples = [t for t in combinations(self.points, 3)]
        if not triples:
            return None
        best, misfit = _orthogonal_focal(np.stack([[p.point for p in t] for t in triples]))
        inside = (misfit <= ORTHOGONAL_TOL_DEG) & (best > _FOCAL_GRID[0]) & (best < _FOCAL_GRID[-1])
        if not inside.any():
            return None
        pick = int(np.argmin(np.where(inside, misfit, np.inf)))
        draws, _ = _orthogonal_focal(np.stack([p.draws for p in triples[pick]], axis=1))
        scale = 2.0 * self.half_px
        return SceneFocal(float(best[pick] * scale), float(np.std(np.log(draws)) * best[pick] * scale))

    def tilt(self, focal_px: float, focal_sd_px: float, prior_up: np.ndarray, cone_deg: float,
             seed: int = 0) -> SceneTilt | None:
        """The world's up at ``focal_px``: the vertical's point (:meth:`_vertical`: within ``cone_deg``
        of ``prior_up``, view frame) and the horizon its horizontal points lie on, fitted together
        (:meth:`_manhattan_up`). Its SD: the bootstrap draws' spread in pitch and roll, the focal's
        error ``focal_sd_px`` (its effect at +1 SD) and :data:`SYSTEMATIC_DEG`, in quadrature. None
        where no point in the cone has :data:`MIN_INLIERS` segments a frame."""
        rng = np.random.default_rng(seed)
        vertical = self._vertical(focal_px, np.asarray(prior_up, dtype=np.float64), np.cos(np.radians(cone_deg)))
        if vertical is None:
            return None
        up, draws = self._manhattan_up(vertical, focal_px, rng)
        pitch, roll = pitch_roll_deg(up)
        spread = np.array(pitch_roll_deg(draws)).std(axis=1)
        shifted, _ = self._manhattan_up(vertical, focal_px + focal_sd_px, np.random.default_rng(seed))
        focal_effect = np.abs(np.array(pitch_roll_deg(shifted)) - np.array([pitch, roll]))
        sds = np.sqrt(spread ** 2 + focal_effect ** 2 + SYSTEMATIC_DEG ** 2)
        return SceneTilt(up, float(pitch), float(roll), float(sds[0]), float(sds[1]), vertical.per_frame)

    def _manhattan_up(self, vertical: VanishingPoint, focal_px: float, rng: np.random.Generator
                      ) -> tuple[np.ndarray, np.ndarray]:
        """The up (view frame, unit) and its :data:`BOOTSTRAP` draws ``[B, 3]`` that the vertical's
        segments and the horizontal points fit best: the least-squares direction lying in the
        vertical segments' planes through the camera (each weighted by its length over
        :data:`LINE_SD_DEG`², per frame) and square to the horizontal points' rays (each weighted by
        its draws' inverse variance). A segment that also points at a horizontal point (a floor edge
        receding straight ahead looks vertical) does not count for the vertical; a horizontal point
        more than :data:`HORIZON_TOL_DEG` off square to the first fit is dropped."""
        first = ray_view(vertical.point, self.half_px, focal_px)
        horizontal = self._horizontals(first, focal_px, rng)
        near = angle_to_points_deg(self.segments, np.stack([vertical.point] + [h.point for h in horizontal]))
        own = (near[0] < REFINE_DEG[-1]) & ~(near[1:] < REFINE_DEG[-1]).any(axis=0)
        if own.sum() < 2:
            own = near[0] < REFINE_DEG[-1]
        normals = plane_normals(segment_lines(self.segments[own]), self.half_px, focal_px)
        weights = self.lengths[own] / (self.frames * np.radians(LINE_SD_DEG) ** 2)
        rays = [ray_view(np.vstack([h.point[None], h.draws]), self.half_px, focal_px) for h in horizontal]
        up = _smallest(normals, weights, rays, first)
        rays = [r for r in rays if abs(r[0] @ up) <= np.sin(np.radians(HORIZON_TOL_DEG))]
        up = _smallest(normals, weights, rays, first)
        size = max(round(own.sum() / self.frames), 2)
        counts = rng.multinomial(size, np.full(own.sum(), 1.0 / own.sum()), size=BOOTSTRAP)
        draws = _smallest(normals, counts * self.lengths[own] / np.radians(LINE_SD_DEG) ** 2,
                          [r[1:, None] for r in rays], first)
        return up, draws

    def _horizontals(self, up: np.ndarray, focal_px: float, rng: np.random.Generator) -> list[VanishingPoint]:
        """Up to :data:`MAX_HORIZONTAL` points whose rays lie within :data:`HORIZON_CONE_DEG` of square to
        ``up``, each found on every segment but the earlier horizontals' (a segment ambiguous between
        the vertical and a horizontal may be either)."""
        found: list[VanishingPoint] = []
        rest = np.ones(len(self.segments), dtype=bool)
        limit = np.sin(np.radians(HORIZON_CONE_DEG))
        while len(found) < MAX_HORIZONTAL:
            result = ransac_point(self.segments[rest], self.lengths[rest], rng,
                                  lambda h: np.abs(ray_view(h, self.half_px, focal_px) @ up) <= limit)
            point = _point(self.segments[rest], self.lengths[rest], result, self.frames, rng)
            if point is None or result is None:
                break
            found.append(point)
            rest[np.flatnonzero(rest)[result[1]]] = False
        return found

    def _vertical(self, focal_px: float, prior_up: np.ndarray, min_cos: float) -> VanishingPoint | None:
        """The vertical's point: of the strongest points (:attr:`points`) whose ray (signed up) lies
        within the cone ``min_cos`` (cosine) of ``prior_up``, the nearest; None without one. (A
        RANSAC restricted to the cone found weak clusters of leaning lines there: 20-38° off on
        turned real frames.)"""
        near = [(float(ray_view(p.point, self.half_px, focal_px) @ prior_up), p) for p in self.points]
        near = [(c, p) for c, p in near if c >= min_cos]
        return max(near, key=lambda cp: cp[0])[1] if near else None


def plane_normals(lines: np.ndarray, half_px: float, focal_px: float) -> np.ndarray:
    """Unit normals ``[N, 3]`` (view frame) of the planes through the camera and image lines
    ``[N, 3]`` (homogeneous, normalised coordinates; ``half_px`` the normalisation) at ``focal_px``."""
    k = half_px / focal_px
    normals = np.column_stack([lines[:, 0] / k, -lines[:, 1] / k, -lines[:, 2]])
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _smallest(normals: np.ndarray, weights: np.ndarray, rays: list[np.ndarray], sign: np.ndarray) -> np.ndarray:
    """The unit direction ``[3]`` (``[B, 3]`` for ``weights [B, N]`` and rays ``[B, 1, 3]``) nearest
    to lying in the planes ``normals [N, 3]`` (weights) and square to each horizontal point's rays
    (``rays``: a point's ray first, then its draws; weighted by the draws' inverse variance), signed
    along ``sign``: the smallest eigenvector of the weighted scatter."""
    scatter = np.einsum("...n,ni,nj->...ij", weights, normals, normals)
    for r in rays:
        ray = r[0] if r.ndim == 2 else r[:, 0]
        spread = r[1:] if r.ndim == 2 else r
        variance = max(float(np.mean(1.0 - np.abs(spread.reshape(-1, 3) @ (r[0] if r.ndim == 2 else r[0, 0])) ** 2)),
                       np.radians(MIN_POINT_SD_DEG) ** 2)
        scatter = scatter + np.einsum("...i,...j->...ij", ray, ray) / variance
    return _same_sign(np.linalg.eigh(scatter)[1][..., :, 0], sign)


def vanishing_points(scene: SceneLines, seed: int = 0) -> SceneVanishing:
    """The scene's segments and up to :data:`MAX_POINTS` vanishing points, each by RANSAC on the
    segments the points before left (module docstring)."""
    segments, lengths, half = normalised_segments(scene)
    frames = max(len(scene.frames), 1)
    rng = np.random.default_rng(seed)
    rest = np.ones(len(segments), dtype=bool)
    points: list[VanishingPoint] = []
    while len(points) < MAX_POINTS:
        found = ransac_point(segments[rest], lengths[rest], rng)
        point = _point(segments[rest], lengths[rest], found, frames, rng)
        if point is None or found is None:
            break
        points.append(point)
        rest[np.flatnonzero(rest)[found[1]]] = False
    return SceneVanishing(segments, lengths, half, frames, tuple(points))


def _point(segments: np.ndarray, lengths: np.ndarray, found: tuple[np.ndarray, np.ndarray] | None, frames: int,
           rng: np.random.Generator) -> VanishingPoint | None:
    """A RANSAC result as a :class:`VanishingPoint` with its bootstrap draws; None without
    :data:`MIN_INLIERS` segments a frame."""
    if found is None:
        return None
    point, inliers = found
    per_frame = inliers.sum() / frames
    if per_frame < MIN_INLIERS:
        return None
    draws = bootstrap_points(segments[inliers], lengths[inliers], point, frames, rng)
    return VanishingPoint(point, draws, int(inliers.sum()), float(per_frame))


@dataclass(frozen=True)
class SceneEvidence:
    """The scene's vanishing points with the focal the take runs at (pixels) and its error (pixels:
    0 when given, the scene's own when it gave it, the guess's otherwise)."""

    vanishing: SceneVanishing
    focal_px: float
    focal_sd_px: float

    def tilt(self, prior_up: np.ndarray | None) -> SceneTilt | None:
        """The scene's up (:meth:`SceneVanishing.tilt`): its vertical within :data:`PEOPLE_CONE_DEG`
        of the people's up ``prior_up`` (view frame), or within :data:`LEVEL_CONE_DEG` of the
        image's up without one."""
        if prior_up is None:
            return self.vanishing.tilt(self.focal_px, self.focal_sd_px, np.array([0.0, 1.0, 0.0]), LEVEL_CONE_DEG)
        return self.vanishing.tilt(self.focal_px, self.focal_sd_px, prior_up, PEOPLE_CONE_DEG)
