"""The whole take's side labels (runtime/side_labels.py) on a hand-made walk whose sides a detector exchanged:
the exchanged frames and pairs found exactly, a genuine crossing and a long run left as they are."""
import warnings

import numpy as np

from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D
from mocapdb.runtime.side_labels import BODY_PAIRS, consistent_sides

FPS = 60.0


def _walk(frames: int = 120) -> np.ndarray:
    """``[F, 14, 3]``: a person 400 px tall walking right at 2 px a frame, each right point 40-80 px to the
    image's right of its left one, the limbs swinging; every point seen."""
    t = np.arange(frames)[:, None]
    points = np.zeros((frames, N_KEYPOINTS_2D, 3))
    heights = {"head": 100, "neck": 150, "shoulder": 160, "elbow": 240, "wrist": 310, "hip": 330, "knee": 420,
               "ankle": 500}
    for name, y in heights.items():
        half = 0.0 if name in ("head", "neck") else (40.0 if name in ("shoulder", "hip") else 30.0)
        swing = 15.0 * np.sin(2 * np.pi * t / 60.0) if name in ("elbow", "wrist", "knee", "ankle") else 0.0
        for side, sign in (("r_", 1.0), ("l_", -1.0)):
            key = name if name in ("head", "neck") else side + name
            points[:, KP[key], 0] = (200.0 + 2.0 * t + sign * half + sign * swing)[:, 0]
            points[:, KP[key], 1] = y
            points[:, KP[key], 2] = 0.9
    return points


def _exchange(points: np.ndarray, frames, parts) -> None:
    for part in parts:
        right, left = KP[f"r_{part}"], KP[f"l_{part}"]
        points[frames, right], points[frames, left] = points[frames, left], points[frames, right].copy()


def test_exchanged_runs_single_frames_and_partial_flips_are_found_exactly():
    clean = _walk()
    seen = clean.copy()
    _exchange(seen, slice(40, 46), ("shoulder", "elbow", "wrist"))   # 6 frames, the arms (a BlazePose flip)
    _exchange(seen, [20, 70], ("knee", "ankle"))                      # single frames, the legs
    _exchange(seen, [55], ("wrist",))                                 # a partial flip: one pair
    seen[30, KP["l_elbow"], 2] = 0.0                                  # unseen: its pair is left alone
    _exchange(seen, [30], ("elbow",))
    out, exchanged = consistent_sides(seen, BODY_PAIRS, FPS)
    expected = np.zeros_like(exchanged)
    for frames, parts in ((range(40, 46), ("shoulder", "elbow", "wrist")), ([20, 70], ("knee", "ankle")),
                          ([55], ("wrist",))):
        for part in parts:
            expected[list(frames), list(BODY_PAIRS[:, 0]).index(KP[f"r_{part}"])] = True
    assert np.array_equal(exchanged, expected)
    restored = np.delete(np.arange(len(clean)), 30)
    assert np.array_equal(out[restored], clean[restored])
    assert np.array_equal(out[30], seen[30])


def test_a_genuine_crossing_and_a_long_run_keep_their_labels():
    """Wrists that cross the body's mid-line (the arms folded) move smoothly through it: no frame is nearer
    exchanged. A run longer than half the window (0.2 s) is the take's own labelling."""
    crossing = _walk()
    right, left = KP["r_wrist"], KP["l_wrist"]
    centre = 0.5 * (crossing[:, right, 0] + crossing[:, left, 0])
    offset = np.linspace(30.0, -30.0, len(crossing))   # the right wrist from the right of the mid-line to its left
    crossing[:, right, 0], crossing[:, left, 0] = centre + offset, centre - offset
    assert not consistent_sides(crossing, BODY_PAIRS, FPS)[1].any()
    long_run = _walk()
    _exchange(long_run, slice(40, 70), ("shoulder", "elbow", "wrist"))   # 0.5 s
    assert not consistent_sides(long_run, BODY_PAIRS, FPS)[1].any()


def test_the_streams_causal_check_marks_a_flip_against_the_frames_before_and_counts_it_unseen():
    """exchanged_now judges a frame against the recent frames' median alone; the online take then counts every
    joint of a flipped frame's fit as unseen (MIN_CONFIDENCE), and a frame as labelled as the others as seen."""
    from mocapdb.runtime.online_take import OnlineParams, OnlineTrack
    from mocapdb.runtime.rotation_kalman import MIN_CONFIDENCE, joint_confidence
    from mocapdb.runtime.side_labels import exchanged_now

    walk = _walk()
    flipped = walk[30].copy()
    _exchange(flipped[None], [0], ("knee", "ankle"))
    assert list(exchanged_now(walk[6:30], flipped, BODY_PAIRS)) == [False] * 4 + [True] * 2
    assert not exchanged_now(walk[6:30], walk[30], BODY_PAIRS).any()
    track = OnlineTrack(FPS, OnlineParams())
    for frame in walk[:30]:
        assert np.array_equal(track._confidence(frame), joint_confidence(frame))
    assert np.all(track._confidence(flipped) == MIN_CONFIDENCE)
    assert np.array_equal(track._confidence(walk[31]), joint_confidence(walk[31]))


def test_the_causal_kernel_matches_a_nan_median_reference():
    """exchanged_now's numba kernel against NumPy's NaN median written out, on random frames with unseen points."""
    from mocapdb.runtime.side_labels import LABEL_MARGIN, exchanged_now

    rng = np.random.default_rng(3)
    for _ in range(200):
        recent = np.concatenate([rng.normal(300, 40, (24, N_KEYPOINTS_2D, 2)),
                                 (rng.random((24, N_KEYPOINTS_2D, 1)) > 0.2) * 0.9], axis=2)
        points = np.concatenate([rng.normal(300, 40, (N_KEYPOINTS_2D, 2)),
                                 (rng.random((N_KEYPOINTS_2D, 1)) > 0.1) * 0.9], axis=1)
        xy = np.where((recent[..., 2] > 0)[..., None], recent[..., :2], np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # an all-NaN point: its median NaN
            median = np.nanmedian(xy, axis=0)
        expected = []
        for right, left in BODY_PAIRS:
            labelled = np.hypot(*(points[right, :2] - median[right])) + np.hypot(*(points[left, :2] - median[left]))
            crossed = np.hypot(*(points[right, :2] - median[left])) + np.hypot(*(points[left, :2] - median[right]))
            expected.append(bool(points[right, 2] > 0 and points[left, 2] > 0 and crossed < LABEL_MARGIN * labelled))
        assert list(exchanged_now(recent, points, BODY_PAIRS)) == expected


def test_the_fits_of_flipped_frames_are_bridged_by_their_neighbours():
    """bridged_frames: skipped frames interpolated by hand-computable turns about one axis (slerp is then exact),
    a neighbour's opposite sign aligned, the root linear, the ends held."""
    from mocapdb.runtime.take_smoothing import bridged_frames

    def about_z(deg):
        half = np.radians(deg) / 2
        return np.array([np.cos(half), 0.0, 0.0, np.sin(half)])
    quats = np.stack([about_z(d) for d in (0, 10, 99, 99, 40, 50, 99)])[:, None]   # 99: a flipped frame's fit
    quats[4] *= -1.0                                                               # the same turn, other sign
    root = np.array([[0.0, 0.0, -3.0]] * 7)
    root[:, 0] = [0.0, 0.1, 9.0, 9.0, 0.4, 0.5, 9.0]
    skip = np.array([False, False, True, True, False, False, True])
    out_quats, out_root = bridged_frames(quats, root, skip)
    for frame, deg in ((2, 20.0), (3, 30.0), (6, 50.0)):
        assert abs(abs(out_quats[frame, 0] @ about_z(deg)) - 1.0) < 1e-12
    assert np.allclose(out_root[[2, 3, 6], 0], [0.2, 0.3, 0.5]) and np.array_equal(out_quats[~skip], quats[~skip])
    assert bridged_frames(quats, root, np.ones(7, dtype=bool))[0] is quats
