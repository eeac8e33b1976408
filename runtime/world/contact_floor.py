"""The floor under a track's planted ankles: its plane (:func:`floor_plane`), the contacts on its
lowest level (:func:`lowest_level`), whether contacts lie on one plane (:func:`coplanar_spread`)
and span a floor (:func:`spans_floor`), their steps (:func:`count_steps`), and roots lifted so that
no ankle sinks below it (:func:`above_floor`). Step 4 of the whole-take
fit (:mod:`mocapdb.runtime.take`); the take's world (:mod:`mocapdb.runtime.world.fuse`) uses it too."""
from __future__ import annotations

import numpy as np

MIN_FLOOR_SPREAD_M = 0.3  # RMS extent of the contacts (≈ 1 m end to end) along a direction they fix
MAX_FLOOR_RMS_M = 0.03    # contacts farther off their plane (RMS) are not one floor: their plane is not trusted
FLOOR_BAND_M = 0.15       # contacts within this of the lowest are on the floor; higher: steps (risers 15-20 cm)
FLOOR_MIN_SHARE = 0.25    # the floor holds at least this share of a track's contacts (data_specs/world.md)


def floor_plane(ankles_view_m: np.ndarray, planted: np.ndarray, up: np.ndarray,
                ankle_height_m: float) -> tuple[np.ndarray, float]:
    """The floor ``normal · p = offset`` (view frame) under the planted ankles ``[F, 2, 3]``, lowered by
    ``ankle_height_m``. The normal (:func:`_floor_normal`): a plane fitted to the contacts where they
    lie on one and span about 1 m in two directions; along a straight walk, ``up`` made
    perpendicular to it; else ``up``. The offset: the median height of the contacts on the lowest
    level (:func:`_floor_height`; contacts higher up stand on steps or platforms)."""
    points = ankles_view_m[planted]
    normal = _floor_normal(points, up / np.linalg.norm(up))
    return normal, _floor_height(points, normal) - ankle_height_m


def _floor_normal(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The floor's unit normal under contacts ``[N, 3]`` (view frame): see :func:`floor_plane`. A
    plane is trusted only where the contacts lie on it (RMS :data:`MAX_FLOOR_RMS_M`): first all of
    them, then those on the lowest level along ``up``."""
    if len(points) < 10:
        return up
    for subset in (points, lowest_level(points, up)):
        plane = coplanar_spread(subset)
        if plane is None:
            continue
        spread, vt = plane
        if spread[1] >= MIN_FLOOR_SPREAD_M and abs(vt[2] @ up) > 0.8:
            return vt[2] * np.sign(vt[2] @ up)
        if spread[0] >= MIN_FLOOR_SPREAD_M and abs(vt[0] @ up) < 0.5:
            # contacts along one line (a straight walk): the floor contains it; the up estimate keeps
            # only its tilt about the line
            normal = up - (up @ vt[0]) * vt[0]
            return normal / np.linalg.norm(normal)
    return up


def coplanar_spread(points: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The RMS extents ``[3]`` and principal directions ``[3, 3]`` (rows) of contacts ``[N, 3]``, or
    None when they are fewer than 10 or do not lie on one plane (RMS off it over
    :data:`MAX_FLOOR_RMS_M`)."""
    if len(points) < 10:
        return None
    _, spread, vt = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)
    spread = spread / np.sqrt(len(points))
    return (spread, vt) if spread[2] <= MAX_FLOOR_RMS_M else None


def lowest_level(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The contacts ``[N, 3]`` on the lowest level along ``normal``: those on the floor, not on a step
    or platform above it. A level is a band :data:`FLOOR_BAND_M` high from one contact up; the lowest
    that holds :data:`FLOOR_MIN_SHARE` of the contacts (or as many as the fullest band, if fewer) is
    the floor. A few strays below it (an ankle whose depth drifts as the body leaves the image: 10 %
    of a take's contacts 20 cm low) do not make a floor of their own."""
    heights = points @ normal
    order = np.sort(heights)
    held = np.searchsorted(order, order + FLOOR_BAND_M, side="right") - np.arange(len(order))
    base = order[np.argmax(held >= min(FLOOR_MIN_SHARE * len(order), held.max()))]
    return points[(heights >= base) & (heights <= base + FLOOR_BAND_M)]


def _floor_height(points: np.ndarray, normal: np.ndarray) -> float:
    """The median height along ``normal`` of the contacts ``[N, 3]`` on the lowest level."""
    return float(np.median(lowest_level(points, normal) @ normal))


def above_floor(root_m: np.ndarray, ankle_offsets_m: np.ndarray, normal: np.ndarray, offset: float,
                 ankle_height_m: float) -> np.ndarray:
    """Roots lifted along ``normal`` where the lower ankle would sink below the ankle height."""
    heights = (root_m[:, None] + ankle_offsets_m) @ normal - offset
    deficit = np.maximum(ankle_height_m - heights.min(axis=1), 0.0)
    return root_m + deficit[:, None] * normal


STEP_GRID_M = 0.01  # contacts within this of each other are one step (the whole-take fit anchors a step)


def count_steps(contacts_m: np.ndarray) -> int:
    """The steps among contacts ``[N, 3]``: the distinct ones to :data:`STEP_GRID_M` (the whole-take
    fit holds a planted ankle at one place for its whole contact)."""
    return len(np.unique(np.round(contacts_m / STEP_GRID_M), axis=0))


def spans_floor(contacts: np.ndarray) -> bool:
    """Whether contacts ``[N, 3]`` spread over about a metre (RMS :data:`MIN_FLOOR_SPREAD_M` along
    their main direction)."""
    if len(contacts) < 10:
        return False
    return bool(np.linalg.svd(contacts - contacts.mean(axis=0), compute_uv=False)[0] / np.sqrt(len(contacts))
                >= MIN_FLOOR_SPREAD_M)
