"""ElliPose core (mocapdb.stereo: ellipose, ellipsoid, bone_lengths, relative_pose, checks): ellipsoid fit,
undistortion, stage 3, camera recovery, bad inputs."""
import cv2
import numpy as np
import pytest

from mocapdb.core.cameras import CameraModel
from mocapdb.core.clips import ClipOptions, process_clip
from mocapdb.evaluation import stereo as eval_stereo
from mocapdb.stereo.bone_lengths import RIGID_BONES, refine_bone_lengths
from mocapdb.stereo.checks import check_geometry, check_parallax, check_synchronised
from mocapdb.stereo.config import StereoConfig, StereoError
from mocapdb.stereo.ellipose import _stage2, converged, reconstruct
from mocapdb.stereo.ellipsoid import fit_ellipsoid, ransac_ellipsoid, sphericity, undistort
from mocapdb.stereo.outputs import StereoSummary
from mocapdb.stereo.people import Selection
from mocapdb.stereo.relative_pose import rotation_angle_deg, triangulate, triangulate_all, triangulation_covariance

from .conftest import SAMPLE_BVH

N_TYPES = 6


def _random_shape(rng, spread=0.3):
    """A symmetric positive definite ``A`` with trace 3 and its eigen-decomposition."""
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    values = 1.0 + rng.uniform(-spread, spread, 3)
    values *= 3.0 / values.sum()
    return q @ np.diag(values) @ q.T


def _on_ellipsoid(A, scales, per_type, rng):
    """Vectors with ``vᵀ A v = scale_b²``: uniform directions mapped through ``A^{-1/2}``."""
    values, vectors = np.linalg.eigh(A)
    inv_sqrt = vectors @ np.diag(values ** -0.5) @ vectors.T
    types = np.repeat(np.arange(len(scales)), per_type)
    u = rng.normal(size=(len(types), 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return (u @ inv_sqrt.T) * scales[types, None], types


def test_sphericity_hand_computed():
    assert sphericity(np.eye(3)) == pytest.approx(0.0)
    assert sphericity(5 * np.eye(3)) == pytest.approx(0.0)          # scale does not count
    # diag(2, 1, 1) → trace 3: diag(1.5, 0.75, 0.75): 0.25 + 0.0625 + 0.0625
    assert sphericity(np.diag([2.0, 1.0, 1.0])) == pytest.approx(0.375)


def test_fit_recovers_a_known_ellipsoid_and_per_bone_scales():
    rng = np.random.default_rng(0)
    A = _random_shape(rng)
    scales = np.array([0.2, 0.43, 0.42, 0.38, 0.29, 0.26])
    vectors, types = _on_ellipsoid(A, scales, 400, rng)
    vectors += rng.normal(0, 0.002, vectors.shape)                    # 2 mm noise
    fitted, fitted_scales = fit_ellipsoid(vectors, types, N_TYPES)
    assert np.trace(fitted) == pytest.approx(3.0)
    np.testing.assert_allclose(fitted, A, atol=0.02)
    np.testing.assert_allclose(fitted_scales, scales, rtol=0.01)


def test_ransac_ignores_gross_outliers_that_break_the_plain_fit():
    rng = np.random.default_rng(1)
    A = _random_shape(rng)
    scales = np.array([0.2, 0.43, 0.42, 0.38, 0.29, 0.26])
    vectors, types = _on_ellipsoid(A, scales, 300, rng)
    vectors += rng.normal(0, 0.002, vectors.shape)
    bad = rng.random(len(vectors)) < 0.1
    vectors[bad] *= rng.uniform(1.6, 2.5, (bad.sum(), 1))             # mis-detections: far too long
    plain, _ = fit_ellipsoid(vectors, types, N_TYPES)
    robust, robust_scales, inliers = ransac_ellipsoid(vectors, types, N_TYPES, 300, StereoConfig(),
                                                      np.random.default_rng(0))
    assert np.abs(plain - A).max() > 0.05
    np.testing.assert_allclose(robust, A, atol=0.03)
    np.testing.assert_allclose(robust_scales, scales, rtol=0.02)
    assert not inliers[bad].any() and inliers[~bad].mean() > 0.95


def test_noise_covariance_matches_the_empirical_triangulation_error():
    rng = np.random.default_rng(2)
    R, _ = cv2.Rodrigues(np.array([0.0, -0.6, 0.05]))
    t = np.array([1.0, 0.0, 0.3]) / np.linalg.norm([1.0, 0.0, 0.3])
    point = np.array([0.2, -0.1, 2.5])
    sigma = 0.004
    clean1 = point[:2] / point[2]
    q = R @ point + t
    clean2 = q[:2] / q[2]
    n1 = clean1 + rng.normal(0, sigma, (4000, 2))
    n2 = clean2 + rng.normal(0, sigma, (4000, 2))
    P1, P2 = np.hstack([np.eye(3), np.zeros((3, 1))]), np.hstack([R, t[:, None]])
    points = triangulate(P1, P2, n1, n2)
    predicted = triangulation_covariance(points, R, t, n1, n2).mean(axis=0)
    np.testing.assert_allclose(predicted, np.cov(points.T), rtol=0.15, atol=0.02 * np.abs(np.cov(points.T)).max())


def test_undistortion_of_a_known_linear_distortion():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(50, 3))
    stretch = _random_shape(rng, spread=0.4)                # symmetric: distorted = stretch · true
    distorted = points @ stretch.T
    # bone vectors of the distorted world satisfy vᵀ A v = const with A ∝ stretch⁻²
    A = np.linalg.inv(stretch @ stretch)
    full = undistort(distorted, A, gamma=1.0)
    ratio = full / points
    np.testing.assert_allclose(ratio, ratio[0, 0], rtol=1e-9)          # the true shape up to one scale
    np.testing.assert_allclose(undistort(distorted, A, gamma=0.0), distorted)
    values, vectors = np.linalg.eigh(A * 3 / np.trace(A))
    half = vectors @ np.diag(0.5 + 0.5 * np.sqrt(values)) @ vectors.T  # the γ = 0.2 ... 1 family, γ = 0.5
    np.testing.assert_allclose(undistort(distorted, A, gamma=0.5), distorted @ half.T)


def _dense_stage3(points, P1, P2, n1, n2, alpha):
    """One stage-3 round as one dense least-squares problem per frame (np.linalg.lstsq)."""
    pairs = np.array([(i, j) for i, j, _ in RIGID_BONES])
    vec = points[:, pairs[:, 1]] - points[:, pairs[:, 0]]
    length = np.linalg.norm(vec, axis=-1)
    target = vec * (length.mean(axis=0) / length)[..., None]
    n_joints = points.shape[1]
    out = np.zeros_like(points)
    for f in range(len(points)):
        rows, rhs = [], []
        for P, n in ((P1, n1[f]), (P2, n2[f])):
            for k in range(n_joints):
                for axis in range(2):
                    row = np.zeros(3 * n_joints)
                    full = n[k, axis] * P[2] - P[axis]
                    row[3 * k:3 * k + 3] = full[:3]
                    rows.append(row)
                    rhs.append(-full[3])
        for b, (i, j) in enumerate(pairs):
            for axis in range(3):
                row = np.zeros(3 * n_joints)
                row[3 * j + axis], row[3 * i + axis] = np.sqrt(alpha), -np.sqrt(alpha)
                rows.append(row)
                rhs.append(np.sqrt(alpha) * target[f, b, axis])
        out[f] = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0].reshape(n_joints, 3)
    return out


def test_stage3_matches_a_dense_solve():
    rng = np.random.default_rng(4)
    n_frames, n_joints = 3, 14
    truth = rng.normal(0, 0.4, (n_frames, n_joints, 3)) + np.array([0.0, 0.0, 4.0])
    R, _ = cv2.Rodrigues(np.array([0.0, -0.8, 0.0]))
    t = np.array([-1.0, 0.0, 0.4])
    P1, P2 = np.hstack([np.eye(3), np.zeros((3, 1))]), np.hstack([R, t[:, None]])
    n1 = truth[..., :2] / truth[..., 2:] + rng.normal(0, 0.003, (n_frames, n_joints, 2))
    q = truth @ R.T + t
    n2 = q[..., :2] / q[..., 2:] + rng.normal(0, 0.003, (n_frames, n_joints, 2))
    start = truth + rng.normal(0, 0.02, truth.shape)
    valid = np.ones((n_frames, n_joints), bool)
    ours = refine_bone_lengths(start, P1, P2, n1, n2, valid, alpha=20.0, rounds=1)
    np.testing.assert_allclose(ours, _dense_stage3(start, P1, P2, n1, n2, 20.0), atol=1e-9)


def test_stage3_makes_bone_lengths_constant():
    rng = np.random.default_rng(5)
    clip = process_clip(SAMPLE_BVH / "005_11.bvh", SAMPLE_BVH, ClipOptions(fps=30.0)).positions[:, :14]
    cam1, cam2 = eval_stereo.pair_cameras("side", clip.mean(axis=(0, 1)))
    (x1, c1), (x2, c2) = (eval_stereo.render(clip, c, rng, 3.0, 0.0) for c in (cam1, cam2))
    valid = (c1 > 0) & (c2 > 0)
    n1, n2 = np.zeros(x1.shape), np.zeros(x2.shape)
    n1[valid], n2[valid] = cam1.undistort_normalized(x1[valid]), cam2.undistort_normalized(x2[valid])
    R, t = cam2.R @ cam1.R.T, cam2.t - cam2.R @ cam1.R.T @ cam1.t
    raw = triangulate_all(R, t, n1, n2, valid)
    P1, P2 = np.hstack([np.eye(3), np.zeros((3, 1))]), np.hstack([R, t[:, None]])
    fixed = refine_bone_lengths(np.nan_to_num(raw), P1, P2, n1, n2, valid)
    pairs = np.array([(i, j) for i, j, _ in RIGID_BONES])

    def spread(points):
        lengths = np.linalg.norm(points[:, pairs[:, 1]] - points[:, pairs[:, 0]], axis=-1)
        return np.nanmean(np.nanstd(lengths, axis=0))

    assert spread(fixed) < 0.3 * spread(raw)


@pytest.fixture(scope="module")
def dance():
    """A bundled clip with varied bone directions (dance steps, a pirouette), 30 fps, metres."""
    return process_clip(SAMPLE_BVH / "005_11.bvh", SAMPLE_BVH, ClipOptions(fps=30.0)).positions[:, :14]


def _pair(positions, kind, noise_px, seed=0):
    cam1, cam2 = eval_stereo.pair_cameras(kind, positions.mean(axis=(0, 1)))
    rng = np.random.default_rng(seed)
    (x1, c1), (x2, c2) = (eval_stereo.render(positions, c, rng, noise_px, 0.0) for c in (cam1, cam2))
    rel_R = cam2.R @ cam1.R.T
    return cam1, cam2, (x1, c1, x2, c2), rel_R, cam2.t - rel_R @ cam1.t


@pytest.mark.parametrize("kind", ["side", "front"])
def test_camera_recovery_on_synthetic_cameras(dance, kind):
    cam1, cam2, views, rel_R, rel_t = _pair(dance, kind, noise_px=1.0)
    distance = float(np.linalg.norm(rel_t))
    result = reconstruct(*views, cam1, cam2, StereoConfig(camera_distance_m=distance))
    assert rotation_angle_deg(result.R @ rel_R.T) < 1.0
    direction = np.degrees(np.arccos(np.clip(result.t @ rel_t / distance ** 2, -1, 1)))
    assert direction < 1.0
    truth = dance @ cam1.R.T + cam1.t                                 # camera-1 frame, metres
    error = np.linalg.norm(result.points_m - truth, axis=-1)[result.valid]
    assert np.median(error) < 0.03


def test_ellipsoid_rounds_undo_a_wrong_camera(dance):
    """Noise-free views, camera 2 turned 8° off: the ellipsoid rounds bring it back."""
    cam1, cam2, (x1, c1, x2, c2), rel_R, rel_t = _pair(dance, "front", noise_px=0.0)
    valid = (c1 > 0) & (c2 > 0)
    n1, n2 = np.zeros(x1.shape), np.zeros(x2.shape)
    n1[valid], n2[valid] = cam1.undistort_normalized(x1[valid]), cam2.undistort_normalized(x2[valid])
    wrong = cv2.Rodrigues(np.array([0.0, np.radians(8.0), 0.0]))[0] @ rel_R
    t = rel_t / np.linalg.norm(rel_t)
    config = StereoConfig(epsilon=0.001)
    start = triangulate_all(wrong, t, n1, n2, valid)
    _, R, _, epsilons, kept = _stage2(start, n1, n2, valid, wrong, t, config, RIGID_BONES, [])
    assert kept > 0 and epsilons[kept] < epsilons[0]
    assert rotation_angle_deg(R @ rel_R.T) < 0.3 * 8.0


def test_too_few_correspondences():
    x = np.zeros((3, 14, 2))
    c = np.zeros((3, 14))
    c[:, :2] = 1.0
    cam = eval_stereo.look_at(np.array([0.0, 1.5, -4.0]), np.zeros(3))
    with pytest.raises(StereoError, match="correspondences"):
        reconstruct(x, c, x, c, cam, cam, StereoConfig())


def test_mismatched_views():
    cam = eval_stereo.look_at(np.array([0.0, 1.5, -4.0]), np.zeros(3))
    with pytest.raises(StereoError, match="do not match"):
        reconstruct(np.zeros((10, 14, 2)), np.ones((10, 14)), np.zeros((9, 14, 2)), np.ones((9, 14)),
                    cam, cam, StereoConfig())


@pytest.mark.parametrize("epsilons, expected", [
    ([0.07, 0.03, 0.024], True),                          # the method's stop
    ([0.07, 0.045, 0.05, 0.055, 0.049, 0.06, 0.052], True),  # the lowest (0.045) not lowered in 5 rounds: a floor
    ([0.07, 0.045, 0.05, 0.055, 0.049, 0.06], False),       # 4 rounds after it: still falling, perhaps
    ([0.2, 0.15, 0.16, 0.17, 0.16, 0.18, 0.17], False),     # a floor, but no sphere: above 0.1
    ([], None)])
def test_the_ellipsoid_rounds_converge_at_the_stop_or_on_a_floor_near_a_sphere(epsilons, expected):
    assert converged(epsilons, StereoConfig()) is expected


def test_an_ellipsoid_fit_that_cannot_converge_is_warned_once(dance, caplog):
    """A body 30 % longer along the vertical than across (no rigid skeleton): under any camera pose its
    bone vectors lie on an ellipsoid, never a sphere, so ε stays ≈ 0.15 in all 20 rounds."""
    centre = dance.mean(axis=(0, 1))
    stretched = (dance[:150] - centre) * [1.0, 1.3, 1.0] + centre
    cam1, cam2, views, _, _ = _pair(stretched, "side", noise_px=1.0)
    with caplog.at_level("WARNING", logger="mocapdb.stereo"):
        result = reconstruct(*views, cam1, cam2, StereoConfig())
    assert result.converged is False and len(result.epsilons) == 20 and min(result.epsilons) > 0.1
    warned = [w for w in result.warnings if "did not converge" in w]
    assert warned == [f"the ellipsoid fit did not converge: ε stayed at or above 0.025 in all 20 round(s) and did "
                      f"not settle below 0.1 (at most 20; last ε {result.epsilons[-1]:.4f}; round "
                      f"{result.kept_round}, ε {result.epsilons[result.kept_round]:.4f}, is kept)"
                      + warned[0].split("is kept)")[1]]
    assert [r.getMessage() for r in caplog.records] == warned
    summary = StereoSummary(150, {}, result.epsilons, result.kept_round, 90.0, 1.0, False, "legs", warned, {}, [],
                            [], [], result.converged)
    assert f"kept round {result.kept_round}, not converged (warning below)" in summary.report()
    assert f"warning: {warned[0]}" in summary.report()
    cam1, cam2, views, _, _ = _pair(dance[:150], "side", noise_px=1.0)
    rigid = reconstruct(*views, cam1, cam2, StereoConfig())
    assert rigid.converged is True and not any("did not converge" in w for w in rigid.warnings)


@pytest.mark.parametrize("case", ["still", "short"])
def test_a_still_or_short_sequence_falls_back_to_stage1(dance, case):
    motion = np.repeat(dance[:1], 60, axis=0) if case == "still" else dance[:8]
    cam1, cam2, views, rel_R, _ = _pair(motion, "side", noise_px=0.0)
    result = reconstruct(*views, cam1, cam2, StereoConfig())
    assert any("too still" in w for w in result.warnings)
    assert result.kept_round == 0 and result.epsilons == [] and result.converged is None
    assert np.isfinite(result.points_m[result.valid]).all()


# --- sanity checks (issue 13) ---------------------------------------------------------------------

@pytest.mark.parametrize("distance", [0.0, -5.0, float("inf"), float("nan"), 1e308])
def test_a_camera_distance_must_be_positive(distance):
    from mocapdb.core.domains import DomainError

    with pytest.raises(DomainError, match="camera_distance_m .*: must be a distance between the two cameras"):
        StereoConfig(camera_distance_m=distance)
    assert StereoConfig(camera_distance_m=2.5).camera_distance_m == 2.5


def test_check_geometry_refuses_a_camera_facing_away_and_no_parallax():
    rng = np.random.default_rng(0)
    points = rng.normal(0.0, 0.3, (50, 14, 3)) + [0.0, 0.0, 4.0]      # in front of camera 1
    valid = np.ones((50, 14), bool)
    turned = cv2.Rodrigues(np.array([0.0, np.pi, 0.0]))[0]            # camera 2 turned 180°, 1 unit aside
    with pytest.raises(StereoError, match=r"camera 2 at rotation 180.0°.*puts the people behind camera 2 in 50 of "
                                          r"50 frames: it cannot be right"):
        check_geometry(points, valid, turned, np.array([1.0, 0.0, 0.0]))
    # camera 2 on the other side of the people, facing camera 1: right
    assert check_geometry(points, valid, turned, np.array([0.0, 0.0, 8.0])) == []
    behind = points.copy()
    behind[:30, :, 2] *= -1                                           # most frames behind camera 1
    with pytest.raises(StereoError, match="behind camera 1 in 30 of 50 frames"):
        check_geometry(behind, valid, np.eye(3), np.array([1.0, 0.0, 0.0]))
    # cameras side by side (baseline 1 unit): the people 1000 units away, 20 units away, 3 units away
    with pytest.raises(StereoError, match=r"almost no parallax \(the rays of a joint meet at a median 0.06°"):
        check_geometry(points + [0.0, 0.0, 996.0], valid, np.eye(3), np.array([1.0, 0.0, 0.0]))
    warned = check_geometry(points + [0.0, 0.0, 16.0], valid, np.eye(3), np.array([1.0, 0.0, 0.0]))
    assert len(warned) == 1 and warned[0].startswith("little parallax between the views")
    assert check_geometry(points - [0.0, 0.0, 1.0], valid, np.eye(3), np.array([1.0, 0.0, 0.0])) == []


def test_check_parallax_refuses_views_one_homography_maps():
    rng = np.random.default_rng(1)
    n1 = rng.uniform(-0.3, 0.3, (200, 2))
    essential = np.cross(np.eye(3), np.array([1.0, 0.0, 0.0]))        # [t]× for R = I, t = x
    with pytest.raises(StereoError, match="no parallax: one homography maps"):
        check_parallax(n1, n1 * 1.1 + 0.02, essential, 1000.0)


def test_parallax_is_judged_per_person(dance):
    """A still person far behind is nearly flat: one homography maps its keypoints whatever the baseline, and
    its keypoints, repeated every frame, can outnumber a moving person's: their joint median said "no parallax"
    (the demo video's cameras 1 and 2: 8.1 px against 2.8 px). Per person, the moving one shows the parallax; one
    homography mapping every person (the same view shifted) is still refused."""
    cam1, cam2, _, rel_R, rel_t = _pair(dance, "front", noise_px=0.0)
    essential = np.cross(np.eye(3), rel_t) @ rel_R                    # [t]× R
    rng = np.random.default_rng(0)
    moving = (dance[:20] @ cam1.R.T + cam1.t).reshape(-1, 3)         # camera 1's axes
    flat = np.repeat(np.c_[rng.uniform(-0.1, 0.1, (14, 2)), np.ones(14)] * 12.0, 100, axis=0)  # 12 m away
    points = np.concatenate([flat, moving])
    n1 = points[:, :2] / points[:, 2:] + rng.normal(0.0, 0.5 / 1145, (len(points), 2))
    seen2 = points @ rel_R.T + rel_t
    n2 = seen2[:, :2] / seen2[:, 2:] + rng.normal(0.0, 0.5 / 1145, (len(points), 2))
    person = np.r_[np.zeros(len(flat)), np.ones(len(moving))].astype(int)
    with pytest.raises(StereoError, match="no parallax"):
        check_parallax(n1, n2, essential, 1145.0)                    # all as one: the still one outnumbers
    check_parallax(n1, n2, essential, 1145.0, person)
    with pytest.raises(StereoError, match="no parallax: one homography maps"):
        check_parallax(n1, n1 + 0.02, essential, 1145.0, person)


def test_views_shifted_in_time_are_refused(dance):
    """The main person's keypoints fit one camera geometry best as given; with view 2 a few frames late a shift
    fits better (the bundled pair with camera 4 reversed or shifted: once refused only because camera 1's
    still figure matched by chance). A still main person cannot tell: not checked."""
    cam1, cam2, (x1, c1, x2, c2), _, _ = _pair(dance[:120], "side", noise_px=1.0)

    def person(x2_, c2_, still=False):
        return Selection(x1, c1, x2_, c2_, np.ones(len(x1), bool), np.zeros(len(x1)), still=still)

    check_synchronised(person(x2, c2), cam1, cam2, StereoConfig())
    late = np.roll(x2, 8, axis=0), np.roll(c2, 8, axis=0)
    with pytest.raises(StereoError, match="do not look synchronised: .* better with view 2 8 frames later"):
        check_synchronised(person(*late), cam1, cam2, StereoConfig())
    check_synchronised(person(*late, still=True), cam1, cam2, StereoConfig())


def test_cameras_at_one_place_are_refused(dance):
    """Camera 2 where camera 1 is, turned 10°: a homography maps the views, depth is undetermined."""
    cam1, _ = eval_stereo.pair_cameras("side", dance.mean(axis=(0, 1)))
    turn = cv2.Rodrigues(np.array([0.0, np.radians(10.0), 0.0]))[0]
    cam2 = CameraModel(cam1.K, cam1.dist, turn @ cam1.R, turn @ cam1.t, cam1.size)
    rng = np.random.default_rng(0)
    (x1, c1), (x2, c2) = (eval_stereo.render(dance, c, rng, 1.0, 0.0) for c in (cam1, cam2))
    with pytest.raises(StereoError, match="no parallax"):
        reconstruct(x1, c1, x2, c2, cam1, cam2, StereoConfig())
