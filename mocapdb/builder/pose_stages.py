"""The build's stages over the poses, each chunked (:func:`~mocapdb.builder.run.run_chunks`):
``project`` (every frame from every yaw, normalised 2D), ``embed`` (landmark MDS), ``cluster``
(streamed k-means, then each cluster's representative) and ``assign`` (every pose to its nearest
representative under Eq. 1). The kernels are in :mod:`mocapdb.builder.landmark_mds`,
:mod:`mocapdb.builder.kmeans` and :mod:`mocapdb.builder.pose_distance`.
"""
from __future__ import annotations

import numpy as np

from mocapdb.builder.config import BuildConfig
from mocapdb.builder.kmeans import (
    KMEANS_BLOCK_ROWS,
    KMeansBounds,
    KMeansState,
    kmeans_finish,
    kmeans_iterate,
    kmeans_seed,
)
from mocapdb.builder.landmark_mds import fit_landmarks, landmark_pool
from mocapdb.builder.pose_distance import nearest_poses
from mocapdb.builder.run import MIN_CHUNK_ROWS, BuildRun, run_chunks, stage_output
from mocapdb.builder.work import WorkArray
from mocapdb.core.geometry import normalize_pose_2d, project_views
from mocapdb.core.progress import progress
from mocapdb.core.skeleton import N_KEYPOINTS_2D, PELVIS

KMEANS_MAX_ITER = 50
# Memory per chunk row of each stage, bytes (measured, with margin; data_specs/build.md "Memory"):
PROJECT_BYTES_PER_PROJECTION = 2048  # float64 views, pixels and normalisation of one projection
EMBED_BYTES_PER_POSE = 256           # the pose read, its coordinates written
KMEANS_BYTES_PER_POINT = 64          # the point, its label and bounds
ASSIGN_BYTES_PER_POSE = 256          # the pose read, its label written


def project_frames(positions_m: np.ndarray, config: BuildConfig) -> np.ndarray:
    """Normalised 2D poses ``[F·V, 14, 2]`` float32 (frame-major) of frames ``[F, 15, 3]`` from every yaw."""
    positions_m = positions_m.astype(np.float64)
    pixels = project_views(positions_m, positions_m[:, PELVIS], config.yaws_deg, 0.0, config.camera)
    normalised, _, _ = normalize_pose_2d(pixels[..., :N_KEYPOINTS_2D, :])
    return normalised.reshape(-1, N_KEYPOINTS_2D, 2).astype(np.float32)


def _project_task(job: tuple) -> None:
    positions, keypoints, config, start, stop, durable = job
    n_yaws = len(config.yaws_deg)
    keypoints[start * n_yaws:stop * n_yaws] = project_frames(positions[start:stop], config)
    if durable:  # written on another machine: on the shared disk before the task returns
        keypoints.sync()


def project_stage(run: BuildRun) -> list[WorkArray]:
    positions = run.work.array("positions")
    keypoints = stage_output(run, "project", "keypoints_2d", np.float32, (N_KEYPOINTS_2D, 2), run.n_projections)
    frames = run.plan.rows(PROJECT_BYTES_PER_PROJECTION * run.n_yaws)
    config = run.chunks.share(run.config)
    run_chunks(run, "project", run.n_frames, frames, _project_task,
               lambda start, stop: (positions, keypoints, config, start, stop, run.chunks.remote),
               [keypoints], "project", "frame")
    return [keypoints]


def _embed_task(job: tuple) -> None:
    keypoints, embedding, landmarks, start, stop, durable = job
    landmarks.place(keypoints[start:stop], embedding[start:stop])
    if durable:  # written on another machine: on the shared disk before the task returns
        embedding.sync()


def embed_stage(run: BuildRun) -> list[WorkArray]:
    """Landmark MDS: landmarks from a seeded sample (fitted again, identically, on a resume), then
    every pose placed chunk by chunk."""
    keypoints, config = run.work.array("keypoints_2d"), run.config
    rng = np.random.default_rng(config.seed)
    pool = landmark_pool(len(keypoints), config.landmarks, rng)
    landmarks = run.chunks.share(fit_landmarks(keypoints.take(pool), config.dims, config.landmarks, rng))
    embedding = stage_output(run, "embed", "embedding", np.float32, (config.dims,), len(keypoints))
    rows = run.plan.rows(EMBED_BYTES_PER_POSE, MIN_CHUNK_ROWS)
    run_chunks(run, "embed", len(keypoints), rows, _embed_task,
               lambda start, stop: (keypoints, embedding, landmarks, start, stop, run.chunks.remote),
               [embedding], "embed (MDS)", "pose", MIN_CHUNK_ROWS)
    return [embedding]


def _kmeans_bounds(run: BuildRun, n: int, fresh: bool) -> KMeansBounds[WorkArray]:
    """The labels and bounds of every point: new arrays, or an interrupted run's (any content will do)."""
    names = [(f"kmeans_{name}", dtype) for name, dtype in KMeansBounds.FIELDS]
    if fresh or not all((run.work.path / f"{name}.npy").is_file() for name, _ in names):
        return KMeansBounds(*(run.work.new_array(name, dtype, (), n) for name, dtype in names))
    return KMeansBounds(*(run.work.array(name) for name, _ in names))


def cluster_stage(run: BuildRun) -> list[WorkArray]:
    """Streamed k-means of the embedding (saved after every iteration), then each cluster's
    representative; the bounds' scratch arrays are deleted at the end."""
    embedding, config, record = run.work.array("embedding"), run.config, run.work.record("cluster")
    resumed = "iteration" in record
    if resumed:
        state = KMeansState(run.work.load("centroids"), record["tol_abs"], record["iteration"], record["shift"])
    else:
        state = kmeans_seed(embedding, config.clusters, config.seed)
    bounds = _kmeans_bounds(run, len(embedding), fresh=not resumed)
    partial_bytes = 8 * config.clusters * (config.dims + 1) / KMEANS_BLOCK_ROWS  # block sums, per point
    rows = run.plan.rows(KMEANS_BYTES_PER_POINT + partial_bytes, KMEANS_BLOCK_ROWS)
    bar = progress(total=KMEANS_MAX_ITER, initial=state.iteration, desc="k-means", unit="iter")

    def save(state: KMeansState) -> None:
        run.work.save("centroids", state.centroids)
        record.update(iteration=state.iteration, shift=state.shift, tol_abs=state.tol_abs)
        run.work.commit()
        run.work.wait()  # the state of this iteration is on disk before the next one's centroids
        bar.update()

    kmeans_iterate(embedding, state, bounds, KMEANS_MAX_ITER, rows, save, run.chunks)
    bar.close()
    run.work.save("representatives", kmeans_finish(embedding, state, bounds, rows, run.chunks))
    run.note_disk()
    for array in (bounds.labels, bounds.upper, bounds.lower):
        array.path.unlink()
    return []


def assign_to_representatives(poses: np.ndarray, reps: np.ndarray, rep_poses: np.ndarray,
                              first_row: int = 0) -> np.ndarray:
    """Cluster (int32) of each of ``poses [n, 14, 2]`` (rows ``first_row…`` of the projections) = its
    nearest representative under Eq. 1; ``rep_poses`` are the poses of the non-empty clusters'
    representatives ``reps[reps >= 0]``. A representative always belongs to its own cluster (ties).

    k-means works in the 5-D MDS space, which keeps Eq. 1 neighbourhoods only roughly: on the
    CMU set, a projection's own k-means cluster was among the 5 clusters with the nearest
    representatives for only ~70 % of queries. Re-assigning members to their nearest
    representative makes the runtime's "nearest representatives, then their members" search
    find the exact nearest projection (recall ~1.0, see ``mocapdb eval``). Cost O(n·K).
    """
    valid = np.flatnonzero(reps >= 0)
    labels = valid[nearest_poses(poses, rep_poses)].astype(np.int32)
    own = (reps[valid] >= first_row) & (reps[valid] < first_row + len(poses))
    labels[reps[valid][own] - first_row] = valid[own]
    return labels


def _assign_task(job: tuple) -> None:
    keypoints, cluster, reps, rep_poses, start, stop, durable = job
    cluster[start:stop] = assign_to_representatives(keypoints[start:stop], reps, rep_poses, start)
    if durable:  # written on another machine: on the shared disk before the task returns
        cluster.sync()


def assign_stage(run: BuildRun) -> list[WorkArray]:
    keypoints, reps = run.work.array("keypoints_2d"), run.work.load("representatives")
    rep_poses = run.chunks.share(keypoints.take(reps[reps >= 0]))
    cluster = stage_output(run, "assign", "cluster", np.int32, (), len(keypoints))
    rows = run.plan.rows(ASSIGN_BYTES_PER_POSE, MIN_CHUNK_ROWS)
    run_chunks(run, "assign", len(keypoints), rows, _assign_task,
               lambda start, stop: (keypoints, cluster, reps, rep_poses, start, stop, run.chunks.remote),
               [cluster], "assign", "pose", MIN_CHUNK_ROWS)
    return [cluster]
