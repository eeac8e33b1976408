"""The runtime engine against database truth: frames, yaw, axes, translation, temporal choice."""
import numpy as np
import pytest

from mocapdb.core.cameras import DatabaseCamera
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import project_views, quat_geodesic, yaw_matrix
from mocapdb.core.skeleton import KP, PELVIS
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig, TrackLimits
from mocapdb.runtime.frame_people import FramePeople, usable_people
from mocapdb.runtime.pose_pipeline import PosePipeline
from mocapdb.runtime.temporal import temporal_costs
from mocapdb.runtime.track_book import TrackBook
from mocapdb.runtime.track_state import NO_EXTREMITIES, TrackState


def _db_views(db, clip: int, yaw_index: int, camera: DatabaseCamera, turn_deg: float = 0.0):
    """Keypoint frames of one database clip seen as the database saw it (turned ``turn_deg`` more)."""
    first, n = db.clip_first_frame[clip], db.clip_n_frames[clip]
    pos = db.positions[first:first + n].astype(np.float64)
    yaw = db.meta["yaws_deg"][yaw_index] + turn_deg
    px = project_views(pos, pos[:, PELVIS], np.array([yaw]), 0.0, camera)[:, 0, :14]
    frames = [KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9))]) for i in range(n)]
    view = (pos - pos[:, PELVIS:PELVIS + 1]) @ yaw_matrix(yaw).T
    return frames, view * [1.0, 1.0, -1.0], first


@pytest.mark.parametrize("search", ["clustered", "exact"])
def test_database_views_are_found_exactly(small_db, search):
    camera = DatabaseCamera(**small_db.meta["camera"])
    frames, truth, first = _db_views(small_db, clip=1, yaw_index=7, camera=camera)
    engine = Engine(small_db, EngineConfig(search=search, smoothing=False, refine_yaw=False, refine=False, fps=24.0,
                                           focal_px=camera.focal_px,
                                           image_size=(camera.width_px, camera.height_px)))
    outputs = [engine.step(f) for f in frames]
    assert outputs[0] == []  # a track is confirmed on its second frame
    for i, poses in enumerate(outputs[1:], start=1):
        (pose,) = poses
        assert pose.match.frame == i and pose.match.yaw_deg == small_db.meta["yaws_deg"][7]
        assert pose.match.distance_2d == pytest.approx(0.0, abs=1e-4)
        np.testing.assert_allclose(pose.joints_m - pose.root_m, truth[i], atol=1e-4)
        # The database camera stands camera.distance_m in front of the pelvis, 1.5 m above the floor.
        assert pose.root_m[2] == pytest.approx(camera.distance_m, rel=0.02)
    recordings = engine.finish()
    # the recording (the track's files) starts at the first detection, the frame before the confirmation
    assert [(r.first_frame, len(r.quaternions)) for r in recordings] == [(0, len(frames))]


@pytest.mark.parametrize("turn", [-4.0, 3.0])
def test_yaw_between_database_yaws_is_refined(small_db, turn):
    camera = DatabaseCamera(**small_db.meta["camera"])
    frames, _, _ = _db_views(small_db, clip=1, yaw_index=7, camera=camera, turn_deg=turn)
    yaw = small_db.meta["yaws_deg"][7] + turn
    for refine, tolerance in ((True, 1.5), (False, abs(turn) + 0.01)):
        engine = Engine(small_db, EngineConfig(smoothing=False, refine_yaw=refine, refine=False))
        yaws = [p.match.yaw_deg for f in frames for p in engine.step(f)]
        errors = np.abs(np.array(yaws) - yaw)
        assert np.median(errors) <= tolerance
    assert np.median(errors) >= abs(turn) - 0.01  # unrefined: the grid yaw


def test_left_side_of_a_subject_facing_the_camera_is_on_image_right(small_db):
    camera = DatabaseCamera(**small_db.meta["camera"])
    frames, truth, _ = _db_views(small_db, clip=0, yaw_index=0, camera=camera)
    engine = Engine(small_db, EngineConfig(smoothing=False, fps=24.0))
    poses = [p for f in frames for p in engine.step(f)]
    for pose, frame in zip(poses, frames[1:]):
        px = frame.people[0].points_px
        # Image x grows with camera-aligned x.
        assert np.sign(px[KP["l_hip"], 0] - px[KP["r_hip"], 0]) == np.sign(
            pose.joints_m[KP["l_hip"], 0] - pose.joints_m[KP["r_hip"], 0])


def test_people_with_too_few_joints_are_skipped(small_db):
    engine = Engine(small_db)
    conf = np.zeros(14)
    conf[:3] = 0.9
    assert engine.step(KeypointFrame(0, None, [Person(np.zeros((14, 2)), conf)])) == []
    assert engine.stats.skipped_people == 1


def test_the_pose_pipeline_alone_gives_the_engines_poses(small_db):
    """One track's frames through the pose pipeline and its own memory: the engine's poses and recording."""
    camera = DatabaseCamera(**small_db.meta["camera"])
    frames, _, _ = _db_views(small_db, clip=1, yaw_index=7, camera=camera, turn_deg=3.0)
    config = EngineConfig(fps=24.0, focal_px=camera.focal_px, image_size=(camera.width_px, camera.height_px))
    engine = Engine(small_db, config)
    streamed = [p for f in frames for p in engine.step(f)]
    pipeline = PosePipeline(small_db, config)
    state = TrackState(0, 0, config, len(config.window_weights))
    alone = [pipeline.pose(state, usable_people(f, config).detection(0)) for f in frames]
    assert len(streamed) == len(frames) - 1  # the engine reports a track from its confirmation
    for got, want in zip(alone[1:], streamed):
        np.testing.assert_array_equal(got.joints_m, want.joints_m)
        np.testing.assert_array_equal(got.quaternions, want.quaternions)
        assert got.match == want.match
    (recording,) = engine.finish()
    np.testing.assert_array_equal(np.array(state.recording.quaternions), np.array(recording.quaternions))


def _crowd(frame: int, n: int, t_s: float | None = None) -> FramePeople:
    """``n`` people standing side by side, 300 px apart, in frame ``frame`` (24 fps)."""
    shape = np.column_stack([np.tile([0.0, 40.0, 80.0], 5)[:14], np.repeat(np.arange(5) * 50.0, 3)[:14]])
    points = np.stack([shape + [300.0 * k + 100.0, 200.0] for k in range(n)])
    return FramePeople(frame, frame / 24.0 if t_s is None else t_s, points, np.full((n, 14), 0.9),
                       np.repeat(NO_EXTREMITIES[None], n, axis=0))


def test_the_track_book_holds_its_limits_without_a_database():
    book = TrackBook(EngineConfig(fps=24.0, limits=TrackLimits(max_tracks=2, max_new_per_min=0)))
    seen = [book.update(_crowd(i, 5)) for i in range(4)]
    assert seen[0] == [] and [len(s) for s in seen[1:]] == [2, 2, 2]
    assert [[d.frame_index for d in s.earlier] for s in seen[1]] == [[0], [0]]  # confirmed with frame 0
    assert all(s.earlier == [] for s in seen[2])
    assert sorted(book.tracks) == [0, 1] and book.counts.over_max_tracks == 3 * 4
    assert book.update(_crowd(4, 5, t_s=10.0)) == [] and book.counts.gaps == 1 and not book.tracks

    book = TrackBook(EngineConfig(fps=24.0, limits=TrackLimits(max_tracks=0, max_new_per_min=1)))
    assert [len(book.update(_crowd(i, 3))) for i in range(3)] == [0, 1, 1]
    assert book.counts.tracks_started == 1 and book.counts.over_max_new > 0
    assert len(book.update(_crowd(3, 3), now_s=61.0)) == 2  # a minute on: one more


def test_temporal_costs_match_numpy_reference():
    rng = np.random.default_rng(0)
    db_quats = rng.normal(size=(30, 11, 4))
    db_quats /= np.linalg.norm(db_quats, axis=-1, keepdims=True)
    clip_first = np.repeat([0, 12], [12, 18])
    yaw_quats = np.array([[1.0, 0, 0, 0], [np.cos(0.3), 0, np.sin(0.3), 0]])
    history = rng.normal(size=(4, 11, 4))
    history /= np.linalg.norm(history, axis=-1, keepdims=True)
    frames, yaws = np.array([5, 13, 29]), np.array([0, 1, 1])
    window, joints = np.array([0.4, 0.3, 0.2, 0.1]), np.linspace(0.5, 1.5, 11)
    costs = temporal_costs(db_quats.astype(np.float32), clip_first, yaw_quats, frames, yaws, history, 3, window, joints)
    from mocapdb.core.geometry import quat_mul
    for c, (f, v) in enumerate(zip(frames, yaws)):
        total = 0.0
        for i in range(3):
            g = max(f - 1 - i, clip_first[f])
            q = db_quats[g].astype(np.float32).astype(np.float64).copy()
            q[0] = quat_mul(yaw_quats[v], q[0])
            total += window[i] * np.sum(joints * quat_geodesic(history[i], q) ** 2)
        assert costs[c] == pytest.approx(total / window[:3].sum(), rel=1e-5)
