"""The 2D refinement: numba primitives against scipy, analytic gradients against finite differences,
and what the fit must do (recover a rendered pose, ignore a wrong keypoint, keep the prior's depth
order, hold joint limits, leave unseen joints to the prior)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.geometry import quat_mul
from mocapdb.core.kernels import cholesky_solve_into, quat_exp_into, quat_relative_log_into, right_jacobian_inverse_into
from mocapdb.core.skeleton import KP, RIG_JOINTS, pose_from_rotations
from mocapdb.runtime import refine
from mocapdb.runtime.refine import JointLimits, RefineParams, Refiner, rotation_vectors

FOCAL, CENTER = 1000.0, (960.0, 540.0)
ROOT = np.array([0.2, -0.4, -5.0])  # view frame: 5 m in front of the camera


def _scipy_quat(q):
    return Rotation.from_quat(np.asarray(q)[..., [1, 2, 3, 0]])


def _quat(rotvec):
    return Rotation.from_rotvec(rotvec).as_quat()[..., [3, 0, 1, 2]]


def _project(points):
    return np.stack([CENTER[0] + FOCAL * points[:, 0] / -points[:, 2],
                     CENTER[1] - FOCAL * points[:, 1] / -points[:, 2]], axis=-1)


def _render(quats, root=ROOT, scale=1.0):
    joints = pose_from_rotations(quats[None], root[None] / scale)[0] * scale
    return joints, _project(joints[:14])


def _perturbed(quats, sigma_rad, seed):
    noise = np.random.default_rng(seed).normal(scale=sigma_rad, size=(len(quats), 3))
    return quat_mul(quats, _quat(noise))


def _relative_error_m(a, b):
    return np.linalg.norm((a - a[14]) - (b - b[14]), axis=-1).mean()


@pytest.fixture(scope="module")
def limits(small_db):
    return JointLimits.from_rotations(small_db.quaternions)


@pytest.fixture(scope="module")
def no_limits():
    return JointLimits(np.full((11, 3), -np.inf), np.full((11, 3), np.inf))


@pytest.fixture(scope="module")
def pose(small_db):
    """A real captured pose (walking, database frame 40) turned to face the camera at 30°."""
    q = small_db.quaternions[40].astype(np.float64)
    q[0] = quat_mul(_quat(np.array([0.0, np.radians(30.0), 0.0])), q[0])
    return q


def test_log_exp_and_inverse_right_jacobian_match_scipy():
    rng = np.random.default_rng(1)
    out3, out4, jr = np.empty(3), np.empty(4), np.empty((3, 3))
    for _ in range(20):
        a, b = Rotation.random(random_state=rng), Rotation.random(random_state=rng)
        qa, qb = a.as_quat()[[3, 0, 1, 2]], b.as_quat()[[3, 0, 1, 2]]
        quat_relative_log_into(qa, -qb, out3)  # the double cover does not matter
        np.testing.assert_allclose(out3, (a.inv() * b).as_rotvec(), atol=1e-9)
        v = rng.normal(size=3)
        quat_exp_into(v, out4)
        np.testing.assert_allclose(_scipy_quat(out4).as_matrix(), Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
        # log(exp(φ) exp(δ)) ≈ φ + J_r⁻¹(φ) δ
        phi = rng.normal(size=3) * 0.8
        right_jacobian_inverse_into(phi, jr)
        eps = 1e-6
        for c in range(3):
            delta = np.zeros(3)
            delta[c] = eps
            moved = (Rotation.from_rotvec(phi) * Rotation.from_rotvec(delta)).as_rotvec()
            np.testing.assert_allclose((moved - phi) / eps, jr[:, c], atol=1e-5)


def test_cholesky_solve_matches_numpy():
    rng = np.random.default_rng(2)
    m = rng.normal(size=(36, 36))
    a = m @ m.T + 36 * np.eye(36)
    b = rng.normal(size=36)
    x = np.empty(36)
    assert cholesky_solve_into(a.copy(), b, 36, x)
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-10)
    assert not cholesky_solve_into(-np.eye(36), b, 36, x)


def _cost_and_gradient(refiner, quats, root, points, conf, prior, prev, world=refine.NO_WORLD):
    """The kernel's cost and its Gauss–Newton gradient (half the cost's gradient)."""
    args = (1.0, points, conf, refine._box_height(points, conf), prior, prev, True, FOCAL, *CENTER,
            refiner._params, refiner.limits.lo, refiner.limits.hi, refine._RIG, world, refiner._ws)
    cost = refine._cost(quats, root, *args)
    refine._linearise(quats, root, *args)
    return cost, refiner._ws[5].copy()


def _numeric_gradient(refiner, quats, root, points, conf, prior, prev, world=refine.NO_WORLD, eps=1e-6):
    """The cost's gradient by forward differences: the root, then each joint's increment δ."""
    cost = _cost_and_gradient(refiner, quats, root, points, conf, prior, prev, world)[0]
    numeric = np.empty(refine.N_PARAMS)
    for i in range(refine.N_PARAMS):
        q, r = quats.copy(), root.copy()
        if i < 3:
            r[i] += eps
        else:
            j, c = divmod(i - 3, 3)
            delta = np.zeros(3)
            delta[c] = eps
            q[j] = quat_mul(q[j], _quat(delta))
        numeric[i] = (_cost_and_gradient(refiner, q, r, points, conf, prior, prev, world)[0] - cost) / eps
    return numeric


def test_analytic_gradient_matches_finite_differences(pose, limits):
    # Every term active: keypoints off (some far: robust), priors off, a knee outside its limits.
    quats = _perturbed(pose, 0.3, seed=3)
    quats[RIG_JOINTS.index("r_knee")] = _quat(np.array([-0.6, 0.0, 0.0]))
    _, points = _render(pose)
    points[KP["l_wrist"]] += [120.0, -80.0]
    conf = np.linspace(0.4, 1.0, 14)
    prior, prev = _perturbed(pose, 0.2, seed=4), _perturbed(pose, 0.2, seed=5)
    refiner = Refiner(RefineParams(), limits)
    root = ROOT + [0.1, -0.05, 0.3]
    cost, grad = _cost_and_gradient(refiner, quats, root, points, conf, prior, prev)
    numeric = _numeric_gradient(refiner, quats, root, points, conf, prior, prev)
    np.testing.assert_allclose(2.0 * grad, numeric, atol=2e-5 * np.abs(numeric).max())


def _world_bones(truth_joints, weights):
    """The limb, girdle and side bones of ``truth_joints [15, 3]`` (view frame) as the fit's world bones."""
    pairs = [("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"), ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"),
             ("r_hip", "r_knee"), ("r_knee", "r_ankle"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"),
             ("r_shoulder", "l_shoulder"), ("r_hip", "l_hip"), ("r_hip", "r_shoulder"), ("l_hip", "l_shoulder")]
    start, end = np.array([KP[a] for a, _ in pairs]), np.array([KP[b] for _, b in pairs])
    bones = truth_joints[end] - truth_joints[start]
    return refine.WorldBones(start, end, bones / np.linalg.norm(bones, axis=-1, keepdims=True),
                             np.asarray(weights, dtype=np.float64))


def test_analytic_gradient_of_the_world_bones_matches_finite_differences(pose, no_limits):
    # World bones of another pose (some bones far off: robust), no other term.
    quats = _perturbed(pose, 0.3, seed=3)
    other = _perturbed(pose, 0.8, seed=11)
    world = _world_bones(pose_from_rotations(other[None], ROOT[None])[0], np.linspace(0.2, 3.0, 12)).as_tuple()
    _, points = _render(pose)
    refiner = Refiner(RefineParams(prior_root=0.0, prior_joint=0.0, previous=0.0, world_scale=0.4), no_limits)
    off = np.zeros(14)
    root = ROOT + [0.1, -0.05, 0.3]
    cost, grad = _cost_and_gradient(refiner, quats, root, points, off, quats, quats, world)
    assert cost > 0.1
    numeric = _numeric_gradient(refiner, quats, root, points, off, quats, quats, world)
    np.testing.assert_allclose(2.0 * grad, numeric, atol=2e-5 * np.abs(numeric).max())


def test_world_bones_decide_the_depth_order_the_image_cannot(no_limits):
    # Arms stretched forward; the fit starts from arms stretched backward (the same image, nearly):
    # the image alone keeps them back, the detector's 3D brings them forward.
    q = np.zeros((11, 4))
    q[:, 0] = 1.0
    forward, backward = q.copy(), q.copy()
    for side, sign in (("r_shoulder", 1.0), ("l_shoulder", -1.0)):
        forward[RIG_JOINTS.index(side)] = _quat(np.array([0.0, sign * np.radians(80.0), 0.0]))
        backward[RIG_JOINTS.index(side)] = _quat(np.array([0.0, -sign * np.radians(80.0), 0.0]))
    truth, points = _render(forward)
    world = _world_bones(truth, np.ones(12))
    runs = {}
    for name, given in (("image", None), ("image and world", world)):
        quats, root = backward.copy(), ROOT.copy()
        Refiner(RefineParams(iterations=10, world_scale=2.0), no_limits)(quats, root, 1.0, points, np.ones(14),
                                                                         backward, None, FOCAL, CENTER, world=given)
        runs[name] = pose_from_rotations(quats[None], root[None])[0]
    assert runs["image"][KP["r_wrist"], 2] < runs["image"][KP["neck"], 2]   # still behind
    assert runs["image and world"][KP["r_wrist"], 2] > runs["image and world"][KP["neck"], 2] + 0.3
    assert _relative_error_m(runs["image and world"], truth) < 0.03


def test_a_rendered_pose_is_recovered_from_a_neighbouring_pose(small_db, pose, no_limits):
    # Retrieval returns a pose near the truth (here the captured pose 1/12 s later): the fit
    # makes it explain the image and brings it closer in 3D.
    truth, points = _render(pose)
    start = small_db.quaternions[42].astype(np.float64)
    start[0] = quat_mul(_quat(np.array([0.0, np.radians(30.0), 0.0])), start[0])
    quats, root = start.copy(), ROOT + [0.05, 0.05, 0.4]
    start_error = _relative_error_m(pose_from_rotations(start[None], root[None])[0], truth)
    Refiner(RefineParams(), no_limits)(quats, root, 1.0, points, np.ones(14), start, None, FOCAL, CENTER)
    refined = pose_from_rotations(quats[None], root[None])[0]
    assert start_error > 0.02
    assert np.abs(_project(refined[:14]) - points).max() < 1.0  # pixels
    assert _relative_error_m(refined, truth) < 0.3 * start_error
    assert np.linalg.norm(root - ROOT) < 0.05


def test_scale_makes_a_smaller_body_at_the_same_image_size(pose, no_limits):
    truth, points = _render(pose, ROOT * 0.8, scale=0.8)
    quats, root = pose.copy(), ROOT * 0.8 * 1.1
    Refiner(RefineParams(iterations=10), no_limits)(quats, root, 0.8, points, np.ones(14), pose, None, FOCAL, CENTER)
    np.testing.assert_allclose(root, ROOT * 0.8, atol=0.02)


def test_one_wrong_keypoint_does_not_drag_the_limb(pose, no_limits):
    # The right wrist detected on the other side of the body: the robust fit must end where it
    # ends when the wrist is not seen at all; plain least squares drags the arm across.
    truth, points = _render(pose)
    wrong = points.copy()
    wrong[KP["r_wrist"]] = points[KP["l_wrist"]] + [40.0, 60.0]
    unseen = np.ones(14)
    unseen[KP["r_wrist"]] = 0.0
    start = _perturbed(pose, 0.1, seed=7)
    runs = {"robust": (RefineParams(), wrong, np.ones(14)),
            "least squares": (RefineParams(robust_scale=1e3), wrong, np.ones(14)),
            "wrist unseen": (RefineParams(), points, unseen)}
    arm = [KP["r_elbow"], KP["r_wrist"]]
    result = {}
    for name, (params, image, conf) in runs.items():
        quats, root = start.copy(), ROOT.copy()
        Refiner(params, no_limits)(quats, root, 1.0, image, conf, start, None, FOCAL, CENTER)
        result[name] = pose_from_rotations(quats[None], root[None])[0][arm]
    assert np.linalg.norm(result["robust"] - result["wrist unseen"], axis=-1).max() < 0.02
    assert np.linalg.norm(result["least squares"] - truth[arm], axis=-1).max() > 0.15


def test_the_prior_keeps_the_depth_order(no_limits):
    # Arms stretched forward towards the camera: the image cannot tell forward from backward.
    q = np.zeros((11, 4))
    q[:, 0] = 1.0
    q[RIG_JOINTS.index("r_shoulder")] = _quat(np.array([0.0, np.radians(80.0), 0.0]))
    q[RIG_JOINTS.index("l_shoulder")] = _quat(np.array([0.0, -np.radians(80.0), 0.0]))
    truth, points = _render(q)
    assert truth[KP["r_wrist"], 2] > truth[KP["neck"], 2] + 0.3  # nearer the camera
    start = _perturbed(q, 0.05, seed=8)
    quats, root = start.copy(), ROOT.copy()
    Refiner(RefineParams(), no_limits)(quats, root, 1.0, points, np.ones(14), start, None, FOCAL, CENTER)
    refined = pose_from_rotations(quats[None], root[None])[0]
    for wrist in ("r_wrist", "l_wrist"):
        assert refined[KP[wrist], 2] > refined[KP["neck"], 2] + 0.3
    assert _relative_error_m(refined, truth) < 0.02


def test_joint_limits_hold_against_an_impossible_image(pose, limits):
    # A right knee bent 60° the wrong way (hyperextended), seen from the side so the image shows
    # which way it bends: the fit may not follow it.
    side = pose.copy()
    side[0] = quat_mul(_quat(np.array([0.0, np.radians(60.0), 0.0])), pose[0])
    impossible = side.copy()
    knee = RIG_JOINTS.index("r_knee")
    impossible[knee] = _quat(np.array([-np.radians(60.0), 0.0, 0.0]))
    _, points = _render(impossible)
    for weight, holds in ((RefineParams().limits, True), (0.0, False)):
        quats, root = side.copy(), ROOT.copy()
        params = RefineParams(iterations=10, prior_joint=1e-5, limits=weight)
        Refiner(params, limits)(quats, root, 1.0, points, np.ones(14), side, None, FOCAL, CENTER)
        flexion = rotation_vectors(quats[knee])[0]
        assert (flexion >= limits.lo[knee, 0] - np.radians(3.0)) == holds


def test_unseen_joints_stay_with_the_prior(pose, no_limits):
    truth, points = _render(pose)
    conf = np.ones(14)
    conf[[KP["l_elbow"], KP["l_wrist"]]] = 0.0
    points[[KP["l_elbow"], KP["l_wrist"]]] = 0.0  # whatever is there is not used
    start = _perturbed(pose, 0.1, seed=9)
    quats, root = start.copy(), ROOT.copy()
    Refiner(RefineParams(), no_limits)(quats, root, 1.0, points, conf, start, None, FOCAL, CENTER)
    elbow = RIG_JOINTS.index("l_elbow")
    relative = _scipy_quat(start[elbow]).inv() * _scipy_quat(quats[elbow])
    assert np.degrees(relative.magnitude()) < 1.0
    seen = np.flatnonzero(conf)
    before = pose_from_rotations(start[None], ROOT[None])[0]
    refined = pose_from_rotations(quats[None], root[None])[0]
    error = np.linalg.norm(_project(refined[seen]) - points[seen], axis=-1).mean()
    assert error < 0.2 * np.linalg.norm(_project(before[seen]) - points[seen], axis=-1).mean()


def test_joint_limits_come_from_the_database(small_db, limits):
    logs = rotation_vectors(small_db.quaternions.astype(np.float64))
    inside = (logs[:, 1:] >= limits.lo[1:]) & (logs[:, 1:] <= limits.hi[1:])
    assert inside.mean() > 0.999
    knee = RIG_JOINTS.index("l_knee")
    assert limits.hi[knee, 0] > np.radians(60) and limits.lo[knee, 0] < 0.0  # flexes forward only
    assert np.isinf(limits.lo[0]).all()
