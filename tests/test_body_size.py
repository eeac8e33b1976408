"""Body size: a given subject height and a camera height (feet on the floor) put a small person at
the right depth; BVH output keeps one skeleton of that size."""
import numpy as np
import pytest

from mocapdb.core.exports import write_tracks
from mocapdb.core.formats.bvh import forward_kinematics, read_bvh
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import axis_rotation_matrices, yaw_matrix
from mocapdb.core.skeleton import KP, PELVIS, UNIVERSAL_HEIGHT_M
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig

FOCAL, SIZE = 1000.0, (1920, 1080)


def _seen(db, clip, height_m, camera_height_m, pitch_deg, distance_m=4.0):
    """A database clip scaled to ``height_m``, turned 40°, seen by a camera ``camera_height_m`` above
    the floor and pitched down by ``pitch_deg``. Returns frames and the camera-aligned truth."""
    first, n = db.clip_first_frame[clip], db.clip_n_frames[clip]
    world = db.positions[first:first + n].astype(np.float64) * (height_m / UNIVERSAL_HEIGHT_M)  # floor at y = 0
    centre = world[:, PELVIS].mean(axis=0) * [1, 0, 1]
    world = (world - centre) @ yaw_matrix(40.0).T
    view = np.stack([world[..., 0], world[..., 1] - camera_height_m, world[..., 2] - distance_m], axis=-1)
    view = view @ axis_rotation_matrices("X", np.radians(pitch_deg)).T
    px = np.stack([SIZE[0] / 2 + FOCAL * view[..., 0] / -view[..., 2],
                   SIZE[1] / 2 - FOCAL * view[..., 1] / -view[..., 2]], axis=-1)[:, :14]
    frames = [KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9))]) for i in range(n)]
    return frames, view * [1.0, 1.0, -1.0]


def _run(db, frames, **options):
    engine = Engine(db, EngineConfig(fps=24.0, focal_px=FOCAL, image_size=SIZE, **options))
    poses = [p for f in frames for p in engine.step(f)]
    return engine, poses


@pytest.mark.parametrize("pitch", [0.0, 12.0])
def test_subject_height_puts_a_small_person_at_the_right_depth(small_db, pitch):
    frames, truth = _seen(small_db, clip=0, height_m=1.5, camera_height_m=1.4, pitch_deg=pitch)
    depth = truth[1:, PELVIS, 2]
    errors = {}
    for name, height in (("given", 1.5), ("assumed 1.75 m", None)):
        _, poses = _run(small_db, frames, subject_height_m=height)
        roots = np.array([p.root_m for p in poses])
        errors[name] = np.median(np.linalg.norm(roots - truth[1:, PELVIS], axis=-1) / depth)
        if height:
            assert all(p.height_m == pytest.approx(1.5) for p in poses)
    assert errors["given"] < 0.05
    assert errors["assumed 1.75 m"] > 0.1  # a 1.75 m body at this image size is 17 % further away


@pytest.mark.parametrize("pitch", [0.0, 12.0])
def test_camera_height_measures_the_person_from_the_feet(small_db, pitch, tmp_path):
    """A 1.5 m person, the camera 1.4 m above the floor: per frame the floor's estimate pulls the size
    from the assumed 1.75 m towards 1.5 m, weighed against people's heights by the tilt's error. The
    whole take's world weighs the floor-consistent size against the stature prior by the camera
    tilt's error: one walker shows the pitch to about 3° (its body's up; its contacts vote through
    their flatness), and 1° moves the floor under a person 4 m away by 5 % of their size, so the size
    lands between the truth and the prior, and the root lies along the true rays at that size. Its
    reported error is the posterior's, narrowed by the adult prior (1.75 m ± 5.4 %), in whose tail
    (2.7 SDs below its mean) a 1.5 m adult lies: the truth sits at the edge of its ±2 SD (1.8-2.1 SD
    off as the whole take's settings move), so the check is ±2.5 SD."""
    from mocapdb.runtime.take import take_joints
    from mocapdb.runtime.world.fuse import fit_world

    frames, truth = _seen(small_db, clip=0, height_m=1.5, camera_height_m=1.4, pitch_deg=pitch)
    engine, poses = _run(small_db, frames, camera_height_m=1.4, keep_take=True)
    assert 1.5 < poses[-1].height_m < 1.74
    (take,), world = fit_world(engine.finish(), 24.0, camera_height_m=1.4)
    size = world.people[take.track]
    assert 1.75 * take.scales[-1] == pytest.approx(size.stature_m)
    assert 1.5 < size.stature_m < 1.75
    assert abs(np.log(size.stature_m / 1.5)) < 2.5 * size.stature_log_sd
    index, _, roots = take_joints(take, 24.0)
    late = index[len(index) // 2:]
    ratio = np.linalg.norm(roots[len(index) // 2:], axis=-1) / np.linalg.norm(truth[late, PELVIS], axis=-1)
    assert np.median(ratio) == pytest.approx(size.stature_m / 1.5, rel=0.05)
    # The BVH holds one skeleton of the final size, its roots moved to that size.
    (path,) = write_tracks([take], tmp_path, 24.0)
    bvh = read_bvh(path)
    fk, _ = forward_kinematics(bvh)
    thigh = np.linalg.norm(fk[:, bvh.index("r_knee")] - fk[:, bvh.index("r_hip")], axis=-1)
    height = 1.75 * take.scales[-1]
    np.testing.assert_allclose(thigh, take.proportions_m[0] * height / UNIVERSAL_HEIGHT_M, rtol=1e-4)  # own thigh …
    assert thigh[0] == pytest.approx(0.43 * height / UNIVERSAL_HEIGHT_M, rel=0.05)  # … near this body's
    np.testing.assert_allclose(bvh.motion[-1, :3] * [1, 1, -1], roots[-1], atol=1e-4)


def test_camera_height_needs_the_refinement(small_db):
    with pytest.raises(ValueError, match="refinement"):
        EngineConfig(camera_height_m=1.5, refine=False)


def test_own_bone_proportions_are_recovered_from_the_2d(small_db):
    """A body of known, non-universal proportions (long shanks, short upper arms, broad shoulders)
    walking in front of the camera: the track's bones come out within 5 % (height given), and the
    universal body stays universal."""
    from mocapdb.core.skeleton import MEASURED_BONE_NAMES, bone_lengths_m, universal_bone_lengths_m
    from mocapdb.evaluation.bodies import reshape_body

    first, n = small_db.clip_first_frame[0], small_db.clip_n_frames[0]
    source = small_db.positions[first:first + n].astype(np.float64)
    factors = np.array([1.0, 1.12, 0.88, 1.0, 1.0, 1.1, 0.95, 1.0])
    target = universal_bone_lengths_m() * factors
    for bones, expected in ((target, target), (universal_bone_lengths_m(), universal_bone_lengths_m())):
        world = reshape_body(source, bones)
        height = 1.75 * (bones[[0, 1, 6, 7]].sum() / universal_bone_lengths_m()[[0, 1, 6, 7]].sum())
        world = (world - world[:, PELVIS].mean(axis=0) * [1, 0, 1]) @ yaw_matrix(40.0).T
        view = world - [0.0, 1.4, 4.0]
        px = np.stack([SIZE[0] / 2 + FOCAL * view[..., 0] / -view[..., 2],
                       SIZE[1] / 2 - FOCAL * view[..., 1] / -view[..., 2]], axis=-1)[:, :14]
        frames = [KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9))]) for i in range(n)]
        _, poses = _run(small_db, frames, subject_height_m=height)
        error = poses[-1].bones_m / expected - 1.0
        body = [MEASURED_BONE_NAMES.index(b) for b in ("thigh", "shank", "upper_arm", "forearm", "torso")]
        assert np.abs(error[body]).max() < 0.05, dict(zip(MEASURED_BONE_NAMES, error.round(3)))
        # the output skeleton has those bones
        np.testing.assert_allclose(bone_lengths_m(poses[-1].joints_m), poses[-1].bones_m, rtol=1e-9)
    with pytest.raises(AssertionError):  # the universal body would have missed the first
        np.testing.assert_allclose(universal_bone_lengths_m()[body], target[body], rtol=0.05)


def test_tilt_error_grows_with_the_frames_disagreement():
    """Frames whose fitted roots lean alternately ±10° about the camera's x axis: their mean up is
    level and its error is their RMS spread, 2 sin(5°) = 9.99° in closed form; frames that agree
    keep the least error, TILT_SD_DEG."""
    from mocapdb.runtime.world.body_size import TILT_SD_DEG, CameraTilt

    upright = np.array([1.0, 0.0, 0.0, 0.0])
    half = np.radians(10.0) / 2
    agreeing, leaning = CameraTilt(), CameraTilt()
    for i in range(40):
        agreeing.update(np.array([np.cos(half), np.sin(half), 0.0, 0.0]), upright)
        sign = 1.0 if i % 2 else -1.0
        leaning.update(np.array([np.cos(half), sign * np.sin(half), 0.0, 0.0]), upright)
    assert agreeing.sd_deg == pytest.approx(TILT_SD_DEG)
    np.testing.assert_allclose(agreeing.up, [0.0, np.cos(2 * half), np.sin(2 * half)], atol=1e-12)
    np.testing.assert_allclose(leaning.up, [0.0, 1.0, 0.0], atol=1e-12)
    assert leaning.sd_deg == pytest.approx(np.degrees(2 * np.sin(np.radians(5.0))), rel=1e-9)


def _filled(log_factors, n=None):
    """A BoneLengths whose bones hold ``n`` (a count, or one per bone; default all) samples of
    ``log_factors [8]``; a NaN: none."""
    from mocapdb.runtime.world.body_size import BoneLengths

    bones = BoneLengths()
    counts = np.broadcast_to(bones.CAPACITY if n is None else n, len(log_factors))
    for b, value in enumerate(log_factors):
        if np.isfinite(value):
            bones.samples[b, :counts[b]], bones.counts[b] = value, counts[b]
    return bones


def _head_on_top(world_m, neck_nose_m):
    """Joints ``[F, 15, 3]`` with the head keypoint where a head-top detector puts it: ``neck_nose_m``
    straight above the neck (along pelvis→neck)."""
    up = world_m[:, KP["neck"]] - world_m[:, PELVIS]
    out = world_m.copy()
    out[:, KP["head"]] = world_m[:, KP["neck"]] + neck_nose_m * up / np.linalg.norm(up, axis=-1, keepdims=True)
    return out


def test_a_head_top_keypoint_is_not_believed_and_does_not_shrink_the_body(monkeypatch):
    """A body of known proportions (long shanks, short upper arms) measured exactly, but its head
    keypoint on top of the head: neck→nose 1.6× the bone. That bone is not believed: the estimate is
    the body's own (neck→nose the prior's, here the truth's), as if the bone had not been measured;
    believed, it took 1.6 × 0.21 m of the 1.75 m stature and shrank the rest."""
    from mocapdb.core.skeleton import MEASURED_BONE_NAMES, stature_m, universal_bone_lengths_m
    from mocapdb.runtime.world import body_size

    universal = universal_bone_lengths_m()
    truth = universal * [1.0, 1.12, 0.88, 1.0, 1.0, 1.1, 0.95, 1.0]
    truth *= UNIVERSAL_HEIGHT_M / stature_m(truth)
    measured = np.log(truth / universal)
    nose = MEASURED_BONE_NAMES.index("neck_nose")
    head_top = measured.copy()
    head_top[nose] += np.log(1.6)
    bones = _filled(head_top)
    precision = bones.counts / bones.DECORRELATION / bones.SAMPLE_SD ** 2
    assert body_size.believed_bones(head_top, precision).tolist() == [b != nose for b in range(8)]
    estimate = bones.estimate()
    np.testing.assert_allclose(estimate, truth, rtol=0.02)  # neck→nose unmeasured: the prior's, given the rest
    without = _filled(np.where(np.arange(8) == nose, np.nan, measured)).estimate()
    np.testing.assert_allclose(estimate, without, rtol=1e-12)  # no weight at all
    monkeypatch.setattr(body_size, "PLAUSIBLE_SD", np.inf)  # the bone believed, as before
    shrunk = _filled(head_top).estimate() / truth
    assert np.all(np.delete(shrunk, nose) < 0.95)


def test_a_plausibly_long_neck_is_believed_and_few_bones_are_not_judged():
    from mocapdb.core.skeleton import MEASURED_BONE_NAMES, universal_bone_lengths_m

    nose, thigh = MEASURED_BONE_NAMES.index("neck_nose"), MEASURED_BONE_NAMES.index("thigh")
    measured = np.zeros(8)
    measured[nose] = np.log(1.1)  # a neck→nose 10 % longer than the universal proportion
    estimate = _filled(measured).estimate() / universal_bone_lengths_m()
    assert estimate[nose] / estimate[thigh] == pytest.approx(1.1, rel=0.02)
    three = np.full(8, np.nan)
    three[[thigh, nose, 1]] = [0.0, np.log(1.6), 0.0]  # two other bones measured: too few to judge by
    estimate = _filled(three).estimate() / universal_bone_lengths_m()
    assert estimate[nose] / estimate[thigh] > 1.5


def test_a_head_top_detector_keeps_the_legs_through_the_engine(small_db):
    """A walk rendered twice, the head keypoint once at the nose and once on top of the head (straight
    above the neck, 1.6 × neck→nose): the track's thigh and shank come out the same (they were 6 %
    shorter when the head-top bone was believed)."""
    from mocapdb.core.skeleton import MEASURED_BONE_NAMES, universal_bone_lengths_m

    first, n = small_db.clip_first_frame[0], small_db.clip_n_frames[0]
    world = small_db.positions[first:first + n].astype(np.float64)
    head_top = _head_on_top(world, 1.6 * universal_bone_lengths_m()[-1])
    legs = [MEASURED_BONE_NAMES.index("thigh"), MEASURED_BONE_NAMES.index("shank")]
    found = []
    for body in (world, head_top):
        view = (body - body[:, PELVIS].mean(axis=0) * [1, 0, 1]) @ yaw_matrix(40.0).T - [0.0, 1.4, 4.0]
        px = np.stack([SIZE[0] / 2 + FOCAL * view[..., 0] / -view[..., 2],
                       SIZE[1] / 2 - FOCAL * view[..., 1] / -view[..., 2]], axis=-1)[:, :14]
        _, poses = _run(small_db, [KeypointFrame(i, i / 24.0, [Person(px[i], np.full(14, 0.9))]) for i in range(n)])
        found.append(poses[-1].bones_m)
    np.testing.assert_allclose(found[1][legs], found[0][legs], rtol=0.03)
    assert found[1][-1] == pytest.approx(found[0][-1], rel=0.05)  # neck→nose: the prior's, not 1.6×


@pytest.mark.parametrize("offset, believed", [(0.385, True), (0.396, False), (-0.385, True), (-0.396, False)])
def test_the_plausible_range_of_neck_nose_by_hand(offset, believed):
    """Seven bones at the common size, measured without error, and neck→nose ``offset`` off. By hand:
    neck→nose is uncorrelated, so the SD of it minus the others' mean is √(0.07² + 0.1² + (1ᵀΣ1 +
    7 × 0.1²) / 7²), 1ᵀΣ1 over the seven = 0.018675 (variances) + 2 × 0.0058575 (the nine correlated
    pairs) = 0.03039: SD 0.130188, a limit of 3 SD = 0.3906."""
    from mocapdb.runtime.world.body_size import believed_bones

    medians = np.full(8, 0.02)
    medians[-1] += offset
    assert believed_bones(medians, np.full(8, np.inf)).tolist() == [True] * 7 + [believed]
