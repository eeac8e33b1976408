"""The detector's world landmarks as a prior beside retrieval: their axes brought to the database's
views, the candidates' disagreement with them, their weight across frames, and the engine's choice."""
import numpy as np

from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import yaw_matrix
from mocapdb.core.skeleton import KP, PELVIS
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.world_prior import (
    BONES,
    VIEW_FROM_IMAGE_AXES,
    candidate_costs,
    database_bones,
    temporal_weights,
    world_bones,
)

FOCAL, SIZE = 1000.0, (1000, 1000)


def _seen(db, frame: int, yaw_deg: float, depth_m: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Database frame ``frame`` turned by ``yaw_deg`` in front of a level camera, its pelvis on the
    optical axis: the keypoints ``[14, 2]`` px and its world landmarks ``[14, 3]`` (image axes, hips-centred)."""
    rel = (db.positions[frame] - db.positions[frame, PELVIS]) @ yaw_matrix(yaw_deg).T   # view frame
    camera = rel * VIEW_FROM_IMAGE_AXES + [0.0, 0.0, depth_m]                           # OpenCV axes
    px = FOCAL * camera[:14, :2] / camera[:14, 2:] + np.array(SIZE) / 2.0
    world = rel[:14] * VIEW_FROM_IMAGE_AXES
    hips = (world[KP["r_hip"]] + world[KP["l_hip"]]) / 2.0
    return px, world - hips


def test_the_seen_pose_costs_nothing_and_its_mirror_more(small_db):
    yaws = np.asarray(small_db.meta["yaws_deg"], dtype=np.float64)
    frame, yaw = 40, yaws[3]
    px, world = _seen(small_db, frame, yaw)
    bones, weights = world_bones(world, px, np.ones(14), np.array([0.0, 1.0, 0.0]), FOCAL,
                                 (SIZE[0] / 2, SIZE[1] / 2))
    assert bones.shape == (len(BONES), 3) and (weights == 1.0).all()
    db_bones = database_bones(small_db.positions)
    frames = np.array([frame, frame, frame])
    costs = candidate_costs(db_bones, frames, np.array([yaw, yaw + 180.0, yaw + 40.0]), bones, weights)
    assert costs[0] < 1e-5 and costs[1] > 0.3 and costs[2] > 0.05   # itself; turned round; turned 40°
    # a tilted camera: the world landmarks lean with it, the track's up says by how much
    tilt = yaw_matrix(0.0)
    angle = np.radians(20.0)
    pitch = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(angle), -np.sin(angle)], [0.0, np.sin(angle), np.cos(angle)]])
    leaning = (world * VIEW_FROM_IMAGE_AXES) @ (pitch @ tilt).T * VIEW_FROM_IMAGE_AXES
    up = pitch @ np.array([0.0, 1.0, 0.0])
    level, _ = world_bones(leaning, px, np.ones(14), up, FOCAL, (SIZE[0] / 2, SIZE[1] / 2))
    np.testing.assert_allclose(level, bones, atol=1e-3)   # the same up to the ray through the hips (≈ the axis)


def test_a_bone_that_flips_between_frames_counts_little():
    before = np.tile([0.0, -1.0, 0.0], (len(BONES), 1))
    now = before.copy()
    now[0] = [0.0, 0.0, 1.0]          # turned 90°: a swap
    now[1] = [0.0, -0.99, 0.141]      # turned 8°: motion
    weights = temporal_weights(now, before)
    assert weights[0] == 0.0 and weights[1] > 0.9 and (weights[2:] == 1.0).all()
    assert (temporal_weights(now, None) == 1.0).all()


def test_the_engine_uses_them_only_when_asked(small_db):
    """With the prior on, the engine's choices move towards the pose the world landmarks show (here
    another moment than the keypoints'); off (the default) or without world landmarks, nothing changes."""
    yaws = np.asarray(small_db.meta["yaws_deg"], dtype=np.float64)
    db_bones = database_bones(small_db.positions)
    frames, shown = [], []
    for i in range(12):
        px, _ = _seen(small_db, 100 + 2 * i, yaws[5])
        _, world = _seen(small_db, 110 + 2 * i, yaws[5])
        frames.append(KeypointFrame(i, i / 30.0, [Person(px, np.full(14, 0.9), None, None, world)]))
        shown.append(world_bones(world, px, np.ones(14), np.array([0.0, 1.0, 0.0]), FOCAL,
                                 (SIZE[0] / 2, SIZE[1] / 2))[0])
    plain = [KeypointFrame(f.index, f.time_s, [Person(f.people[0].points_px, f.people[0].confidence)])
             for f in frames]
    common = dict(focal_px=FOCAL, image_size=SIZE, fps=30.0, refine=False, smoothing=False)

    def run(config, given):
        engine = Engine(small_db, config)
        return [p.match for f in given for p in engine.step(f)]

    def disagreement(matches):
        clips = np.array(small_db.clip_name)[small_db.frame_clip]
        rows = [int(np.flatnonzero((clips == m.clip) & (small_db.frame_index == m.frame))[0]) for m in matches]
        return np.mean([candidate_costs(db_bones, np.array([r]), np.array([m.yaw_deg]), b, np.ones(len(BONES)))[0]
                        for r, m, b in zip(rows, matches, shown[-len(matches):])])

    off = run(EngineConfig(**common), frames)
    assert off == run(EngineConfig(**common), plain) == run(EngineConfig(world_prior=10.0, **common), plain)
    on = run(EngineConfig(world_prior=10.0, **common), frames)
    assert len(on) == len(off) > 0 and on != off
    assert disagreement(on) < 0.8 * disagreement(off)
