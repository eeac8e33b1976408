"""The detector's world landmarks as a prior beside retrieval: their axes brought to the database's
views, the candidates' disagreement with them, their weight across frames, and the engine's choice."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import yaw_matrix
from mocapdb.core.skeleton import KP, PELVIS
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.refine import RefineParams
from mocapdb.runtime.world.detector_prior import (
    BONES,
    FIT_BONES,
    VIEW_FROM_IMAGE_AXES,
    bone_directions,
    candidate_costs,
    database_bones,
    rotation_between,
    temporal_weights,
    world_bones,
)

FOCAL, SIZE = 1000.0, (1000, 1000)


def test_rotation_between_is_scipys_smallest_rotation_and_the_identity_when_parallel():
    rng = np.random.default_rng(5)
    for a, b in rng.normal(size=(20, 2, 3)):
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        expected = Rotation.align_vectors(b[None], a[None])[0].as_matrix()
        np.testing.assert_allclose(rotation_between(a, b), expected, atol=1e-12)
    z = np.array([0.0, 0.0, 1.0])
    assert np.array_equal(rotation_between(z, z), np.eye(3))


def test_bone_directions_are_numpys_unit_vectors_and_smaller_confidences():
    """The kernel against the NumPy formula it replaced (unit vectors of end − start, NaN-free: 0 and weight
    0 where the ends coincide within 1e-9 m or are not finite; the smaller confidence, NaN if either is, in
    the confidences' dtype), on random joints with coincident, NaN and infinite ones, both bone sets."""
    rng = np.random.default_rng(7)
    for trial in range(300):
        joints = rng.normal(0.0, 0.4, (15, 3))
        joints[rng.integers(15)] = joints[rng.integers(15)]
        joints[rng.integers(15), rng.integers(3)] = [np.nan, np.inf, -np.inf, 1e-12][trial % 4]
        conf = rng.uniform(0, 1, 15).astype(np.float32 if trial % 2 else np.float64)
        conf[rng.integers(15)] = np.nan if trial % 3 == 0 else 0.0
        for bones in (BONES, FIT_BONES):
            start, end = np.array([b[0] for b in bones]), np.array([b[1] for b in bones])
            d = joints[end] - joints[start]
            norm = np.linalg.norm(d, axis=-1, keepdims=True)
            with np.errstate(invalid="ignore", divide="ignore"):
                u = np.where(norm > 1e-9, d / norm, np.nan)
            ok = np.isfinite(u).all(axis=-1)
            directions, weights = bone_directions(joints, conf, bones)
            np.testing.assert_allclose(directions, np.where(ok[:, None], u, 0.0), rtol=0, atol=1e-15)
            np.testing.assert_array_equal(weights, np.where(ok, np.minimum(conf[start], conf[end]), 0.0))
            assert weights.dtype == conf.dtype


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


def test_the_engine_uses_them_only_when_given_and_refining(small_db):
    """The retrieval's choices move towards the pose the world landmarks show (here another moment
    than the keypoints'); without world landmarks, with the prior at 0 or without the refinement (the
    published method), nothing changes."""
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
    common = dict(focal_px=FOCAL, image_size=SIZE, fps=30.0, smoothing=False, refinement=RefineParams(world=0.0))

    def run(config, given):
        engine = Engine(small_db, config)
        return [(p.match, p.joints_m.round(9).tolist()) for f in given for p in engine.step(f)]

    def disagreement(outputs):
        clips = np.array(small_db.clip_name)[small_db.frame_clip]
        matches = [m for m, _ in outputs]
        rows = [int(np.flatnonzero((clips == m.clip) & (small_db.frame_index == m.frame))[0]) for m in matches]
        return np.mean([candidate_costs(db_bones, np.array([r]), np.array([m.yaw_deg]), b, np.ones(len(BONES)))[0]
                        for r, m, b in zip(rows, matches, shown[-len(matches):])])

    off = run(EngineConfig(world_prior=0.0, **common), frames)
    assert off == run(EngineConfig(**common), plain)
    published = dict(common, refine=False)
    assert run(EngineConfig(**published), frames) == run(EngineConfig(**published), plain)
    on = run(EngineConfig(**common), frames)   # world_prior: its default
    assert len(on) == len(off) > 0 and on != off
    assert disagreement(on) < 0.8 * disagreement(off)


def test_the_fit_turns_bones_towards_them_and_the_whole_take_keeps_them(small_db):
    """The 2D fit's world term (``RefineParams.world``): the per-frame output nearer the world
    landmarks' bones; the recording keeps the weighted bones (``world_bones``), and the whole take,
    which starts from those fits (and is not pulled to the bones a second time), stays nearer them."""
    from mocapdb.runtime.take import take_joints
    from mocapdb.runtime.world.detector_prior import FIT_BONES, bone_directions
    from mocapdb.runtime.world.fuse import fit_takes

    yaws = np.asarray(small_db.meta["yaws_deg"], dtype=np.float64)
    frames, truth = [], []
    for i in range(20):
        px, _ = _seen(small_db, 100 + 2 * i, yaws[5])
        _, world = _seen(small_db, 108 + 2 * i, yaws[5])   # another moment: the image cannot make them agree
        frames.append(KeypointFrame(i, i / 30.0, [Person(px, np.full(14, 0.9), None, None, world)]))
        truth.append(world)
    common = dict(focal_px=FOCAL, image_size=SIZE, fps=30.0, world_prior=0.0, keep_take=True)

    def run(weight):
        engine = Engine(small_db, EngineConfig(refinement=RefineParams(world=weight), **common))
        joints = [p.joints_m for f in frames for p in engine.step(f)]
        return np.array(joints), engine.finish()[0]

    def disagreement(joints):
        seen = [bone_directions(j * [1.0, 1.0, -1.0], np.ones(15), FIT_BONES)[0] for j in joints]   # camera → view
        wanted = [bone_directions(w * [1.0, -1.0, -1.0], np.ones(14), FIT_BONES)[0] for w in truth[-len(joints):]]
        return float(np.mean([1.0 - np.sum(a * b, axis=-1) for a, b in zip(seen, wanted)]))

    plain, plain_rec = run(0.0)
    pulled, rec = run(0.05)
    assert disagreement(pulled) < 0.7 * disagreement(plain)
    assert (plain_rec.column("world_bones")[..., 3] == 0).all() and (rec.column("world_bones")[..., 3] > 0).any()
    def take(recording):
        return take_joints(fit_takes([recording], 30.0)[0], 30.0)[1]

    assert disagreement(take(rec)) < 0.7 * disagreement(take(plain_rec))


def _standing_bones(up: np.ndarray, frames: int, lean_sd_deg: float = 0.0, seed: int = 0) -> np.ndarray:
    """Recorded world bones ``[F, 12, 4]`` of a body standing along ``up`` (view frame): legs straight
    down it, the trunk's sides up it, each frame leaning by up to ``lean_sd_deg``; weights 1."""
    from mocapdb.runtime.world.detector_prior import FIT_BONES

    rng = np.random.default_rng(seed)
    out = np.zeros((frames, len(FIT_BONES), 4))
    for f in range(frames):
        lean = Rotation.from_rotvec(np.radians(lean_sd_deg) * rng.normal(size=3)).as_matrix()
        u = lean @ up
        out[f, [4, 5, 6, 7], :3] = -u            # hip → knee → ankle: down
        out[f, [10, 11], :3] = u                 # hip → shoulder: up
        out[f, :, 3] = 1.0
    return out


def test_the_body_vertical_is_the_standing_bodys_up():
    """A body standing along an up pitched 20° and rolled −10° (as the camera sees it) gives that up;
    frames that lean about it widen the error; too few frames give none."""
    from mocapdb.runtime.world.body_size import TILT_SD_DEG
    from mocapdb.runtime.world.detector_prior import MIN_VERTICAL_FRAMES, body_vertical

    p, r = np.radians(20.0), np.radians(-10.0)
    up = np.array([np.sin(r) * np.cos(p) * -1.0, np.cos(r) * np.cos(p), np.sin(p)])
    found, sd = body_vertical(_standing_bones(up, 40))
    assert np.degrees(np.arccos(np.clip(found @ up, -1, 1))) < 1e-6 and sd == TILT_SD_DEG
    found, sd = body_vertical(_standing_bones(up, 400, lean_sd_deg=5.0))
    assert np.degrees(np.arccos(found @ up)) < 1.5 and 5.0 < sd < 12.0
    assert body_vertical(_standing_bones(up, MIN_VERTICAL_FRAMES - 1)) is None
    unseen = _standing_bones(up, 40)
    unseen[:, 5, 3] = 0.0                        # a shank never seen: no whole chain
    assert body_vertical(unseen) is None


def test_the_streams_up_follows_the_bodys_vertical_in_the_detectors_3d(small_db):
    """The same keypoints with world landmarks as a level camera and as one pitched 20° sees them:
    after a few frames the stream's up (``PersonPose.up_view``) differs by the 20°, about the camera's
    x axis; without world landmarks it is the fit's tilt estimate, the same in both."""
    yaws = np.asarray(small_db.meta["yaws_deg"], dtype=np.float64)
    pitch = np.radians(20.0)
    turn = Rotation.from_rotvec([pitch, 0.0, 0.0]).as_matrix()   # the world's up, seen pitched: y → (0, cos, sin)
    common = dict(focal_px=FOCAL, image_size=SIZE, fps=30.0, smoothing=False)

    def last_up(tilted: bool, landmarks: bool = True) -> np.ndarray:
        engine = Engine(small_db, EngineConfig(**common))
        up = None
        for i in range(30):
            px, world = _seen(small_db, 100 + i, yaws[5])
            world = (world * VIEW_FROM_IMAGE_AXES @ (turn.T if tilted else np.eye(3))) * VIEW_FROM_IMAGE_AXES
            person = Person(px, np.full(14, 0.9), None, None, world if landmarks else None)
            poses = engine.step(KeypointFrame(i, i / 30.0, [person]))
            up = poses[0].up_view if poses else up
        assert up is not None
        return up

    level, pitched = last_up(False), last_up(True)
    angle = np.degrees(np.arccos(np.clip(level @ pitched, -1.0, 1.0)))
    assert angle == pytest.approx(20.0, abs=1.0)
    turned_deg = np.degrees(np.arctan2(pitched[2], pitched[1]) - np.arctan2(level[2], level[1]))
    assert turned_deg == pytest.approx(20.0, abs=1.0)
    assert np.allclose(last_up(False, landmarks=False), last_up(True, landmarks=False))


def test_the_body_vertical_of_one_leg_balance_is_its_centre_of_mass_over_the_standing_foot():
    """A body on its left leg, the right leg raised 40° sideways, arms hanging, leans over the
    standing foot until its centre of mass is above it. Hand-computed with Winter's mass fractions
    (pelvis at the origin, x to the body's left, y up; the hips 0.1 m apart from it, the lifted
    ankle 0.2 m higher): the centre of mass at (−0.03891, 0.11007), so the standing ankle (0.1,
    −0.85) → it runs along (−0.13891, 0.96007), 8.2° off the trunk. Seen through a camera pitched 20°,
    the estimate is the world's up; the ankles' mid-point → shoulders' would be 20° off."""
    from mocapdb.runtime.world.detector_prior import FIT_BONES, body_vertical, bone_directions

    s, c = np.sin(np.radians(40.0)), np.cos(np.radians(40.0))
    joints = np.zeros((15, 3))
    for name, xy in {"r_hip": (-0.1, 0.0), "r_knee": (-0.1 - 0.43 * s, -0.43 * c),
                     "r_ankle": (-0.1 - 0.85 * s, -0.85 * c),
                     "l_hip": (0.1, 0.0), "l_knee": (0.1, -0.43), "l_ankle": (0.1, -0.85),
                     "r_shoulder": (-0.19, 0.52), "r_elbow": (-0.19, 0.23), "r_wrist": (-0.19, -0.03),
                     "l_shoulder": (0.19, 0.52), "l_elbow": (0.19, 0.23), "l_wrist": (0.19, -0.03)}.items():
        joints[KP[name], :2] = xy
    balance = np.array([-0.13891, 0.96007, 0.0]) / np.hypot(0.13891, 0.96007)
    upright = Rotation.from_rotvec([0.0, 0.0, -np.arctan2(-balance[0], balance[1])]).as_matrix()  # balance → +y
    camera = Rotation.from_rotvec([np.radians(20.0), 0.0, 0.0]).as_matrix()
    seen = joints @ (camera @ upright).T
    bones, weights = bone_directions(seen, np.ones(15), FIT_BONES)
    recorded = np.repeat(np.column_stack([bones, weights])[None], 30, axis=0)
    up = camera @ np.array([0.0, 1.0, 0.0])
    found, _ = body_vertical(recorded)
    assert np.degrees(np.arccos(np.clip(found @ up, -1.0, 1.0))) < 0.1
    ankles = seen[KP["r_ankle"]] + seen[KP["l_ankle"]]
    chain = seen[KP["r_shoulder"]] + seen[KP["l_shoulder"]] - ankles
    assert np.degrees(np.arccos(chain @ up / np.linalg.norm(chain))) > 15.0
