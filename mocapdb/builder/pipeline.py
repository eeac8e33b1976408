"""`mocapdb build`: BVH clips → universal skeleton → yaw projections → MDS → k-means → database.

Stage costs (N projections, F frames, V yaws, L landmarks, K clusters, d dims, I iterations):
reading and retargeting O(F·source joints); projection O(F·V); landmark MDS O(N·L·14);
k-means O(I·N·K·d); writing O(N). ``tools/bench_build.py`` prints how each grows with N.
"""
from __future__ import annotations

import fnmatch
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from mocapdb import __version__
from mocapdb.builder.embedding import kmeans, landmark_mds, pose_distances, representatives
from mocapdb.core import domains as D
from mocapdb.core.cameras import DatabaseCamera
from mocapdb.core.clips import Clip, ClipOptions, clips_from_bvh
from mocapdb.core.errors import MocapdbError
from mocapdb.core.formats.bvh import BvhError
from mocapdb.core.formats.database import MotionDatabase, check_output_path, recover_interrupted, write_database
from mocapdb.core.geometry import normalize_pose_2d, project_views
from mocapdb.core.joint_map import UNITS, UP_AXES, JointMapError, load_joint_map_file
from mocapdb.core.progress import progress
from mocapdb.core.skeleton import (
    BONE_LENGTHS_M,
    KEYPOINTS,
    N_KEYPOINTS_2D,
    PELVIS,
    RIG_JOINTS,
)

PROJECTION_CHUNK_FRAMES = 2000
MAX_YAWS = 32767  # projections.yaw is int16


class BuildError(MocapdbError, RuntimeError):
    """A build that cannot go on; the message says why, ``skipped`` names the files skipped before
    it stopped, each with its reason (``(path, reason)`` pairs)."""

    def __init__(self, message: str, skipped: list[tuple[str, str]] = ()):
        super().__init__(message)
        self.skipped = list(skipped)


@dataclass
class BuildConfig:
    """Parameters of a database build (defaults are the method's)."""

    fps: float = 24.0
    yaw_step_deg: float = 12.0
    camera: DatabaseCamera = field(default_factory=DatabaseCamera)
    clusters: int = 500
    dims: int = 5
    seed: int = 0
    landmarks: int = 2000
    workers: int = 1
    strict: bool = False
    joint_map: Path | None = None
    unit: str | None = None
    up_axis: str | None = None
    credit: str | None = None
    mirror: bool = True  # also store every clip's left-right mirror image

    def clip_options(self) -> ClipOptions:
        """The options that turn a BVH file into clips (:mod:`mocapdb.core.clips`)."""
        return ClipOptions(self.fps, self.joint_map, self.unit, self.up_axis, self.credit, self.mirror)

    @property
    def yaws_deg(self) -> np.ndarray:
        step = D.YAW_STEP_DEG.check(self.yaw_step_deg, "--yaw-step")
        ratio = 360.0 / step
        n = round(ratio) if ratio < MAX_YAWS + 1 else 0
        if n < 1 or abs(n * step - 360.0) > 1e-6:
            raise BuildError(f"--yaw-step {step} does not divide 360 degrees into 1 to {MAX_YAWS} yaws")
        return np.arange(n) * step

    def check(self) -> None:
        """Raise DomainError or BuildError naming the first option (by its ``mocapdb build`` flag)
        that cannot work."""
        for flag, domain, value in [
                ("--fps", D.FPS_HZ, self.fps), ("--camera-height", D.CAMERA_HEIGHT_M, self.camera.height_m),
                ("--camera-distance", D.CAMERA_DISTANCE_M, self.camera.distance_m),
                ("--focal", D.FOCAL_PX, self.camera.focal_px), ("--clusters", D.CLUSTERS, self.clusters),
                ("--dims", D.DIMS, self.dims), ("--landmarks", D.LANDMARKS, self.landmarks),
                ("--workers", D.WORKERS, self.workers), ("--seed", D.SEED, self.seed),
                ("camera width_px", D.IMAGE_SIDE_PX, self.camera.width_px),
                ("camera height_px", D.IMAGE_SIDE_PX, self.camera.height_px)]:
            domain.check(value, flag)
        self.yaws_deg
        if self.landmarks <= self.dims:
            raise BuildError(f"--landmarks {self.landmarks} is too few for --dims {self.dims}: "
                             "landmark MDS needs at least dims + 1 landmarks")
        if self.unit not in (None, *UNITS) or self.up_axis not in (None, *UP_AXES):
            raise BuildError(f"unknown --unit {self.unit!r} or --up-axis {self.up_axis!r}: "
                             f"units {', '.join(UNITS)}; up axes {', '.join(UP_AXES)}")


@dataclass
class BuildSummary:
    files: int = 0
    clips: int = 0
    mirrored: int = 0
    frames: int = 0
    projections: int = 0
    clusters: int = 0
    skipped: list[tuple[str, str]] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    bytes_on_disk: int = 0
    warnings: list[str] = field(default_factory=list)

    def report(self) -> str:
        lines = [f"files {self.files}, clips {self.clips} (files split at jumps in the data; {self.mirrored} of them "
                 f"mirrored copies), frames {self.frames}, projections {self.projections}, "
                 f"clusters {self.clusters}, size on disk {self.bytes_on_disk / 1e6:.1f} MB"]
        lines += [f"  {stage:<12} {sec:8.2f} s" for stage, sec in self.seconds.items()]
        lines.append(f"  {'total':<12} {sum(self.seconds.values()):8.2f} s")
        lines += [f"skipped {path}: {why}" for path, why in self.skipped]
        lines += [f"warning: {text}" for text in self.warnings]
        return "\n".join(lines)


def find_sources(sources: list[str], exclude: list[str] = ()) -> list[tuple[Path, Path]]:
    """BVH files named or found (recursively) under ``sources``, minus ``exclude`` glob patterns.

    Returns sorted ``(file, source_root)`` pairs; a pattern matches the file name or its path.
    """
    found: dict[Path, Path] = {}
    for src in sources:
        root = Path(src)
        if root.is_dir():
            files = [p for p in root.rglob("*") if p.suffix.lower() == ".bvh" and p.is_file()]
        elif root.is_file():
            files, root = [root], root.parent
        else:
            raise BuildError(f"source {src!r} is neither a BVH file nor a folder")
        for f in files:
            if not any(fnmatch.fnmatch(f.name, pat) or fnmatch.fnmatch(str(f), pat) for pat in exclude):
                found.setdefault(f, root)
    return sorted(found.items())


def _process_one(args: tuple[Path, Path, BuildConfig]) -> list[Clip] | tuple[str, str]:
    """One file's clips, or ``(file, reason)`` when anything goes wrong: one bad file never ends a build."""
    path, root, config = args
    try:
        return clips_from_bvh(path, root, config.clip_options())
    except (BvhError, JointMapError) as exc:
        return (str(path), str(exc))
    except Exception as exc:  # noqa: BLE001 - any failure on one file is that file's skip reason
        return (str(path), f"unexpected {type(exc).__name__}: {exc}")


def load_clips(files: list[tuple[Path, Path]], config: BuildConfig,
               summary: BuildSummary) -> list[Clip]:
    """Process every file (in ``config.workers`` processes); files that fail go to ``summary.skipped``
    with the reason (``config.strict``: :class:`BuildError` naming them all; no clip at all:
    :class:`BuildError` whose ``skipped`` lists them)."""
    jobs = [(path, root, config) for path, root in files]
    bar = progress(total=len(jobs), desc="read+retarget", unit="clip")
    results = []
    if config.workers > 1 and len(jobs) > 1:
        with ProcessPoolExecutor(max_workers=config.workers) as pool:
            for res in pool.map(_process_one, jobs):
                results.append(res)
                bar.update()
    else:
        for job in jobs:
            results.append(_process_one(job))
            bar.update()
    bar.close()
    clips = [clip for r in results if isinstance(r, list) for clip in r]
    summary.skipped = [r for r in results if isinstance(r, tuple)]
    if summary.skipped and config.strict:
        raise BuildError("--strict: " + "; ".join(f"{p}: {why}" for p, why in summary.skipped))
    if not clips:
        why = f": all {len(summary.skipped)} BVH file(s) were skipped" if summary.skipped else ""
        raise BuildError(f"no readable BVH clip among the sources{why}", summary.skipped)
    return clips


def project_all(positions: np.ndarray, config: BuildConfig) -> np.ndarray:
    """Normalised 2D poses ``[F·V, 14, 2]`` (frame-major) of every frame from every yaw."""
    yaws = config.yaws_deg
    out = np.empty((len(positions) * len(yaws), N_KEYPOINTS_2D, 2), dtype=np.float32)
    bar = progress(total=len(positions), desc="project", unit="frame")
    for start in range(0, len(positions), PROJECTION_CHUNK_FRAMES):
        chunk = positions[start:start + PROJECTION_CHUNK_FRAMES].astype(np.float64)
        pixels = project_views(chunk, chunk[:, PELVIS], yaws, 0.0, config.camera)
        normalised, _, _ = normalize_pose_2d(pixels[..., :N_KEYPOINTS_2D, :])
        out[start * len(yaws):(start + len(chunk)) * len(yaws)] = normalised.reshape(-1, N_KEYPOINTS_2D, 2)
        bar.update(len(chunk))
    bar.close()
    return out


def _embed_and_cluster(keypoints_2d: np.ndarray, config: BuildConfig, summary: BuildSummary):
    t0 = time.perf_counter()
    bar = progress(total=len(keypoints_2d), desc="embed (MDS)", unit="pose")
    embedding = landmark_mds(keypoints_2d, dims=config.dims, n_landmarks=config.landmarks,
                             seed=config.seed, progress=bar.update)
    bar.close()
    t1 = time.perf_counter()
    bar = progress(total=None, desc="k-means", unit="iter")
    centroids, labels = kmeans(embedding, config.clusters, seed=config.seed, progress=lambda it, shift: bar.update())
    bar.close()
    reps = representatives(embedding, labels, centroids)
    labels = assign_to_representatives(keypoints_2d, reps)
    summary.seconds["embed"] = t1 - t0
    summary.seconds["cluster"] = time.perf_counter() - t1
    return embedding, centroids, labels, reps


ASSIGN_CHUNK = 20000


def assign_to_representatives(keypoints_2d: np.ndarray, reps: np.ndarray) -> np.ndarray:
    """Cluster of every projection = its nearest representative under Eq. 1 (int32 ``[P]``).

    k-means works in the 5-D MDS space, which keeps Eq. 1 neighbourhoods only roughly: on the
    CMU set, a projection's own k-means cluster was among the 5 clusters with the nearest
    representatives for only ~70 % of queries. Re-assigning members to their nearest
    representative makes the runtime's "nearest representatives, then their members" search
    find the exact nearest projection (recall ~1.0, see ``mocapdb eval``). Cost O(P·K).
    """
    valid = np.flatnonzero(reps >= 0)
    rep_poses = keypoints_2d[reps[valid]]
    labels = np.empty(len(keypoints_2d), dtype=np.int32)
    bar = progress(total=len(keypoints_2d), desc="assign", unit="pose")
    for start in range(0, len(keypoints_2d), ASSIGN_CHUNK):
        chunk = keypoints_2d[start:start + ASSIGN_CHUNK]
        labels[start:start + len(chunk)] = valid[pose_distances(chunk, rep_poses).argmin(axis=1)]
        bar.update(len(chunk))
    bar.close()
    labels[reps[valid]] = valid  # a representative always belongs to its own cluster (ties)
    return labels


def assemble(clips: list[Clip], keypoints_2d: np.ndarray, embedding: np.ndarray, centroids: np.ndarray,
             labels: np.ndarray, reps: np.ndarray, config: BuildConfig) -> MotionDatabase:
    """The database tables of a finished build."""
    n_frames = np.array([len(c.positions) for c in clips])
    n_yaws = len(config.yaws_deg)
    total = int(n_frames.sum())
    return MotionDatabase(
        meta=_meta(config),
        clip_name=[c.name for c in clips], clip_source=[c.source for c in clips],
        clip_source_fps=np.array([c.source_fps for c in clips]),
        clip_n_frames=n_frames.astype(np.int32),
        clip_first_frame=np.concatenate([[0], np.cumsum(n_frames)[:-1]]).astype(np.int64),
        clip_convention=[c.convention for c in clips], clip_credit=[c.credit for c in clips],
        clip_mirrored=np.array([c.mirrored for c in clips], dtype=bool),
        frame_clip=np.repeat(np.arange(len(clips), dtype=np.int32), n_frames),
        frame_index=np.concatenate([np.arange(n, dtype=np.int32) for n in n_frames]),
        quaternions=np.concatenate([c.quaternions for c in clips]),
        positions=np.concatenate([c.positions for c in clips]),
        proj_frame=np.repeat(np.arange(total, dtype=np.int64), n_yaws),
        proj_yaw=np.tile(np.arange(n_yaws, dtype=np.int16), total),
        keypoints_2d=keypoints_2d, embedding=embedding.astype(np.float32),
        cluster=labels.astype(np.int32), centroids=centroids.astype(np.float32),
        representative=reps.astype(np.int64),
        cluster_size=np.bincount(labels, minlength=len(centroids)).astype(np.int32),
    )


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


def _check_before_work(out: str | os.PathLike, config: BuildConfig, summary: BuildSummary) -> None:
    """Fail in milliseconds, before any file is read, on what would stop the build at the end; then
    clean up after interrupted earlier writes of ``out``."""
    config.check()
    if config.joint_map:
        load_joint_map_file(config.joint_map)
    check_output_path(out)
    summary.warnings += recover_interrupted(out)


def _fit_clusters(config: BuildConfig, n_projections: int, summary: BuildSummary) -> BuildConfig:
    """``config`` with at most one cluster per projection (a warning says when it had more)."""
    if config.clusters <= n_projections:
        return config
    summary.warnings.append(f"--clusters {config.clusters} is more than the {n_projections} projections: "
                            f"made {n_projections} clusters")
    return replace(config, clusters=n_projections)


def build(sources: list[str], out: str | os.PathLike, config: BuildConfig,
          exclude: list[str] = ()) -> BuildSummary:
    """Build a database at ``out`` from BVH files and folders; returns the summary."""
    summary = BuildSummary()
    t0 = time.perf_counter()
    _check_before_work(out, config, summary)
    files = find_sources(sources, exclude)
    if not files:
        raise BuildError(f"no .bvh file found in {', '.join(sources)}")
    clips = load_clips(files, config, summary)
    t1 = time.perf_counter()
    positions = np.concatenate([c.positions for c in clips])
    keypoints_2d = project_all(positions, config)
    summary.seconds.update({"read": t1 - t0, "project": time.perf_counter() - t1})
    config = _fit_clusters(config, len(keypoints_2d), summary)
    embedding, centroids, labels, reps = _embed_and_cluster(keypoints_2d, config, summary)
    t2 = time.perf_counter()
    db = assemble(clips, keypoints_2d, embedding, centroids, labels, reps, config)
    summary.bytes_on_disk = write_database(db, out)
    summary.seconds["write"] = time.perf_counter() - t2
    summary.files = len(files) - len(summary.skipped)
    summary.clips, summary.frames = db.n_clips, db.n_frames
    summary.mirrored = int(db.clip_mirrored.sum())
    summary.projections, summary.clusters = db.n_projections, db.n_clusters
    return summary
