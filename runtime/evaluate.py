"""`mocapdb eval`: held-out motion rendered to 2D, reconstructed, compared with the truth.

Held-out BVH clips (``data_specs/evaluation_split.md``; the database must be built without them)
are retargeted like database clips, turned by yaws off the database's grid, seen by a pinhole
camera at several heights, perturbed by detector-like noise, and run through the engine one
(yaw, clip) sequence at a time. Report (JSON):

* MPJPE (cm): pelvis-aligned, in the camera-aligned frame, so a wrong yaw counts;
* PA-MPJPE (cm) after a similarity alignment; yaw error (degrees) of the facing direction;
* acceleration error (mm/frame²): jitter against the truth;
* clustered-vs-exact search: recall@1 (the exact nearest projection is among the clustered
  candidates) and the time of each, measured in separate passes over the same queries;
* engine throughput (person-frames/s, one thread, parsed keypoints to smoothed skeleton);
* the method's two-view test: one clip seen by two cameras 135° and 75° apart, reconstructed
  independently, compared in the root frame (root rotation and translation removed).
"""
from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mocapdb.builder import BuildConfig, process_clip
from mocapdb.database import MotionDatabase
from mocapdb.geometry import normalize_pose_2d, project_pinhole, yaw_matrix
from mocapdb.keypoints import KeypointFrame, Person
from mocapdb.metrics import acceleration_error, mpjpe, pa_mpjpe
from mocapdb.skeleton import KP, N_KEYPOINTS_2D, PELVIS, pose_from_rotations

from .engine import Engine, EngineConfig
from .search import search_clustered, search_exact

SWAP_PAIRS = [(2, 5), (3, 6), (4, 7), (8, 11), (9, 12), (10, 13)]  # right/left keypoint pairs
IMAGE_HEIGHT_PX = 1080


@dataclass(frozen=True)
class Scenario:
    """One rendering condition."""

    name: str
    camera_height_m: float = 1.5
    noise_px: float = 0.0       # Gaussian σ, pixels of a 1080-pixel-high image
    dropout: float = 0.0        # probability that a keypoint is missing
    swap: float = 0.0           # probability per frame that left and right are swapped


DEFAULT_SCENARIOS = (
    Scenario("clean, camera 1.5 m"),
    Scenario("sigma 5 px, camera 1.5 m", noise_px=5.0),
    Scenario("clean, camera 1.0 m", camera_height_m=1.0),
    Scenario("clean, camera 2.2 m", camera_height_m=2.2),
    Scenario("sigma 5 px + 10% dropout + 5% swaps", noise_px=5.0, dropout=0.1, swap=0.05),
)


@dataclass
class EvalConfig:
    yaws_deg: tuple[float, ...] = (6.0, 51.0, 99.0, 141.0, 186.0, 231.0, 279.0, 321.0)  # 3° or 6° off the 12° grid
    scenarios: tuple[Scenario, ...] = DEFAULT_SCENARIOS
    fps: float = 24.0
    camera_distance_m: float = 5.0   # from the clip's mean pelvis (horizontal)
    focal_px: float = 1000.0
    seed: int = 0
    engine: EngineConfig = field(default_factory=EngineConfig)


@dataclass
class Truth:
    """A held-out clip on the universal skeleton."""

    name: str
    quaternions: np.ndarray  # [F, R, 4]
    positions: np.ndarray    # [F, 15, 3] world, floor at 0


def load_heldout(paths: list[Path], fps: float) -> list[Truth]:
    """Retarget held-out BVH files exactly as the builder does."""
    config = BuildConfig(fps=fps)
    return [Truth(c.name, c.quaternions.astype(np.float64), c.positions.astype(np.float64))
            for c in (process_clip(p, p.parent, config) for p in paths)]


def view_of(truth: Truth, yaw_deg: float, height_m: float, distance_m: float) -> np.ndarray:
    """Truth in the camera-aligned frame ``[F, 15, 3]``: the clip turned by ``yaw_deg`` about its
    mean pelvis, the camera ``distance_m`` in front of it at ``height_m``, looking along −z."""
    centre = truth.positions[:, PELVIS].mean(axis=0) * [1, 0, 1]
    world = (truth.positions - centre) @ yaw_matrix(yaw_deg).T
    return np.stack([world[..., 0], world[..., 1] - height_m, distance_m - world[..., 2]], axis=-1)


def render(cam_points: np.ndarray, scenario: Scenario, focal_px: float, image_size: tuple[int, int],
           rng: np.random.Generator) -> list[KeypointFrame]:
    """Detector-like keypoint frames of camera-aligned points ``[F, 15, 3]``."""
    opencv = cam_points[:, :N_KEYPOINTS_2D] * [1.0, -1.0, 1.0]
    px = project_pinhole(opencv, focal_px, (image_size[0] / 2, image_size[1] / 2))
    px = px + rng.normal(scale=scenario.noise_px * image_size[1] / IMAGE_HEIGHT_PX, size=px.shape)
    conf = np.where(rng.random(px.shape[:2]) < scenario.dropout, 0.0, 0.9)
    swapped = rng.random(len(px)) < scenario.swap
    for r, l in SWAP_PAIRS:
        px[swapped, r], px[swapped, l] = px[swapped, l].copy(), px[swapped, r].copy()
    return [KeypointFrame(i, None, [Person(px[i], conf[i])]) for i in range(len(px))]


def facing_deg(points: np.ndarray) -> np.ndarray:
    """Heading angle in the horizontal (x, z) plane of the hips' normal ``[F]`` (degrees)."""
    across = points[:, KP["l_hip"]] - points[:, KP["r_hip"]]
    return np.degrees(np.arctan2(-across[:, 0], across[:, 2]))


def _angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def run_sequence(engine: Engine, frames: list[KeypointFrame]) -> tuple[np.ndarray, np.ndarray, float]:
    """Pelvis-aligned output joints ``[F, 15, 3]`` (NaN where no output), root-frame joints, seconds."""
    joints = np.full((len(frames), 15, 3), np.nan)
    local = np.full_like(joints, np.nan)
    t0 = time.perf_counter()
    for i, frame in enumerate(frames):
        for pose in engine.step(frame):
            joints[i] = pose.joints_m - pose.root_m
            local[i] = _root_frame(pose.quaternions)
    elapsed = time.perf_counter() - t0
    engine.finish()
    return joints, local, elapsed


def _root_frame(quats: np.ndarray) -> np.ndarray:
    """The pose with root rotation and translation removed (joints in the pelvis frame)."""
    q = quats.copy()
    q[0] = [1.0, 0.0, 0.0, 0.0]
    return pose_from_rotations(q[None], np.zeros((1, 3)))[0]


def _new_engine(db: MotionDatabase, config: EvalConfig, image_size: tuple[int, int]) -> Engine:
    return Engine(db, replace(config.engine, fps=config.fps, focal_px=config.focal_px, image_size=image_size))


def evaluate_scenario(db: MotionDatabase, truths: list[Truth], scenario: Scenario, config: EvalConfig,
                      rng: np.random.Generator, bar: tqdm) -> tuple[dict, list[np.ndarray]]:
    """Accuracy of one scenario over every clip and yaw; also returns the normalised queries."""
    image_size = (1920, 1080)
    errs, pa, yaw_err, acc, seconds, n = [], [], [], [], 0.0, 0
    queries = []
    for truth in truths:
        for yaw in config.yaws_deg:
            cam = view_of(truth, yaw, scenario.camera_height_m, config.camera_distance_m)
            frames = render(cam, scenario, config.focal_px, image_size, rng)
            engine = _new_engine(db, config, image_size)
            joints, _, elapsed = run_sequence(engine, frames)
            seconds, n = seconds + elapsed, n + len(frames)
            gt = cam - cam[:, PELVIS:PELVIS + 1]
            ok = ~np.isnan(joints[:, 0, 0])
            errs.append(mpjpe(joints[ok], gt[ok]))
            pa.append(pa_mpjpe(joints[ok], gt[ok]))
            yaw_err.append(_angle_diff(facing_deg(joints[ok]), facing_deg(gt[ok])))
            run = np.flatnonzero(ok)
            if len(run) > 2 and np.all(np.diff(run) == 1):
                acc.append(acceleration_error(joints[ok], gt[ok]))
            queries.extend(f.people[0] for f in frames[::4])
            bar.update(len(frames))
    cat = np.concatenate
    return {
        "scenario": asdict(scenario),
        "person_frames": n,
        "frames_with_output": int(sum(len(e) for e in errs)),
        "mpjpe_cm": round(100 * float(cat(errs).mean()), 2),
        "pa_mpjpe_cm": round(100 * float(cat(pa).mean()), 2),
        "yaw_error_deg": {"mean": round(float(cat(yaw_err).mean()), 1),
                          "median": round(float(np.median(cat(yaw_err))), 1)},
        "accel_error_mm_per_frame2": round(1000 * float(cat(acc).mean()), 2) if acc else None,
        "engine_person_frames_per_s": round(n / seconds, 1),
    }, queries


def search_benchmark(engine: Engine, people: list[Person], threshold: float) -> dict:
    """Recall@1 of the clustered search against exact search, and the time of each."""
    cfg = engine.config
    prepared = []
    for person in people:
        vis = person.confidence >= threshold
        query, _, scale = normalize_pose_2d(person.points_px, vis)
        if scale > 0:
            prepared.append((query, vis))
    search_clustered(engine.index, *prepared[0])
    search_exact(engine.index, *prepared[0])
    t0 = time.perf_counter()
    clustered = [search_clustered(engine.index, q, v, cfg.n_clusters, cfg.per_cluster)[0] for q, v in prepared]
    t1 = time.perf_counter()
    exact = [search_exact(engine.index, q, v, 1)[0][0] for q, v in prepared]
    t2 = time.perf_counter()
    recall = float(np.mean([e in c for c, e in zip(clustered, exact)]))
    return {"queries": len(prepared), "recall_at_1": round(recall, 4),
            "clustered_us": round(1e6 * (t1 - t0) / len(prepared), 1),
            "exact_us": round(1e6 * (t2 - t1) / len(prepared), 1),
            "speedup": round((t2 - t1) / (t1 - t0), 1)}


def two_view(db: MotionDatabase, truths: list[Truth], config: EvalConfig, separation_deg: float) -> dict:
    """Mean distance (cm) between independent reconstructions from two cameras ``separation_deg`` apart."""
    image_size = (1920, 1080)
    rng = np.random.default_rng(config.seed + 1)
    scenario = Scenario("two-view")
    dists = []
    for truth in truths:
        for yaw in config.yaws_deg[::2]:
            views = []
            for turn in (yaw, yaw + separation_deg):
                cam = view_of(truth, turn, scenario.camera_height_m, config.camera_distance_m)
                frames = render(cam, scenario, config.focal_px, image_size, rng)
                views.append(run_sequence(_new_engine(db, config, image_size), frames)[1])
            ok = ~np.isnan(views[0][:, 0, 0]) & ~np.isnan(views[1][:, 0, 0])
            dists.append(mpjpe(views[0][ok], views[1][ok]))
    return {"separation_deg": separation_deg, "mean_distance_cm": round(100 * float(np.concatenate(dists).mean()), 2)}


def evaluate(db: MotionDatabase, heldout: list[Path], config: EvalConfig) -> dict:
    """The full report (see the module docstring)."""
    truths = load_heldout(heldout, config.fps)
    rng = np.random.default_rng(config.seed)
    total = sum(len(t.positions) for t in truths) * len(config.yaws_deg) * len(config.scenarios)
    bar = tqdm(total=total, desc="eval", unit="frame", disable=None, file=sys.stderr)
    scenarios, first_queries = [], None
    for scenario in config.scenarios:
        report, queries = evaluate_scenario(db, truths, scenario, config, rng, bar)
        scenarios.append(report)
        first_queries = first_queries or queries
    bar.close()
    engine = _new_engine(db, config, (1920, 1080))
    return {
        "database": {"projections": db.n_projections, "frames": db.n_frames, "clusters": db.n_clusters},
        "heldout_clips": [t.name for t in truths],
        "engine": {"search": config.engine.search, "n_clusters": config.engine.n_clusters,
                   "per_cluster": config.engine.per_cluster, "window_weights": config.engine.window_weights,
                   "weight_2d": config.engine.weight_2d, "smoothing": config.engine.smoothing},
        "scenarios": scenarios,
        "search": search_benchmark(engine, first_queries, config.engine.confidence_threshold),
        "two_view": [two_view(db, truths, config, 135.0), two_view(db, truths, config, 75.0)],
    }
