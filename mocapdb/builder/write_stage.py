"""The build's last stage: the database written from the work folder table by table, row group by
row group (:class:`~mocapdb.core.formats.database_writer.DatabaseWriter`), with its metadata.
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import asdict
from datetime import datetime, timezone

import numpy as np

from mocapdb import __version__
from mocapdb.builder.config import BuildConfig
from mocapdb.builder.run import MIN_CHUNK_ROWS, BuildRun, row_ranges
from mocapdb.core.formats.database_writer import DatabaseWriter
from mocapdb.core.formats.search_index import ARRAYS as INDEX_ARRAYS
from mocapdb.core.progress import progress
from mocapdb.core.skeleton import BONE_LENGTHS_M, KEYPOINTS, RIG_JOINTS

# Memory per chunk row of each stage, bytes (measured, with margin; data_specs/build.md "Memory"):
WRITE_BYTES_PER_PROJECTION = 1024    # the row read, its Arrow and Parquet encodings
WRITE_BYTES_PER_FRAME = 2048


def _clip_table(clips: list[dict]) -> dict:
    n_frames = np.array([c["n_frames"] for c in clips], dtype=np.int64)
    return {
        "clip_name": [c["name"] for c in clips], "clip_source": [c["source"] for c in clips],
        "clip_source_fps": np.array([c["source_fps"] for c in clips], dtype=np.float64),
        "clip_n_frames": n_frames.astype(np.int32), "clip_first_frame": np.cumsum(n_frames) - n_frames,
        "clip_convention": [c["convention"] for c in clips], "clip_credit": [c["credit"] for c in clips],
        "clip_mirrored": np.array([c["mirrored"] for c in clips], dtype=bool),
    }


def _frame_rows(run: BuildRun, first_frame: np.ndarray) -> Iterator[dict]:
    positions, quaternions = run.work.array("positions"), run.work.array("quaternions")
    for start, stop in row_ranges(run.n_frames, run.plan.rows(WRITE_BYTES_PER_FRAME, MIN_CHUNK_ROWS)):
        frames = np.arange(start, stop)
        clip = np.searchsorted(first_frame, frames, side="right") - 1
        yield {"frame_clip": clip.astype(np.int32), "frame_index": (frames - first_frame[clip]).astype(np.int32),
               "quaternions": quaternions[start:stop], "positions": positions[start:stop]}


def _projection_rows(run: BuildRun, cluster_size: np.ndarray, bar) -> Iterator[dict]:
    """The projections table in chunks; counts each chunk's clusters into ``cluster_size``."""
    keypoints, embedding, cluster = (run.work.array(n) for n in ("keypoints_2d", "embedding", "cluster"))
    for start, stop in row_ranges(run.n_projections, run.plan.rows(WRITE_BYTES_PER_PROJECTION, MIN_CHUNK_ROWS)):
        rows = np.arange(start, stop)
        labels = cluster[start:stop]
        cluster_size += np.bincount(labels, minlength=len(cluster_size))
        yield {"proj_frame": rows // run.n_yaws, "proj_yaw": (rows % run.n_yaws).astype(np.int16),
               "keypoints_2d": keypoints[start:stop], "embedding": embedding[start:stop], "cluster": labels}
        bar.update(stop - start)


def write_stage(run: BuildRun, out: str | os.PathLike) -> int:
    """The database, table by table, row group by row group; returns its size in bytes."""
    clips = _clip_table(run.work.record("read")["clips"])
    reps, centroids = run.work.load("representatives"), run.work.load("centroids")
    cluster_size = np.zeros(len(reps), dtype=np.int64)
    bar = progress(total=run.n_projections, desc="write", unit="projection")
    with DatabaseWriter(out, _meta(run.config)) as writer:
        writer.write_table("clips", [clips])
        writer.write_table("frames", _frame_rows(run, clips["clip_first_frame"]))
        writer.write_table("projections", _projection_rows(run, cluster_size, bar))
        writer.write_table("clusters", [{"centroids": centroids.astype(np.float32), "representative": reps,
                                         "cluster_size": cluster_size.astype(np.int32)}])
        writer.add_search_index({name: run.work.path / f"index_{name}.npy" for name in INDEX_ARRAYS})
        size = writer.finish()
    bar.close()
    return size


def _meta(config: BuildConfig) -> dict:
    return {
        "fps": config.fps, "yaw_step_deg": config.yaw_step_deg,
        "yaws_deg": config.yaws_deg.tolist(), "camera": asdict(config.camera),
        "dims": config.dims, "n_clusters": config.clusters, "seed": config.seed,
        "landmarks": config.landmarks, "mirror": config.mirror, "builder_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "skeleton": {"keypoints": list(KEYPOINTS), "rig_joints": list(RIG_JOINTS),
                     "bone_lengths_m": BONE_LENGTHS_M},
    }
