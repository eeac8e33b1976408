"""Pose distance, classical and landmark MDS, k-means and representatives against references."""
import numba
import numpy as np
import pytest
from scipy.spatial import procrustes
from scipy.spatial.distance import cdist, pdist
from sklearn.cluster import KMeans
from sklearn.datasets import make_blobs
from sklearn.metrics import adjusted_rand_score

import mocapdb.builder.kmeans as clustering
import mocapdb.builder.landmark_mds as mds
from mocapdb.builder.kmeans import kmeans, mean_member_distance, representatives
from mocapdb.builder.landmark_mds import classical_mds, landmark_mds
from mocapdb.builder.pose_distance import pose_distances

# Articulated test skeleton in OpenPose order (neck is the root): parent, bone length, rest angle.
PARENTS = (1, -1, 1, 2, 3, 1, 5, 6, 1, 8, 9, 1, 11, 12)
BONES = np.array([0.25, 0.0, 0.2, 0.3, 0.25, 0.2, 0.3, 0.25, 0.5, 0.45, 0.45, 0.5, 0.45, 0.45])
REST_DEG = np.array([90, 0, 180, 250, 260, 0, -70, -80, -100, -90, -90, -80, -90, -90])


def articulated_poses(n: int, rng: np.random.Generator) -> np.ndarray:
    """Real-like poses ``[n, 14, 2]``: joint angles driven by 4 correlated motion factors plus
    noise, chained down the skeleton, mid-hip at the origin, unit bounding-box height."""
    loadings = rng.normal(size=(14, 4))
    rel = (np.radians(REST_DEG) + (rng.normal(size=(n, 4)) * [0.6, 0.4, 0.3, 0.2]) @ loadings.T
           + rng.normal(scale=0.08, size=(n, 14)))
    angles, poses = np.zeros((n, 14)), np.zeros((n, 14, 2))
    for j, parent in enumerate(PARENTS):
        if parent >= 0:
            angles[:, j] = rel[:, j] + (angles[:, parent] if parent != 1 else 0.0)
            direction = np.stack([np.cos(angles[:, j]), np.sin(angles[:, j])], axis=-1)
            poses[:, j] = poses[:, parent] + BONES[j] * direction
    poses -= 0.5 * (poses[:, 8] + poses[:, 11])[:, None]
    return poses / np.ptp(poses[..., 1], axis=1)[:, None, None]


def latent_poses(n: int, rng: np.random.Generator, latent_dims: int = 6) -> np.ndarray:
    """Poses ``[n, 14, 2]`` bent smoothly (tanh) by a low-dimensional Gaussian latent."""
    base = rng.normal(size=(14, 2)) * 0.3
    modes = rng.normal(size=(latent_dims, 14, 2)) * 0.1
    return base + np.einsum("nq,qjc->njc", np.tanh(rng.normal(size=(n, latent_dims))), modes)


def test_pose_distances_match_per_joint_cdist():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(31, 14, 2)), rng.normal(size=(17, 14, 2))
    expected = sum(cdist(a[:, k], b[:, k]) for k in range(14))
    got = pose_distances(a, b)
    assert got.shape == (31, 17) and got.dtype == np.float64
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    a32, b32 = a.astype(np.float32), b.astype(np.float32)
    np.testing.assert_allclose(pose_distances(a32, b32), expected, rtol=1e-5)
    np.testing.assert_allclose(pose_distances(a32, b), expected, rtol=1e-6)
    three = sum(cdist(a[:, k], b[:, k]) for k in range(3))
    np.testing.assert_allclose(pose_distances(a[:, :3], b[:, :3]), three, atol=1e-12)
    with pytest.raises(ValueError):
        pose_distances(a, b[:, :3])


@pytest.mark.parametrize("dims", [2, 3])
def test_classical_mds_recovers_euclidean_configuration(dims):
    rng = np.random.default_rng(dims)
    points = rng.normal(size=(60, dims)) * np.arange(dims, 0, -1)
    coords = classical_mds(cdist(points, points), dims)
    assert coords.shape == (60, dims)
    np.testing.assert_allclose(pdist(coords), pdist(points), rtol=0, atol=1e-8)
    np.testing.assert_allclose(coords.mean(axis=0), 0.0, atol=1e-10)
    largest = coords[np.argmax(np.abs(coords), axis=0), np.arange(dims)]
    assert np.all(largest > 0)  # deterministic axis signs


@pytest.mark.parametrize("make_poses, bound", [(latent_poses, 2e-3), (articulated_poses, 5e-3)])
def test_landmark_mds_close_to_exact_classical_mds(make_poses, bound):
    poses = make_poses(1500, np.random.default_rng(1)).astype(np.float32)
    exact = classical_mds(pose_distances(poses, poses), 5)
    approx = landmark_mds(poses, dims=5, n_landmarks=300, seed=0)
    assert approx.shape == (1500, 5) and approx.dtype == np.float32
    assert procrustes(exact, approx)[2] < bound


def test_landmark_mds_chunks_progress_and_determinism(monkeypatch):
    poses = articulated_poses(2000, np.random.default_rng(2)).astype(np.float32)
    whole = landmark_mds(poses, n_landmarks=200, seed=3)
    monkeypatch.setattr(mds, "TRIANGULATE_CHUNK", 300)
    done = []
    chunked = landmark_mds(poses, n_landmarks=200, seed=3, progress=done.append)
    assert done == [300] * 6 + [200]
    np.testing.assert_array_equal(chunked, whole)
    np.testing.assert_array_equal(chunked, landmark_mds(poses, n_landmarks=200, seed=3, progress=done.append))
    assert not np.array_equal(whole, landmark_mds(poses, n_landmarks=200, seed=4))


def test_landmark_mds_of_a_small_set_is_classical_mds():
    poses = latent_poses(150, np.random.default_rng(4))
    done = []
    got = landmark_mds(poses, dims=4, n_landmarks=200, progress=done.append)
    np.testing.assert_allclose(got, classical_mds(pose_distances(poses, poses), 4), atol=1e-5)
    assert done == [150]


def test_kmeans_finds_separated_blobs_like_sklearn():
    points, _ = make_blobs(n_samples=4000, centers=12, n_features=5, cluster_std=0.3,
                           center_box=(-40, 40), random_state=0)
    centroids, labels = kmeans(points.astype(np.float32), 12, seed=0)
    reference = KMeans(12, n_init=10, random_state=0).fit(points)
    assert centroids.shape == (12, 5) and centroids.dtype == np.float64 and labels.dtype == np.int32
    assert adjusted_rand_score(reference.labels_, labels) == 1.0


def test_kmeans_inertia_within_one_percent_of_sklearn():
    points = np.random.default_rng(5).random((20000, 5))
    centroids, labels = kmeans(points, 60, seed=1, max_iter=300)
    inertia = float(((points - centroids[labels]) ** 2).sum())
    reference = KMeans(60, n_init=1, random_state=1, max_iter=300).fit(points).inertia_
    assert abs(inertia - reference) <= 0.01 * reference
    np.testing.assert_array_equal(labels, np.argmin(cdist(points, centroids), axis=1))


def test_kmeans_is_deterministic_whatever_the_thread_count():
    points = np.random.default_rng(6).normal(size=(30000, 5)).astype(np.float32)
    shifts = []
    first = kmeans(points, 40, seed=2, progress=lambda it, shift: shifts.append((it, shift)))
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        second = kmeans(points, 40, seed=2)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(first[1], second[1])
    np.testing.assert_array_equal(first[0], second[0])
    assert [it for it, _ in shifts] == list(range(len(shifts))) and shifts[-1][1] >= 0.0


def test_empty_cluster_takes_the_farthest_point():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0], [0.5, 0.0]])
    labels = np.zeros(4, dtype=np.int32)
    sums, counts = np.array([[11.5, 0.0], [0.0, 0.0]]), np.array([4, 0])
    new = clustering._update_centroids(points, sums, counts, labels, np.array([[2.0, 0.0], [5.0, 5.0]]))
    np.testing.assert_allclose(new, [[0.5, 0.0], [10.0, 0.0]])


def test_representatives_and_mean_member_distance_match_brute_force():
    rng = np.random.default_rng(7)
    points = rng.normal(size=(5000, 5)).astype(np.float32)
    centroids = rng.normal(size=(30, 5))
    labels = rng.integers(0, 29, size=5000).astype(np.int32)  # cluster 29 stays empty
    reps = representatives(points, labels, centroids)
    dist = np.linalg.norm(points.astype(np.float64) - centroids[labels], axis=1)
    expected = [np.flatnonzero(labels == c)[np.argmin(dist[labels == c])] for c in range(29)]
    assert reps.dtype == np.int64
    np.testing.assert_array_equal(reps, expected + [-1])
    assert mean_member_distance(points, labels, centroids) == pytest.approx(dist.mean(), rel=1e-12)
