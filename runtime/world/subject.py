"""Which track of a take is its subject, and which tracks a user asked for (``--people``).

The subject is the person the take was filmed for: seen long, large, near the middle of the image,
and moving. Each track's score is the sum over its frames of its keypoints' box height (pixels,
larger people nearer the camera count more) times how central the box is (1 at the image's middle
column, :data:`EDGE_WEIGHT` at its left or right edge), times ``1 + its image motion`` (the box
centre's path over the take in box heights, at most :data:`MAX_MOTION_BONUS`): a still bystander at
the edge scores far below a performer in the middle.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from mocapdb.core.motion import FrameRecorder
from mocapdb.core.outputs import TrackRecording
from mocapdb.runtime.head_pose import NO_FACE_WORLD
from mocapdb.runtime.track_state import NO_EXTREMITIES

EDGE_WEIGHT = 0.5      # a box at the image's left or right edge counts this much of one in the middle
MAX_MOTION_BONUS = 1.0  # moving doubles a track's score at most
PEOPLE_CHOICES = ("main", "all")


def subject_score(rec: TrackRecording, image_width_px: float) -> float:
    """A track's score (module docstring) from its input keypoints (its ``keypoints`` column; 0 without)."""
    if not len(rec.column("keypoints")):
        return 0.0
    points = rec.column("keypoints")  # [F, K, 3]
    seen = points[..., 2] > 0
    frames = seen.sum(axis=1) >= 2
    if not frames.any():
        return 0.0
    xy = np.where(seen[..., None], points[..., :2], np.nan)[frames]
    low, high = np.nanmin(xy, axis=1), np.nanmax(xy, axis=1)          # [F', 2]
    box_px = high[:, 1] - low[:, 1]
    centre = (low + high) / 2.0
    off_centre = np.clip(np.abs(centre[:, 0] - image_width_px / 2.0) / (image_width_px / 2.0), 0.0, 1.0)
    centrality = 1.0 - (1.0 - EDGE_WEIGHT) * off_centre
    path = np.sum(np.linalg.norm(np.diff(centre, axis=0), axis=1)) / max(float(np.median(box_px)), 1.0)
    return float(np.sum(box_px * centrality) * (1.0 + min(path, MAX_MOTION_BONUS)))


def main_track(recordings: list[TrackRecording], image_width_px: float) -> int | None:
    """The track id of the take's subject (the highest :func:`subject_score`; None: no track)."""
    if not recordings:
        return None
    scores = [subject_score(rec, image_width_px) for rec in recordings]
    return recordings[int(np.argmax(scores))].track


def parse_people(text: str) -> str | tuple[int, ...]:
    """``--people``: "main", "all" or track ids separated by commas (ValueError otherwise)."""
    text = text.strip().lower()
    if text in PEOPLE_CHOICES:
        return text
    try:
        ids = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise ValueError(f"--people takes main, all or track ids separated by commas (e.g. 1,3), not {text!r}") \
            from None
    if not ids or min(ids) < 0:
        raise ValueError(f"--people: track ids are whole numbers from 0, not {text!r}")
    return ids


def chosen(recordings: list[TrackRecording], people: str | tuple[int, ...], main: int | None
           ) -> list[TrackRecording]:
    """The recordings ``people`` asks for: all, the main track's, or those of the listed ids."""
    if people == "all":
        return list(recordings)
    wanted = {main} if people == "main" else set(people)
    return [rec for rec in recordings if rec.track in wanted]


MAX_JOIN_GAP_S = 1.0     # a person lost for at most this long and found again is joined into one track
MAX_JOIN_SHIFT = 0.5     # ... where the box moved at most this many box heights meanwhile
MAX_JOIN_SIZE_RATIO = 1.3  # ... and its height changed by at most this factor


def join_fragments(recordings: list[TrackRecording], fps: float) -> tuple[list[TrackRecording], dict[int, int]]:
    """Tracks of one person lost and found again joined: a track that starts at most
    :data:`MAX_JOIN_GAP_S` after another ends, its first box within :data:`MAX_JOIN_SHIFT` box
    heights of that one's last and of a like size, is appended to it (the frames between hold its
    last pose and see no keypoint, as the engine holds a track over frames it missed). Tracks
    without input keypoints and static ones are left alone. Returns the tracks (in order of their
    first frames) and which track each joined one went into."""
    out: list[TrackRecording] = []
    joined: dict[int, int] = {}
    for rec in sorted(recordings, key=lambda r: r.first_frame):
        target = next((o for o in reversed(out) if _continues(o, rec, fps)), None)
        if target is None:
            out.append(rec)
        else:
            out[out.index(target)] = _appended(target, rec)
            joined[rec.track] = target.track
    return out, joined


def _continues(before: TrackRecording, after: TrackRecording, fps: float) -> bool:
    """Whether ``after`` is ``before``'s person found again (:func:`join_fragments`)."""
    if before.static or after.static or not len(before.column("keypoints")) or not len(after.column("keypoints")):
        return False
    gap = after.first_frame - (before.first_frame + len(before))
    if gap < 0 or gap > MAX_JOIN_GAP_S * fps:
        return False
    last, first = _box(before.column("keypoints")[::-1]), _box(after.column("keypoints"))
    if last is None or first is None:
        return False
    (centre_a, height_a), (centre_b, height_b) = last, first
    shift = float(np.linalg.norm(centre_b - centre_a)) / max((height_a + height_b) / 2.0, 1.0)
    ratio = max(height_a, height_b) / max(min(height_a, height_b), 1.0)
    return shift <= MAX_JOIN_SHIFT and ratio <= MAX_JOIN_SIZE_RATIO


def _box(keypoints: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Centre (px) and height (px) of the first frame in ``keypoints`` with two keypoints seen."""
    for points in keypoints:
        seen = points[:, 2] > 0
        if seen.sum() >= 2:
            low, high = points[seen, :2].min(axis=0), points[seen, :2].max(axis=0)
            return (low + high) / 2.0, float(high[1] - low[1])
    return None


def _appended(before: TrackRecording, after: TrackRecording) -> TrackRecording:
    """``before`` followed by ``after``, the frames between holding ``before``'s last pose and seeing
    no keypoint, heel, toe or knuckle."""
    gap = after.first_frame - (before.first_frame + len(before))
    filler = before.frames.last()
    filler.update(keypoints=np.zeros_like(filler["keypoints"]), extremities=NO_EXTREMITIES)
    if "world_bones" in filler:
        filler.update(world_bones=np.zeros_like(filler["world_bones"]), face_world_m=NO_FACE_WORLD)
    columns = {name: np.concatenate([before.frames[name], np.repeat(filler[name][None], gap, axis=0),
                                     after.frames[name]]) for name in before.frames.names()}
    longer = before if len(before) >= len(after) else after
    return replace(before, frames=FrameRecorder.of(**columns), last_s=after.last_s,
                   proportions_m=longer.proportions_m, up_view=longer.up_view, up_sd_deg=longer.up_sd_deg)
