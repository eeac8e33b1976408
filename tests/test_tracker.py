"""The tracker on synthetic scenes whose true identities are known."""
import numpy as np
import pytest

from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D
from mocapdb.runtime.tracker import Tracker, TrackerConfig

FPS = 30.0
# A standing person in pixels, mid-hip at the origin, y down, about 310 px tall (OpenPose order).
_STANDING = {
    "head": (0, -170), "neck": (0, -120), "r_shoulder": (-40, -115), "r_elbow": (-50, -60),
    "r_wrist": (-55, -10), "l_shoulder": (40, -115), "l_elbow": (50, -60), "l_wrist": (55, -10),
    "r_hip": (-20, 0), "r_knee": (-22, 70), "r_ankle": (-24, 140), "l_hip": (20, 0), "l_knee": (22, 70),
    "l_ankle": (24, 140)}
TEMPLATE = np.zeros((N_KEYPOINTS_2D, 2))
for _name, _xy in _STANDING.items():
    TEMPLATE[KP[_name]] = _xy


def person(x: float, y: float, rng: np.random.Generator, scale: float = 1.0, visible: int = N_KEYPOINTS_2D,
           jitter_px: float = 1.5):
    """Keypoints and confidences of a person whose mid-hip is at ``(x, y)``."""
    points = TEMPLATE * scale + (x, y) + rng.normal(0.0, jitter_px, TEMPLATE.shape)
    confidence = np.where(np.arange(N_KEYPOINTS_2D) < visible, rng.uniform(0.5, 1.0, N_KEYPOINTS_2D), 0.0)
    return points, confidence


def run(frames, tracker=None, shuffle_seed=None):
    """Feed ``frames`` (each a dict label -> (points, confidence)); per frame ``{label: id}`` and the updates."""
    tracker = tracker or Tracker()
    order_rng = np.random.default_rng(shuffle_seed)
    ids, updates = [], []
    for k, people in enumerate(frames):
        labels = list(people)
        if shuffle_seed is not None:
            labels = [labels[i] for i in order_rng.permutation(len(labels))]
        points = np.array([people[label][0] for label in labels]).reshape(-1, N_KEYPOINTS_2D, 2)
        confidence = np.array([people[label][1] for label in labels]).reshape(-1, N_KEYPOINTS_2D)
        update = tracker.update(points, confidence, k / FPS)
        ids.append({labels[d]: track for track, d in update.assignments})
        updates.append(update)
    return ids, updates


def ids_of(ids, label):
    return {frame[label] for frame in ids if label in frame}


def crossing_scene(seed: int = 0):
    """A walks right and B (farther away: smaller, higher) walks left; B is hidden while they overlap."""
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(41):
        xa, xb = 200 + 20 * k, 1000 - 20 * k
        people = {"A": person(xa, 600, rng)}
        if abs(xa - xb) > 70:
            people["B"] = person(xb, 570, rng, scale=0.8)
        frames.append(people)
    return frames


def test_people_crossing_paths_keep_their_ids():
    ids, updates = run(crossing_scene(), shuffle_seed=1)
    assert ids_of(ids, "A") == {0} and ids_of(ids, "B") == {1}  # both start on frame 0, numbered left to right
    assert sum("B" in frame for frame in ids) == sum("B" in frame for frame in crossing_scene()) - 1
    assert all(not u.ended for u in updates)


@pytest.mark.parametrize("gap, same_id", [(5, True), (10, True), (11, False), (15, False)])
def test_dropout_keeps_the_id_up_to_max_missing_frames(gap, same_id):
    rng = np.random.default_rng(gap)
    frames = [{} if 10 <= k < 10 + gap else {"A": person(300 + 5 * k, 600, rng)} for k in range(10 + gap + 10)]
    ids, updates = run(frames)
    assert ids_of(ids, "A") == ({0} if same_id else {0, 1})
    ended_at = [k for k, u in enumerate(updates) if u.ended]
    if same_id:
        assert ended_at == [] and ids[10 + gap] == {"A": 0}  # matched again on its first frame back
    else:
        assert ended_at == [20] and updates[20].ended == [0]  # the 11th missing frame ends it
        assert ids[10 + gap] == {} and ids[10 + gap + 1] == {"A": 1}  # a new track, confirmed after 2 hits


def test_new_track_is_reported_on_the_frame_it_is_confirmed():
    rng = np.random.default_rng(3)
    _, updates = run([{"A": person(400 + 3 * k, 500, rng)} for k in range(4)])
    assert updates[0].assignments == [] and updates[0].started == []
    assert updates[1].assignments == [(0, 0)] and updates[1].started == [0]
    assert updates[2].assignments == [(0, 0)] and updates[2].started == []


def test_the_update_that_confirms_a_track_gives_its_earlier_detections():
    # so that a track's files can start at its first detection, the frame before it is reported
    rng = np.random.default_rng(16)
    frames = [{"A": person(600 + 3 * k, 500, rng)} for k in range(4)]
    frames[1] = {"left": person(200, 500, rng), **frames[1]}  # there A is input 1
    _, updates = run(frames, Tracker(TrackerConfig(min_hits=3)))
    assert [u.started for u in updates] == [[], [], [0], []]
    assert updates[2].earlier == {0: [0, 1]}  # A's input index in frames 0 and 1
    _, updates = run(frames)  # min_hits 2
    assert updates[1].started == [0] and updates[1].earlier == {0: [0]} and updates[2].earlier == {}


def test_one_frame_false_detection_never_becomes_a_track():
    rng = np.random.default_rng(4)
    frames = [{"A": person(300 + 4 * k, 600, rng)} for k in range(30)]
    for k in range(2, 20, 2):  # a ghost in a different place every other frame
        frames[k]["ghost"] = person(900 + 37 * k, 500 - 11 * k, rng)
    frames[25]["B"] = person(1500, 600, rng)
    frames[26]["B"] = person(1502, 600, rng)
    ids, updates = run(frames, shuffle_seed=5)
    assert ids_of(ids, "ghost") == set()
    assert ids_of(ids, "A") == {0}
    assert ids_of(ids, "B") == {1}  # ids are given on confirmation, so the ghosts used none
    assert [u.started for u in updates if u.started] == [[0], [1]]


@pytest.mark.parametrize("jump_px, same_track", [(150, True), (160, False)])
def test_gate_on_distance_plus_iou(jump_px, same_track):
    # The template is 310 px tall and 110 px wide: a jump wider than the box leaves IoU = 0, so the cost is
    # jump / 310 + 0.5 · (1 - 0), under the gate 1.0 below a 155 px jump.
    rng = np.random.default_rng(10)
    frames = [{"A": person(x, 600, rng, jitter_px=0.0)} for x in (300, 300 + jump_px, 300 + jump_px)]
    _, updates = run(frames)
    assert [u.started for u in updates] == ([[], [0], []] if same_track else [[], [], [0]])


def test_double_detection_never_steals_from_a_confirmed_track():
    rng = np.random.default_rng(11)
    frames = []
    for k in range(40):
        frames.append({"A": person(500, 600, rng)})
        if k >= 2 and k % 2 == 0:
            frames[-1]["twin"] = person(500, 600, rng)  # the detector fires twice on A
    ids, updates = run(frames, shuffle_seed=12)
    assert all(list(frame.values()) == [0] for frame in ids[1:])  # either twin may be taken: they are alike
    assert [u.started for u in updates if u.started] == [[0]]


def test_detection_with_three_joints_is_ignored():
    rng = np.random.default_rng(6)
    frames = [{"partial": person(900, 600, rng, visible=3), "A": person(300, 600, rng)} for _ in range(10)]
    ids, updates = run(frames)
    assert ids_of(ids, "partial") == set()
    assert updates[-1].assignments == [(0, 1)]  # detection indices refer to the input, ignored ones included


def test_ids_are_never_reused():
    rng = np.random.default_rng(7)
    frames = []
    for k in range(90):
        people = {}
        if k < 10:
            people["A"] = person(300, 600, rng)
        if 12 <= k < 22:
            people["B"] = person(800, 600, rng)  # while A's track is still waiting, but far from it
        if k >= 60:
            people["C"] = person(300, 600, rng)  # where A was
        frames.append(people)
    tracker = Tracker()
    ids, updates = run(frames, tracker)
    assert (ids_of(ids, "A"), ids_of(ids, "B"), ids_of(ids, "C")) == ({0}, {1}, {2})
    assert [u.started for u in updates if u.started] == [[0], [1], [2]]
    assert [u.ended for u in updates if u.ended] == [[0], [1]]
    assert tracker.active_ids == [2]
    assert tracker.finish() == [2] and tracker.active_ids == []
    _, later = run([{"A": person(300, 600, rng)}] * 3, tracker)
    assert later[1].started == [3]


def _busy_scene(seed: int):
    """Three people appearing together, a crossing, a dropout and a late arrival."""
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(60):
        people = {"A": person(200 + 15 * k, 600, rng), "B": person(1100 - 15 * k, 560, rng, scale=0.8)}
        if not 20 <= k < 26:
            people["C"] = person(1500, 620 - 2 * k, rng, scale=1.1)
        if k >= 40:
            people["D"] = person(600, 300, rng, scale=0.6)
        frames.append(people)
    return frames


def test_detection_order_does_not_change_the_ids():
    reference, _ = run(_busy_scene(8))
    mapping = {label: ids_of(reference, label) for label in "ABCD"}
    assert all(len(v) == 1 for v in mapping.values())
    assert mapping == {"A": {0}, "B": {1}, "C": {2}, "D": {3}}  # same-frame arrivals numbered left to right
    for seed in range(3):
        shuffled, _ = run(_busy_scene(8), shuffle_seed=seed)
        assert shuffled == reference


def test_finish_ends_only_confirmed_tracks():
    rng = np.random.default_rng(9)
    tracker = Tracker(TrackerConfig(min_hits=3))
    run([{"A": person(300, 600, rng)}] * 3 + [{"A": person(300, 600, rng), "B": person(900, 600, rng)}], tracker)
    assert tracker.active_ids == [0]
    assert tracker.finish() == [0]


def test_repeated_timestamp_does_not_break_the_track():
    rng = np.random.default_rng(13)
    tracker = Tracker()
    times = [k / FPS for k in range(8)] + [7 / FPS] + [k / FPS for k in range(8, 14)]  # frame 7's time twice
    updates = [tracker.update(*(a[None] for a in person(300 + 6 * i, 600, rng)), t) for i, t in enumerate(times)]
    assert all(u.assignments == [(0, 0)] for u in updates[1:])  # a 1/0 velocity would lose the track


def _update(tracker, people, k, **limits):
    points = np.array([p[0] for p in people]).reshape(-1, N_KEYPOINTS_2D, 2)
    confidence = np.array([p[1] for p in people]).reshape(-1, N_KEYPOINTS_2D)
    return tracker.update(points, confidence, k / FPS, **limits)


def test_max_tracks_leaves_further_detections_untracked_and_counts_them():
    rng = np.random.default_rng(14)
    tracker = Tracker()
    xs = [1500, 300, 1200, 600, 900]  # in no particular order: the leftmost three get the tracks
    for k in range(12):
        update = _update(tracker, [person(x, 600, rng) for x in xs], k, max_tracks=3)
        assert update.over_max_tracks == 2 and len(tracker._tracks.ids) == 3
    assert sorted(d for _, d in update.assignments) == [1, 3, 4]  # x = 300, 600, 900
    for k in range(12, 40):  # the person at x = 300 leaves; once the track ends, x = 1200 gets one
        update = _update(tracker, [person(x, 600, rng) for x in xs[2:] + [1500]], k, max_tracks=3)
    assert [t for t, _ in update.assignments] == [1, 2, 3] and update.over_max_tracks == 1


def test_max_new_keeps_tracks_waiting_unconfirmed_and_counts_them():
    rng = np.random.default_rng(15)
    tracker = Tracker()
    updates = [_update(tracker, [person(x, 600, rng) for x in (300, 700, 1100)], k, max_new=1 if k < 3 else 0)
               for k in range(6)]
    assert [u.started for u in updates] == [[], [0], [1], [], [], []]  # at most 1 per frame, then none
    assert [u.over_max_new for u in updates] == [0, 2, 1, 1, 1, 1]
    assert [len(u.assignments) for u in updates] == [0, 1, 2, 2, 2, 2]  # a waiting track has no output
    update = _update(tracker, [person(x, 600, rng) for x in (300, 700, 1100)], 6)  # no limit: it goes on
    assert update.started == [2] and update.over_max_new == 0
