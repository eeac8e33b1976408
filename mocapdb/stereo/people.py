"""`mocapdb stereo`: which detections of the two views are the same person, frame by frame.

Each view's detections are linked into 2D tracks by proximity (:mod:`mocapdb.stereo.tracks_2d`).
Pairs of 2D tracks, one per view, are matched by epipolar consistency
(:mod:`mocapdb.stereo.epipolar_pairs`) over the frames they share, under an essential matrix chosen
as the one that makes the scene most consistent (each of the best-corresponding pairings, and every
two, proposes one), then re-fitted to every matched person; a still 2D track never pairs with a
moving one. Matched 2D tracks chain into people (a person keeps its id when one view's 2D track
breaks and the other's does not); once linked, a noisy frame of theirs is still the person's
(:func:`linked_bounds`). A body the detector split in two is put back together (:func:`fragments`),
one whose left and right it swapped is turned back (:func:`unflip`). Detections that match no one
are not people: they are reported. Decisions and thresholds: ``data_specs/stereo.md``.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.skeleton import N_KEYPOINTS_2D
from mocapdb.stereo.config import StereoConfig, StereoError
from mocapdb.stereo.epipolar_pairs import (
    MAX_EPIPOLAR_PX,
    MIN_SHARED_JOINTS,
    MIRROR,
    STILL_SPREAD,
    Pairs,
    all_pairs,
    fit_essential,
    mean_focal,
    measure,
    pair_correspondences,
    pairing_groups,
    spread,
)
from mocapdb.stereo.relative_pose import sampson_distance
from mocapdb.stereo.tracks_2d import Detections, box_diagonal, detections, masked_median

# Once two 2D tracks are linked (the same person over time), a frame of theirs is that person within
# LINKED_SPREAD times the pairing's median distance (at least MAX_EPIPOLAR_PX): a noisier detector
# spreads the true pairs wider (YOLO11n-pose on the Pose2Sim demo video: medians 10-15 px, the lunge's
# frames up to 43 px, 3.4 times their pairing's median), while the 2D tracks already say who is who.
LINKED_SPREAD = 4.0
# Two 2D tracks are the same person when they are consistent in at least MIN_LINK_SHARE of the
# frames they share with MIN_SHARED_JOINTS joints, and in no frame that either already gives to a
# better-matching partner. A person needs MIN_PERSON_FRAMES consistent frames.
MIN_LINK_SHARE = 0.5
MIN_PERSON_FRAMES = 5
# OpenPose sometimes splits one body into two detections of a frame (the Pose2Sim take, camera 1,
# frame 37: head and arms apart from hips and legs). A detection that no person uses is a piece of a
# person's detection in that view when its confident joints are none of the body's and at least
# MIN_FRAGMENT_JOINTS of them, confident in the person's detection of the other view too, lie within
# MAX_EPIPOLAR_PX of it (median): its joints complete the body (:func:`fragments`).
MIN_FRAGMENT_JOINTS = 3
SEED_PAIRINGS = 8  # the best-corresponding pairings of 2D tracks whose own essential matrix is tried


@dataclass
class Selection:
    """One person's detections per frame: ``x [T, 14, 2]`` pixels (NaN when missing), ``c [T, 14]``."""

    x1: np.ndarray
    c1: np.ndarray
    x2: np.ndarray
    c2: np.ndarray
    kept: np.ndarray         # [T] bool: the person is seen consistently in both views
    distance_px: np.ndarray  # [T] median epipolar distance of the chosen pair (NaN when not kept)
    dropped: dict[str, list[int]] = field(default_factory=dict)  # frames with no person at all, by reason
    track: int = 0
    correspondences: int = 0  # joints confident in both views, over the kept frames
    still: bool = False       # a still person (STILL_SPREAD in both views): never the main one


@dataclass
class People:
    """Everyone seen in both views: ``persons[k]`` has track id ``k``; track 0, the main person, has the
    most correspondences of the people who move (a still person behind may have more: every joint seen)."""

    persons: list[Selection]
    dropped: dict[str, list[int]]  # frames with no person, by reason
    unmatched: list[str]           # per view, the detections that are no person (one line each)
    essential: np.ndarray


def link_tracks(pairs: Pairs, d1: Detections, d2: Detections, n_frames: int) -> set[tuple[int, int]]:
    """The pairings (view-1 2D track, view-2 2D track) that are the same person.

    Pairings by decreasing count of consistent frames; one is kept when it is consistent in at
    least MIN_LINK_SHARE of the frames it shares with enough joints, and its consistent frames are
    not already given to another partner of either track. A still track never pairs with a moving one.
    """
    pairings, groups = pairing_groups(pairs, d1, d2)
    ok, enough = pairs.consistent & ~pairs.still_moving, np.isfinite(pairs.distance)
    good = np.array([ok[g].sum() for g in groups], dtype=np.int64)
    used1 = np.zeros((int(d1.track.max(initial=-1)) + 1, n_frames), dtype=bool)
    used2 = np.zeros((int(d2.track.max(initial=-1)) + 1, n_frames), dtype=bool)
    links = set()
    for k in np.argsort(-good, kind="stable"):
        if good[k] < 1 or good[k] < MIN_LINK_SHARE * enough[groups[k]].sum():
            continue
        (ta, tb), frames = pairings[k], pairs.frame[groups[k][ok[groups[k]]]]
        if not (used1[ta, frames].any() or used2[tb, frames].any()):
            used1[ta, frames] = used2[tb, frames] = True
            links.add((int(ta), int(tb)))
    return links


def _components(links: set[tuple[int, int]]) -> dict[tuple[int, int], int]:
    """Person index of each link: links sharing a 2D track are the same person (union-find)."""
    parent: dict[tuple[int, int], tuple[int, int]] = {}

    def root(node: tuple[int, int]) -> tuple[int, int]:
        while parent.setdefault(node, node) != node:
            node = parent[node]
        return node

    for ta, tb in sorted(links):
        parent[root((2, tb))] = root((1, ta))
    roots = {link: root((1, link[0])) for link in links}
    ids = {r: n for n, r in enumerate(dict.fromkeys(roots[link] for link in sorted(links)))}
    return {link: ids[r] for link, r in roots.items()}


def linked_bounds(pairs: Pairs, d1: Detections, d2: Detections, links: set[tuple[int, int]]) -> np.ndarray:
    """``[M]`` each pair's epipolar bound (px): for a pairing of linked 2D tracks :data:`LINKED_SPREAD`
    times its median distance, at least :data:`MAX_EPIPOLAR_PX` (that alone for any other pair)."""
    bound = np.full(len(pairs.i), MAX_EPIPOLAR_PX)
    pairings, groups = pairing_groups(pairs, d1, d2)
    for (ta, tb), rows in zip(pairings.tolist(), groups):
        finite = pairs.distance[rows][np.isfinite(pairs.distance[rows])]
        if (ta, tb) in links and len(finite):
            bound[rows] = max(MAX_EPIPOLAR_PX, LINKED_SPREAD * float(np.median(finite)))
    return bound


def person_rows(pairs: Pairs, d1: Detections, d2: Detections,
                links: set[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """The chosen pair row of each (person, frame): rows of linked 2D tracks within their bound
    (:func:`linked_bounds`), the closest when a person has two in one frame. Returns rows ``[K]`` and
    their persons ``[K]``."""
    person_of = _components(links)
    person = np.array([person_of.get((int(a), int(b)), -1)
                       for a, b in zip(d1.track[pairs.i], d2.track[pairs.j])], dtype=np.int64)
    rows = np.flatnonzero((person >= 0) & (pairs.distance <= linked_bounds(pairs, d1, d2, links)))
    order = rows[np.lexsort((pairs.distance[rows], pairs.frame[rows], person[rows]))]
    first = np.r_[True, (np.diff(person[order]) != 0) | (np.diff(pairs.frame[order]) != 0)] if len(order) else []
    rows = order[np.asarray(first, dtype=bool)]
    return rows, person[rows]


def _match(pairs: Pairs, d1: Detections, d2: Detections, essential: np.ndarray, focal: float,
           n_frames: int) -> tuple[Pairs, np.ndarray, np.ndarray]:
    """Pairs measured under ``essential``, and the chosen rows with their persons."""
    measured = measure(pairs, d1, d2, essential, focal)
    rows, person = person_rows(measured, d1, d2, link_tracks(measured, d1, d2, n_frames))
    return measured, rows, person


def _most_prominent_rows(pairs: Pairs, d1: Detections, d2: Detections) -> np.ndarray:
    """The rows pairing each frame's most prominent detection of view 1 with that of view 2
    (prominence: confident confidences × box diagonal)."""
    top = []
    for d in (d1, d2):
        prominence = np.where(d.vis, d.conf, 0.0).sum(axis=1) * box_diagonal(d.points, d.vis)
        order = np.lexsort((-prominence, d.frame))
        top.append(order[np.r_[True, np.diff(d.frame[order]) != 0]] if len(order) else order)
    return np.flatnonzero(np.isin(pairs.i, top[0]) & np.isin(pairs.j, top[1]))


def seed_rows(pairs: Pairs, d1: Detections, d2: Detections) -> list[np.ndarray]:
    """The rows whose correspondences each propose an essential matrix: each of the SEED_PAIRINGS
    best-corresponding 2D-track pairings (not a still track with a moving one), every two of them that
    share no 2D track (two people: one person's own matrix may miss the other, e.g. a still one far
    behind, whose own matrix is degenerate), and the frames' most prominent pairs (a fallback when the
    2D tracks are short)."""
    pairings, groups = pairing_groups(pairs, d1, d2)
    plausible = [k for k, rows in enumerate(groups) if not pairs.still_moving[rows[0]]]
    counts = np.array([pairs.shared[groups[k]].sum() for k in plausible], dtype=np.int64)
    best = [plausible[k] for k in np.argsort(-counts, kind="stable")[:SEED_PAIRINGS]]
    two = [np.concatenate([groups[a], groups[b]]) for a, b in itertools.combinations(best, 2)
           if (pairings[a] != pairings[b]).all()]
    return [groups[k] for k in best] + two + [_most_prominent_rows(pairs, d1, d2)]


def _score(measured: Pairs, rows: np.ndarray) -> int:
    """How well an essential matrix matches the scene: its chosen rows within :data:`MAX_EPIPOLAR_PX`."""
    return int(measured.consistent[rows].sum())


def seed_essential(pairs: Pairs, d1: Detections, d2: Detections, focal: float, n_frames: int,
                   config: StereoConfig) -> np.ndarray:
    """The essential matrix under which the most person-frames are matched within MAX_EPIPOLAR_PX
    (:func:`_score`), among those the :func:`seed_rows` propose."""
    need = max(8, config.min_correspondences)
    best, best_score = None, -1
    for rows in seed_rows(pairs, d1, d2):
        essential = fit_essential(*pair_correspondences(pairs, rows, d1, d2), config) \
            if pairs.shared[rows].sum() >= need else None
        score = -1 if essential is None else _score(*_match(pairs, d1, d2, essential, focal, n_frames)[:2])
        if score > best_score:
            best, best_score = essential, score
    if best is None:
        counts = [pairs.shared[g].sum() for g in pairing_groups(pairs, d1, d2)[1]]
        raise StereoError(f"at most {int(max(counts, default=0))} keypoint correspondences between a person of "
                          f"view 1 and one of view 2 (need {need}), or no essential matrix fits them: too few "
                          "frames or joints seen by both cameras, or the folders are not the same take")
    return best


def match_people(frames1: list[KeypointFrame], frames2: list[KeypointFrame], cam1: CameraModel,
                 cam2: CameraModel, config: StereoConfig) -> People:
    """Everyone seen in both views, one :class:`Selection` per person (see the module docstring)."""
    n_frames = len(frames1)
    d1, d2 = detections(frames1, cam1, config.confidence), detections(frames2, cam2, config.confidence)
    focal = mean_focal(cam1, cam2)
    essential, measured, rows, person = _matched(d1, d2, focal, n_frames, config)
    if unflip(d1, d2, measured, rows):
        measured, rows, person = _match(all_pairs(d1, d2), d1, d2, essential, focal, n_frames)
    big = np.flatnonzero(np.bincount(person, minlength=1) >= MIN_PERSON_FRAMES)
    rows, person = rows[np.isin(person, big)], person[np.isin(person, big)]
    i, j = measured.i[rows], measured.j[rows]
    pieces = (fragments(d1, d2, i, j, essential, focal, True), fragments(d2, d1, j, i, essential, focal, False))
    persons = sorted((_selection(measured, rows[person == k], d1, d2, n_frames, pieces) for k in big),
                     key=lambda sel: (sel.still, -sel.correspondences))
    kept = np.flatnonzero(np.any([sel.kept for sel in persons], axis=0)) if persons else np.zeros(0, np.int64)
    dropped = dropped_frames(n_frames, d1, d2, measured, kept)
    for k, sel in enumerate(persons):
        sel.track, sel.dropped = k, dropped
    used1, used2 = (np.concatenate([chosen, *map(np.asarray, found.values())]).astype(np.int64)
                    for chosen, found in zip((i, j), pieces))
    return People(persons, dropped, unmatched_lines((d1, d2), (used1, used2)), essential)


def _matched(d1: Detections, d2: Detections, focal: float, n_frames: int,
             config: StereoConfig) -> tuple[np.ndarray, Pairs, np.ndarray, np.ndarray]:
    """The essential matrix (seeded, then re-fitted to every matched person when that matches at
    least as many person-frames within MAX_EPIPOLAR_PX), the measured pairs, the chosen rows and their persons."""
    pairs = all_pairs(d1, d2)
    essential = seed_essential(pairs, d1, d2, focal, n_frames, config)
    measured, rows, person = _match(pairs, d1, d2, essential, focal, n_frames)
    refit = fit_essential(*pair_correspondences(measured, rows, d1, d2), config) if len(rows) >= 8 else None
    if refit is not None:
        again = _match(pairs, d1, d2, refit, focal, n_frames)
        if _score(*again[:2]) >= _score(measured, rows):
            return (refit,) + again
    return essential, measured, rows, person


def unflip(d1: Detections, d2: Detections, pairs: Pairs, chosen: np.ndarray) -> bool:
    """Turns back, in place, the detection whose left and right are swapped in each flipped pair
    (:attr:`Pairs.flipped`) of the 2D-track pairings of the ``chosen`` rows (people's): of its two, the
    one that the swap brings closer to its own 2D track (:func:`flip_gain` above 1). Whether any was."""
    key = d1.track[pairs.i] * (int(d2.track.max(initial=-1)) + 1) + d2.track[pairs.j]
    flipped = pairs.flipped & np.isin(key, key[chosen])
    turned: set[tuple[int, int]] = set()  # (view, detection)
    for i, j in zip(pairs.i[flipped].tolist(), pairs.j[flipped].tolist()):
        gain, view, k = max((flip_gain(d1, i), 1, i), (flip_gain(d2, j), 2, j))
        if gain > 1 and not {(1, i), (2, j)} & turned:
            d = d1 if view == 1 else d2
            for values in (d.points, d.conf, d.vis, d.normalised):
                values[k] = values[k][MIRROR]
            turned.add((view, k))
    return bool(turned)


def flip_gain(d: Detections, k: int) -> float:
    """How many times closer detection ``k`` lies to its 2D track's nearest detections before and after it
    with its left and right swapped (median displacement of their common joints); 1 without either."""
    same = np.flatnonzero(d.track == d.track[k])
    near = np.r_[same[d.frame[same] < d.frame[k]][-1:], same[d.frame[same] > d.frame[k]][:1]]
    moved = [masked_median(np.linalg.norm(np.nan_to_num(d.points[near] - points), axis=-1), d.vis[near] & vis)
             for points, vis in ((d.points[k], d.vis[k]), (d.points[k][MIRROR], d.vis[k][MIRROR]))]
    as_is, swapped = (float(np.nansum(m)) for m in moved)
    return as_is / swapped if len(near) and swapped > 0 else 1.0


def fragments(d: Detections, other: Detections, chosen: np.ndarray, partner: np.ndarray, essential: np.ndarray,
              focal: float, first: bool) -> dict[int, list[int]]:
    """The pieces of a body OpenPose split (above :data:`MIN_FRAGMENT_JOINTS`): for each chosen detection
    ``chosen[k]`` of view ``d`` (``first``: view 1), paired with ``partner[k]`` of ``other``, the unused
    detections of its frame whose confident joints are none of the body's so far and lie on the
    partner's epipolar geometry. Detection → its pieces (only those that have one)."""
    used = set(chosen.tolist())
    bounds = np.searchsorted(d.frame, d.frame[chosen][:, None] + np.array([0, 1]))  # each chosen frame's slice
    found: dict[int, list[int]] = {}
    for c, p, (start, stop) in zip(chosen.tolist(), partner.tolist(), bounds):
        body = d.vis[c].copy()
        for k in range(start, stop):
            if k not in used and not (d.vis[k] & body).any() and _on_partner(d, other, k, p, essential, focal, first):
                found.setdefault(c, []).append(k)
                used.add(k)
                body |= d.vis[k]
    return found


def _on_partner(d: Detections, other: Detections, k: int, p: int, essential: np.ndarray, focal: float,
                first: bool) -> bool:
    """Whether at least MIN_FRAGMENT_JOINTS joints confident in both ``d``'s detection ``k`` and ``other``'s
    ``p`` lie within MAX_EPIPOLAR_PX of each other's epipolar lines (median)."""
    shared = d.vis[k] & other.vis[p]
    if shared.sum() < MIN_FRAGMENT_JOINTS:
        return False
    ends = (d.normalised[k][shared], other.normalised[p][shared])
    return float(np.median(sampson_distance(essential, *(ends if first else ends[::-1])))) * focal <= MAX_EPIPOLAR_PX


def _selection(pairs: Pairs, rows: np.ndarray, d1: Detections, d2: Detections, n_frames: int,
               pieces: tuple[dict[int, list[int]], dict[int, list[int]]]) -> Selection:
    """The arrays of one person's chosen pairs ``rows`` (one per frame), completed by their ``pieces``
    (:func:`fragments`, per view)."""
    t = pairs.frame[rows]
    views = [_view_arrays(n_frames, t, chosen, d, found) for chosen, d, found in
             ((pairs.i[rows], d1, pieces[0]), (pairs.j[rows], d2, pieces[1]))]
    (x1, c1, v1), (x2, c2, v2) = views
    kept = np.zeros(n_frames, dtype=bool)
    kept[t] = True
    distance = np.full(n_frames, np.nan)
    distance[t] = pairs.distance[rows]
    still = max(spread(d1, pairs.i[rows]), spread(d2, pairs.j[rows])) < STILL_SPREAD
    return Selection(x1, c1, x2, c2, kept, distance, correspondences=int((v1 & v2).sum()), still=still)


def _view_arrays(n_frames: int, frames: np.ndarray, chosen: np.ndarray, d: Detections,
                 pieces: dict[int, list[int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One view of a person: points ``[T, 14, 2]`` (NaN where missing), confidences ``[T, 14]`` (0 where
    missing) and confident joints ``[T, 14]`` of the detections ``chosen`` in ``frames``, with their pieces' joints."""
    x = np.full((n_frames, N_KEYPOINTS_2D, 2), np.nan)
    c, v = np.zeros((n_frames, N_KEYPOINTS_2D)), np.zeros((n_frames, N_KEYPOINTS_2D), dtype=bool)
    x[frames], c[frames], v[frames] = d.points[chosen], d.conf[chosen], d.vis[chosen]
    for t, k in zip(frames.tolist(), chosen.tolist()):
        for piece in pieces.get(k, ()):
            joints = d.vis[piece]
            x[t, joints], c[t, joints], v[t, joints] = d.points[piece, joints], d.conf[piece, joints], True
    return x, np.where(np.isfinite(x).all(-1), c, 0.0), v


def dropped_frames(n_frames: int, d1: Detections, d2: Detections, pairs: Pairs,
                   kept: np.ndarray) -> dict[str, list[int]]:
    """The frames where no person is reconstructed, by the first reason that applies."""
    everyone = np.setdiff1d(np.arange(n_frames), kept)
    enough = np.unique(pairs.frame[np.isfinite(pairs.distance)])
    consistent = np.unique(pairs.frame[pairs.consistent])
    reasons = {
        "no person in view 1": np.setdiff1d(everyone, d1.frame),
        "no person in view 2": np.setdiff1d(np.intersect1d(everyone, d1.frame), d2.frame),
        f"no pair with {MIN_SHARED_JOINTS} joints confident in both views":
            np.setdiff1d(np.intersect1d(everyone, pairs.frame), enough),
        f"no pair within {MAX_EPIPOLAR_PX:g} px of the epipolar geometry":
            np.setdiff1d(np.intersect1d(everyone, enough), consistent),
        f"consistent pairs, but none of a person matched over at least {MIN_PERSON_FRAMES} frames":
            np.intersect1d(everyone, consistent),
    }
    return {why: sorted(int(f) for f in frames) for why, frames in reasons.items() if len(frames)}


def unmatched_lines(views: tuple[Detections, Detections], used: tuple[np.ndarray, np.ndarray]) -> list[str]:
    """Per view, one line on the 2D tracks of which no detection (``used``: indices) is in a person."""
    lines = []
    for view, (d, in_person) in enumerate(zip(views, used), start=1):
        spare = ~np.isin(d.track, d.track[in_person])
        if spare.any():
            frames = np.unique(d.frame[spare]).tolist()
            lines.append(f"view {view}: {len(np.unique(d.track[spare]))} 2D track(s), {int(spare.sum())} detections "
                         f"in {len(frames)} frames (frames {listed_frames(frames)}) match no one in view {3 - view}: "
                         "seen by one camera only or not epipolar-consistent, not reconstructed")
    return lines


def listed_frames(frames: list[int], most: int = 10) -> str:
    """The first ``most`` frame numbers, comma-separated, with ``...`` when there are more."""
    return ", ".join(map(str, frames[:most])) + (", ..." if len(frames) > most else "")
