"""The scores of ``mocapdb eval --world`` (:mod:`mocapdb.evaluation.world`): engine tracks against
the people of a take (:mod:`mocapdb.evaluation.world_takes`).

Tracks (:class:`TrackFit`) are matched to people by their 2D keypoints (:func:`match_tracks`).
Per person (its longest track, :func:`score_person`): the stature error (% of the true stature;
engine stature = 1.75 m × the track's body scale), the root error (median over frames of the
pelvis distance, m, and of it as % of the true camera-to-pelvis distance), the floor error
(:func:`floor_errors`); per track the plausibility flags (:func:`track_flags`); per take the error
of every pair of people's stature ratio (:func:`ratio_error_pct`). Summaries over takes
(:func:`summarise`) and by role (:func:`by_role`).
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from typing import cast

import numpy as np

from mocapdb.core.outputs import CAMERA_FROM_VIEW
from mocapdb.core.skeleton import ANKLE_HEIGHT_M, PELVIS
from mocapdb.evaluation.heldout import UNIVERSAL_HEIGHT_M, camera_to_world
from mocapdb.evaluation.metrics import planted_feet
from mocapdb.evaluation.world_takes import ANKLES, Camera, TruePerson, WorldConfig, WorldTake

HUMAN_STATURE_RANGE_M = (0.8, 2.3)  # a track's stature outside this is not a person's
FLOOR_TOLERANCE_M = 0.05  # planted soles further below a floor than this are implausible
MATCH_MAX_BOX = 0.25      # a track follows a person whose keypoints lie within this × its box height
FLAGS = ("out_of_range", "behind_camera", "below_fitted_floor", "below_true_floor")  # track_flags
IMPLAUSIBLE = FLAGS[:3]  # impossible in the track's own world; under the true floor is an error against the truth


@dataclass
class TrackFit:
    """One engine track after the whole-take world, camera-aligned (metres): input frame indices
    ``frames [n]``, ``joints_m [n, 15, 3]``, ``root_m [n, 3]``, the stature (m), the fitted floor
    ``up_view · p = floor_offset_m`` (view frame; None: none found) and the input keypoints the
    track took, ``keypoints [n, 14, 3]`` (x, y px, confidence)."""

    track: int
    frames: np.ndarray
    joints_m: np.ndarray
    root_m: np.ndarray
    stature_m: float
    up_view: np.ndarray | None
    floor_offset_m: float | None
    keypoints: np.ndarray
    static: bool = False


def keypoint_distance_px(keypoints: np.ndarray, points_px: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """Median over frames of the mean distance (px) between a track's keypoints ``[n, 14, 3]`` and
    each person's input ``points_px [P, n, 14, 2]`` over the keypoints both see (``confidence
    [P, n, 14]``): ``[P]``, inf where they share none."""
    seen = (keypoints[None, ..., 2] > 0) & (confidence > 0)
    dist = np.linalg.norm(keypoints[None, ..., :2] - points_px, axis=-1)
    count = seen.sum(axis=-1)
    per_frame = np.where(count > 0, (dist * seen).sum(axis=-1) / np.maximum(count, 1), np.nan)
    out = np.full(len(points_px), np.inf)
    some = np.isfinite(per_frame).any(axis=1)
    out[some] = np.nanmedian(per_frame[some], axis=1)
    return out


def match_tracks(fits: list[TrackFit], people: list[TruePerson], focal_px: float,
                 image_size: tuple[int, int]) -> list[int | None]:
    """The person (index) each track follows: the nearest by :func:`keypoint_distance_px` if within
    :data:`MATCH_MAX_BOX` of that person's box height; None for a track that follows nobody."""
    n_frames = len(people[0].points_px)
    boxes = np.array([p.box_px(focal_px, image_size) for p in people])
    points = np.stack([p.points_px for p in people])
    confidence = np.stack([p.confidence for p in people])
    out: list[int | None] = []
    for fit in fits:
        keep = (fit.frames >= 0) & (fit.frames < n_frames)
        idx = fit.frames[keep]
        cost = keypoint_distance_px(fit.keypoints[keep], points[:, idx], confidence[:, idx]) / boxes
        best = int(np.argmin(cost))
        out.append(best if cost[best] <= MATCH_MAX_BOX else None)
    return out


def _sole_heights_m(fit: TrackFit, camera: Camera, support_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of a track, its lower sole's height (m: ankle minus the body's ankle height) above
    the fitted floor (NaN without one) and above the true surface ``support_m`` up from the floor."""
    ankles = fit.joints_m[:, ANKLES]
    sole = ANKLE_HEIGHT_M * fit.stature_m / UNIVERSAL_HEIGHT_M
    true = camera.heights_m(ankles).min(axis=1) - support_m - sole
    if fit.up_view is None or fit.floor_offset_m is None:
        return np.full(len(ankles), np.nan), true
    fitted = ((ankles * CAMERA_FROM_VIEW) @ fit.up_view).min(axis=1) - fit.floor_offset_m - sole
    return fitted, true


def track_flags(fit: TrackFit, camera: Camera, person: TruePerson | None, fps: float) -> dict[str, bool]:
    """A track's :data:`FLAGS`: its stature outside :data:`HUMAN_STATURE_RANGE_M`, a root at or
    behind the camera (z ≤ 0) in any frame, its lower sole more than :data:`FLOOR_TOLERANCE_M` under
    the fitted floor, or under the true surface it stands on (median over the frames where the
    person's true foot is planted; a track of nobody: all its frames, on the floor). The first three
    are :data:`IMPLAUSIBLE` (impossible in the world the track reconstructs); the last is an error
    against the truth (a body 5 % too big, scaled about a camera 1.5 m up, stands 7.5 cm into it)."""
    support = person.spec.support_m if person is not None else 0.0
    fitted, true = _sole_heights_m(fit, camera, support)
    planted = np.ones(len(fit.frames), dtype=bool)
    if person is not None:
        world = camera_to_world(person.cam_m[:, ANKLES], camera.height_m, 0.0, camera.pitch_deg)
        index = np.clip(fit.frames, 0, len(world) - 1)
        # numpy's stubs give .any(axis=...) as a scalar or an array: over axis 1 of [F, 2] it is an array
        planted = cast(np.ndarray, planted_feet(world, fps).any(axis=1))[index]
    lo, hi = HUMAN_STATURE_RANGE_M
    flags = (not lo <= fit.stature_m <= hi, bool((fit.root_m[:, 2] <= 0.0).any()),
             bool(_median(fitted[planted]) < -FLOOR_TOLERANCE_M), bool(_median(true[planted]) < -FLOOR_TOLERANCE_M))
    return dict(zip(FLAGS, flags))


def floor_errors(fit: TrackFit, camera: Camera) -> tuple[float, float]:
    """The fitted floor's camera height minus the true one (m) and the angle between the fitted and
    the true up (degrees); NaN without a fitted floor."""
    if fit.up_view is None or fit.floor_offset_m is None:
        return float("nan"), float("nan")
    cosine = float(np.clip(fit.up_view @ camera.up_view() / np.linalg.norm(fit.up_view), -1.0, 1.0))
    return -fit.floor_offset_m - camera.height_m, float(np.degrees(np.arccos(cosine)))


def score_person(person: TruePerson, fit: TrackFit, camera: Camera) -> dict:
    """A person against its track: stature error (% of the true stature), median root error (m and
    % of the true camera-to-pelvis distance, over the track's frames), floor errors."""
    keep = (fit.frames >= 0) & (fit.frames < len(person.cam_m))
    truth = person.cam_m[fit.frames[keep], PELVIS]
    error = np.linalg.norm(fit.root_m[keep] - truth, axis=-1)
    height_error, angle = floor_errors(fit, camera)
    return {"stature_m": fit.stature_m, "stature_error_pct": 100.0 * (fit.stature_m / person.stature_m - 1.0),
            "root_error_m": _median(error), "root_error_pct": _median(100.0 * error / np.linalg.norm(truth, axis=-1)),
            "camera_height_error_m": height_error, "floor_angle_deg": angle}


def ratio_error_pct(est_a: float, est_b: float, true_a: float, true_b: float) -> float:
    """How far (%) the estimated ratio of two statures is from the true one, either way round."""
    r = (est_a / est_b) / (true_a / true_b)
    return 100.0 * (max(r, 1.0 / r) - 1.0)


def score_take(take: WorldTake, fits: list[TrackFit], config: WorldConfig) -> dict:
    """A take's people (each its longest matching track), tracks (with :func:`track_flags`) and the
    stature-ratio error of every pair of people with a track."""
    owners = match_tracks(fits, take.people, config.focal_px, config.image_size)
    tracks = []
    for fit, owner in zip(fits, owners):
        person = None if owner is None else take.people[owner]
        flags = track_flags(fit, take.camera, person, config.fps)
        tracks.append({"track": fit.track, "person": owner, "frames": len(fit.frames), "stature_m": fit.stature_m,
                       "static": fit.static, "flags": flags, "implausible": any(flags[f] for f in IMPLAUSIBLE)})
    people = [_person_entry(take, i, fits, owners, config) for i in range(len(take.people))]
    pairs = [ratio_error_pct(a["stature_m"], b["stature_m"], a["true_stature_m"], b["true_stature_m"])
             for a, b in combinations([p for p in people if p["track"] is not None], 2)]
    return {"scenario": take.scenario.name, "repeat": take.repeat, "camera_height_m": take.camera.height_m,
            "pitch_deg": take.camera.pitch_deg, "frames": len(take.frames), "people": people, "tracks": tracks,
            "pair_ratio_error_pct": pairs, "false_tracks": sum(o is None for o in owners)}


def _person_entry(take: WorldTake, index: int, fits: list[TrackFit], owners: list[int | None],
                  config: WorldConfig) -> dict:
    """One person's report entry (:func:`score_person` on its longest track; NaN without one)."""
    person = take.people[index]
    mine = [fit for fit, owner in zip(fits, owners) if owner == index]
    entry = {"role": person.spec.role, "kind": person.spec.kind, "clip": person.clip, "still": person.spec.still,
             "support_m": person.spec.support_m, "true_stature_m": person.stature_m,
             "distance_m": float(np.median(np.linalg.norm(person.cam_m[:, PELVIS], axis=-1))),
             "unseen_keypoints": float(np.mean(person.confidence <= 0)),
             "outside_image": person.outside_share(config.focal_px, config.image_size),
             "tracks": [fit.track for fit in mine], "track": None, "static": None}
    nan = float("nan")
    entry.update(stature_m=nan, stature_error_pct=nan, root_error_m=nan, root_error_pct=nan,
                 camera_height_error_m=nan, floor_angle_deg=nan)
    if mine:
        main = max(mine, key=lambda fit: len(fit.frames))
        entry.update(track=main.track, static=main.static, **score_person(person, main, take.camera))
    return entry


def _median(values: np.ndarray | list[float]) -> float:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if len(values) else float("nan")


def _max(values) -> float:
    values = np.asarray(list(values), dtype=np.float64)
    values = values[np.isfinite(values)]
    return float(values.max()) if len(values) else float("nan")


def summarise(takes: list[dict]) -> dict:
    """Figures over takes (:func:`score_take`): people and those missed; |stature error| median and
    max (%); largest pair-ratio error (%); median root error (m, %); largest |child stature error|
    (%); median |camera-height error| (m) and floor angle (degrees); tracks, implausible ones, those
    outside the human range, false ones."""
    people = [p for t in takes for p in t["people"]]
    tracks = [k for t in takes for k in t["tracks"]]
    stature = np.abs([p["stature_error_pct"] for p in people])
    return {
        "takes": len(takes), "people": len(people), "missed": sum(p["track"] is None for p in people),
        "stature_error_pct": {"median": _median(stature), "max": _max(stature)},
        "pair_ratio_error_pct_max": _max(r for t in takes for r in t["pair_ratio_error_pct"]),
        "root_error_m": _median([p["root_error_m"] for p in people]),
        "root_error_pct": _median([p["root_error_pct"] for p in people]),
        "child_stature_error_pct_max": _max(abs(p["stature_error_pct"]) for p in people if p["kind"] == "child"),
        "camera_height_error_m": _median(np.abs([p["camera_height_error_m"] for p in people])),
        "floor_angle_deg": _median([p["floor_angle_deg"] for p in people]),
        "tracks": len(tracks), "implausible_tracks": sum(k["implausible"] for k in tracks),
        "out_of_range_tracks": sum(k["flags"]["out_of_range"] for k in tracks),
        "flagged_tracks": {flag: sum(k["flags"][flag] for k in tracks) for flag in FLAGS},
        "false_tracks": sum(t["false_tracks"] for t in takes),
    }


def by_role(takes: list[dict]) -> dict[str, dict]:
    """Per role: people, missed, |stature error| median and max (%), median root error (m, %)."""
    out = {}
    for role in sorted({p["role"] for t in takes for p in t["people"]}):
        people = [p for t in takes for p in t["people"] if p["role"] == role]
        stature = np.abs([p["stature_error_pct"] for p in people])
        out[role] = {"people": len(people), "missed": sum(p["track"] is None for p in people),
                     "stature_error_pct": {"median": _median(stature), "max": _max(stature)},
                     "root_error_m": _median([p["root_error_m"] for p in people]),
                     "root_error_pct": _median([p["root_error_pct"] for p in people])}
    return out
