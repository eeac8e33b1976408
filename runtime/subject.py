"""Which track of a take is its subject, and which tracks a user asked for (``--people``).

The subject is the person the take was filmed for: seen long, large, near the middle of the image,
and moving. Each track's score is the sum over its frames of its keypoints' box height (pixels,
larger people nearer the camera count more) times how central the box is (1 at the image's middle
column, :data:`EDGE_WEIGHT` at its left or right edge), times ``1 + its image motion`` (the box
centre's path over the take in box heights, at most :data:`MAX_MOTION_BONUS`): a still bystander at
the edge scores far below a performer in the middle.
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.outputs import TrackRecording

EDGE_WEIGHT = 0.5      # a box at the image's left or right edge counts this much of one in the middle
MAX_MOTION_BONUS = 1.0  # moving doubles a track's score at most
PEOPLE_CHOICES = ("main", "all")


def subject_score(rec: TrackRecording, image_width_px: float) -> float:
    """A track's score (module docstring) from its input keypoints (``rec.keypoints``; 0 without)."""
    if not rec.keypoints:
        return 0.0
    points = np.array(rec.keypoints)                                   # [F, K, 3]
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
