"""`mocapdb stereo`'s two views: both keypoint folders read, checked to be two synchronised cameras.

Refused (StereoError, before any output is written): the same folder twice, different frame counts
(unless ``trim``), the same keypoints in both (:func:`check_distinct_views`). Decisions:
``data_specs/stereo.md``.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from mocapdb.core.files import os_error_message
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.stereo.config import StereoError

# Two views are the same when, in at least SAME_VIEW_FRAMES of the frames where both have people,
# every person of each view has a twin in the other whose joints (≥ 3 confident in both) lie within
# SAME_VIEW_SHARE of its box diagonal (median). Two cameras set apart never give that: parallax
# moves the joints of a body by different amounts.
SAME_VIEW_SHARE = 0.02
SAME_VIEW_FRAMES = 0.95


def load_views(view1: str | Path, view2: str | Path, layout: str | None = None,
               trim: bool = False) -> tuple[list[KeypointFrame], list[KeypointFrame], list[str]]:
    """Both folders' frames; StereoError when their frame counts differ (unless ``trim``), when
    they are the same folder, or when they hold the same keypoints (:func:`check_distinct_views`).

    ``trim`` cuts both to the shorter, assuming they start together; the warning says so.
    """
    if _same_folder(view1, view2):
        raise StereoError(f"view 1 and view 2 are the same folder ({view1}): the same view twice has no "
                          "parallax, so no depth can be recovered; give the folders of two different cameras")
    frames1, frames2 = _read_view(view1, layout), _read_view(view2, layout)
    warnings = []
    if len(frames1) != len(frames2):
        counts = f"view 1 ({view1}) has {len(frames1)} frames, view 2 ({view2}) has {len(frames2)}"
        if not trim:
            raise StereoError(f"{counts}: the views must be synchronised frame by frame (same start, same "
                              "frame rate; a different frame rate gives a different count for the same take). "
                              "--trim cuts both to the shorter if they start together")
        n = min(len(frames1), len(frames2))
        frames1, frames2 = frames1[:n], frames2[:n]
        warnings.append(f"{counts}; trimmed both to the first {n}")
    check_distinct_views(frames1, frames2, view1, view2)
    return frames1, frames2, warnings


def _same_folder(a: str | Path, b: str | Path) -> bool:
    """Whether ``a`` and ``b`` are one folder (also through a symlink)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one is missing: reading it says so
        return Path(a).resolve() == Path(b).resolve()


def _read_view(folder: str | Path, layout: str | None) -> list[KeypointFrame]:
    """A view's frames; StereoError naming the folder on an OS error."""
    try:
        return list(read_openpose_folder(folder, layout))
    except OSError as exc:
        raise StereoError(os_error_message(exc, folder, "read the keypoint folder")) from None


def same_view_frames(frames1: list[KeypointFrame], frames2: list[KeypointFrame],
                     confidence: float = 0.3) -> tuple[int, int]:
    """(frames whose people are the same in both views, frames with people in both views)."""
    same = both = 0
    for f1, f2 in zip(frames1, frames2):
        people1, people2 = _confident(f1, confidence), _confident(f2, confidence)
        if not people1 or not people2:
            continue
        both += 1
        share = np.full((len(people1), len(people2)), np.inf)
        for i, (x1, v1, diagonal) in enumerate(people1):
            for j, (x2, v2, _) in enumerate(people2):
                common = v1 & v2
                if common.sum() >= 3:
                    share[i, j] = np.median(np.linalg.norm(x1[common] - x2[common], axis=-1)) / diagonal
        twins = share <= SAME_VIEW_SHARE
        same += bool(twins.any(axis=1).all() and twins.any(axis=0).all())
    return same, both


def _confident(frame: KeypointFrame, confidence: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Each person with ≥ 3 confident joints: points, confident mask, box diagonal (≥ 1 px)."""
    out = []
    for person in frame.people:
        ok = (person.confidence >= confidence) & np.isfinite(person.points_px).all(axis=-1)
        if ok.sum() >= 3:
            pts = person.points_px[ok]
            out.append((person.points_px, ok, max(float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))), 1.0)))
    return out


def check_distinct_views(frames1: list[KeypointFrame], frames2: list[KeypointFrame], view1: str | Path = "view 1",
                         view2: str | Path = "view 2") -> None:
    """StereoError when the two views hold the same keypoints (:func:`same_view_frames`)."""
    same, both = same_view_frames(frames1, frames2)
    if both and same >= SAME_VIEW_FRAMES * both:
        raise StereoError(
            f"view 1 ({view1}) and view 2 ({view2}) hold the same keypoints: every person is at the same place "
            f"in both (within {100 * SAME_VIEW_SHARE:g} % of its size) in {same} of the {both} frames with people "
            "in both. The same view twice has no parallax, so no depth can be recovered; give the keypoints of "
            "two different cameras")
