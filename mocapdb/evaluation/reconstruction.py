"""`mocapdb eval`: the engine run on held-out frames (:mod:`mocapdb.evaluation.heldout`) and scored.

Each (yaw, clip) sequence runs on the same frames refined (the engine's default), as published
(``EngineConfig(refine=False)``) and as ``reconstruct`` runs it for the whole take (its fits kept, no
2D clean-up: :func:`~mocapdb.evaluation.engine_runs.track_files_take`), and, at each of
``EvalConfig.stream_lags``, as the default stream (:func:`~mocapdb.evaluation.engine_runs.stream_runs`:
the online take; the refined variant is the per-frame stream, ``--per-frame-stream``). Per scenario and variant
(JSON): MPJPE (cm, pelvis-aligned in the camera-aligned frame, so a wrong yaw or unseen camera pitch
counts), PA-MPJPE (cm), facing yaw error (degrees), acceleration error (mm/frame², jitter); the
database floor (cm,
:mod:`mocapdb.evaluation.floor`: per frame the best database pose under the best vertical turn, what no
retrieval can beat), ``engine_minus_floor`` and ``frames_below_floor`` (beating it needs leaving the
database: smoothing or 2D refinement); reprojection error (% of the truth's 2D box height) against the
clean projection of the truth and against the noisy input; root error (metres, % of the true depth).
Also clustered-vs-exact search (recall@1, timing), engine throughput, and the method's two-view test
(one clip seen by cameras 135° and 75° apart, root rotation and translation removed).
Leave-one-subject-out evaluation (databases built per fold): :mod:`mocapdb.evaluation.loso`.
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import normalize_pose_2d
from mocapdb.core.progress import progress
from mocapdb.core.skeleton import (
    KP,
    MEASURED_BONE_NAMES,
    N_KEYPOINTS_2D,
    N_POINTS,
    PELVIS,
    bone_lengths_m,
    stature_m,
)
from mocapdb.evaluation.engine_runs import EngineRun, run_sequence, stream_runs, track_files_take, world_landmarks_run
from mocapdb.evaluation.floor import FloorIndex, database_floor
from mocapdb.evaluation.heldout import (
    UNIVERSAL_HEIGHT_M,
    EvalConfig,
    Scenario,
    Truth,
    camera_distance,
    camera_to_world,
    camera_view,
    load_heldout,
    project,
    render,
    scenario_positions,
    view_of,
)
from mocapdb.evaluation.metrics import (
    acceleration_error,
    foot_height_error_m,
    foot_skating_mps,
    mpjpe,
    pa_mpjpe,
    planted_feet,
    speeds_mps,
)
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.search import search_clustered, search_exact

if TYPE_CHECKING:
    from tqdm import tqdm

LOG = logging.getLogger(__name__)

VARIANTS = (("published", False), ("refined", True))  # report name, EngineConfig.refine
TAKE_VARIANT = "whole take"  # a track-files run's tracks through the whole-take fit (track_files_take)
REPORTED = ("published", "refined", TAKE_VARIANT)
PEER_VARIANT = "detector 3D (raw)"  # the keypoints' world landmarks, where a scenario carries them, at the true root


def stream_variant(lag_frames: int) -> str:
    """The report name of the default stream (the online take, ``stream_runs``) at ``lag_frames``."""
    return f"stream, lag {lag_frames}"


def facing_deg(points: np.ndarray) -> np.ndarray:
    """Heading angle in the horizontal (x, z) plane of the hips' normal ``[F]`` (degrees)."""
    across = points[:, KP["l_hip"]] - points[:, KP["r_hip"]]
    return np.degrees(np.arctan2(-across[:, 0], across[:, 2]))


def _angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def reprojection_pct(joints: np.ndarray, target_px: np.ndarray, box_height_px: np.ndarray, focal_px: float,
                     image_size: tuple[int, int], visible: np.ndarray | None = None) -> np.ndarray:
    """Per frame: mean 2D distance between camera-aligned ``joints [F, ≥14, 3]`` projected and
    ``target_px [F, 14, 2]`` (over ``visible [F, 14]`` keypoints), as % of ``box_height_px [F]``."""
    px = project(joints[:, :N_KEYPOINTS_2D], focal_px, image_size)
    dist = np.linalg.norm(px - target_px, axis=-1)
    dist[joints[:, :N_KEYPOINTS_2D, 2] <= 1e-6] = np.nan  # at or behind the camera: no projection
    if visible is not None:
        dist = np.where(visible, dist, np.nan)
    with np.errstate(invalid="ignore"):
        return 100.0 * np.nanmean(dist, axis=1) / box_height_px


@dataclass
class View:
    """One rendered sequence: the truth in the camera-aligned frame ``cam [F, 15, 3]`` and the camera
    that saw it (to take any camera-aligned points back to the world: :meth:`world`)."""

    cam: np.ndarray
    camera_height_m: float
    distance_m: float
    pitch_deg: float
    roll_deg: float = 0.0

    def world(self, cam_points: np.ndarray) -> np.ndarray:
        return camera_to_world(cam_points, self.camera_height_m, self.distance_m, self.pitch_deg, self.roll_deg)


BELOW_HEAD = np.array([k for k in range(N_POINTS) if k not in (KP["head"], PELVIS)])  # the 13 joints scored
BODY_BONES = np.array([i for i, name in enumerate(MEASURED_BONE_NAMES) if name != "neck_nose"])
ANKLES = [KP["r_ankle"], KP["l_ankle"]]
MAX_HUMAN_SPEED_MPS = 12.0  # a joint faster than this where the truth is slower is a pop


@dataclass
class VariantStats:
    """Per-frame results of one engine variant in one scenario (frames with an output)."""

    mpjpe: list[np.ndarray] = field(default_factory=list)
    mpjpe13: list[np.ndarray] = field(default_factory=list)
    pa: list[np.ndarray] = field(default_factory=list)
    pa13: list[np.ndarray] = field(default_factory=list)
    bones: list[np.ndarray] = field(default_factory=list)      # [F, 8] |bone − true bone|
    proportions: list[np.ndarray] = field(default_factory=list)  # [F, 8] the same at the true stature
    yaw: list[np.ndarray] = field(default_factory=list)
    accel: list[np.ndarray] = field(default_factory=list)
    floor: list[np.ndarray] = field(default_factory=list)
    reproj: list[np.ndarray] = field(default_factory=list)
    reproj_input: list[np.ndarray] = field(default_factory=list)
    root: list[np.ndarray] = field(default_factory=list)
    root_pct: list[np.ndarray] = field(default_factory=list)
    skate: list[np.ndarray] = field(default_factory=list)      # planted-foot horizontal speeds, m/s
    foot_height: list[np.ndarray] = field(default_factory=list)  # planted-foot height error, m
    pops: list[np.ndarray] = field(default_factory=list)       # per frame: a joint over MAX_HUMAN_SPEED_MPS
    seconds: float = 0.0
    person_frames: int = 0

    def add(self, run: EngineRun, view: View, floor: np.ndarray, frames: list[KeypointFrame],
            config: EvalConfig, person_frames: int | None = None) -> None:
        ok = run.ok
        self.seconds += run.seconds
        self.person_frames += len(ok) if person_frames is None else person_frames
        joints, root, truth = run.joints[ok], run.root[ok], view.cam[ok]
        gt = truth - truth[:, PELVIS:PELVIS + 1]
        rel = joints - root[:, None]
        self.mpjpe.append(mpjpe(rel, gt))
        self.mpjpe13.append(mpjpe(rel[:, BELOW_HEAD], gt[:, BELOW_HEAD]))
        self.pa.append(pa_mpjpe(rel, gt))
        self.pa13.append(pa_mpjpe(rel[:, BELOW_HEAD], gt[:, BELOW_HEAD]))
        out_bones, true_bones = bone_lengths_m(rel), bone_lengths_m(gt)
        self.bones.append(np.abs(out_bones - true_bones))
        at_true_size = out_bones * (stature_m(true_bones) / stature_m(out_bones))[:, None]
        self.proportions.append(np.abs(at_true_size - true_bones))
        self.yaw.append(_angle_diff(facing_deg(rel), facing_deg(gt)))
        run_idx = np.flatnonzero(ok)
        if len(run_idx) > 2 and np.all(np.diff(run_idx) == 1):
            self.accel.append(acceleration_error(rel, gt))
        self.floor.append(floor[ok])
        if not config.engine.translation:  # the pelvis is kept at the origin: no root, no projection
            return
        clean_px = project(truth[:, :N_KEYPOINTS_2D], config.focal_px, config.image_size)
        box = np.ptp(clean_px[..., 1], axis=1)
        self.reproj.append(reprojection_pct(joints, clean_px, box, config.focal_px, config.image_size))
        given = np.array([f.people[0].points_px for f in frames])[ok]
        visible = np.array([f.people[0].confidence for f in frames])[ok] >= config.engine.confidence_threshold
        self.reproj_input.append(reprojection_pct(joints, given, box, config.focal_px, config.image_size, visible))
        err = np.linalg.norm(root - truth[:, PELVIS], axis=-1)
        self.root.append(err)
        self.root_pct.append(100.0 * err / truth[:, PELVIS, 2])
        self._add_world(view.world(run.joints), view.world(view.cam), ok, config.fps)

    def _add_world(self, pred_w: np.ndarray, true_w: np.ndarray, ok: np.ndarray, fps: float) -> None:
        """Feet and speeds in the world (NaN rows: frames without output)."""
        planted = planted_feet(true_w[:, ANKLES], fps)
        self.skate.append(foot_skating_mps(pred_w[:, ANKLES], planted, fps))
        self.foot_height.append(foot_height_error_m(pred_w[:, ANKLES], true_w[:, ANKLES], planted))
        pred_speed, true_speed = speeds_mps(pred_w, fps), speeds_mps(true_w, fps)
        # numpy's stubs give .any(axis=...) as a scalar or an array: over axis 1 of [F, J] it is an array
        pop = cast(np.ndarray, ((pred_speed > MAX_HUMAN_SPEED_MPS) & (true_speed <= MAX_HUMAN_SPEED_MPS)).any(axis=1))
        self.pops.append(pop[ok])

    def extend(self, other: VariantStats) -> None:
        for name in ("mpjpe", "mpjpe13", "pa", "pa13", "bones", "proportions", "yaw", "accel", "floor", "reproj",
                     "reproj_input", "root", "root_pct", "skate", "foot_height", "pops"):
            getattr(self, name).extend(getattr(other, name))
        self.seconds += other.seconds
        self.person_frames += other.person_frames

    def summary(self) -> dict:
        cat = _cat
        err, floor, yaw, acc = cat(self.mpjpe), cat(self.floor), cat(self.yaw), cat(self.accel)
        bones = np.concatenate(self.bones) if self.bones else np.zeros((0, len(MEASURED_BONE_NAMES)))
        proportions = np.concatenate(self.proportions) if self.proportions else bones
        skate, height = cat(self.skate), cat(self.foot_height)
        return {
            "frames_with_output": int(len(err)),
            "mpjpe_cm": _r(100 * _mean(err)),
            "mpjpe13_cm": _r(100 * _mean(cat(self.mpjpe13))),
            "pa_mpjpe_cm": _r(100 * _mean(cat(self.pa))),
            "pa_mpjpe13_cm": _r(100 * _mean(cat(self.pa13))),
            "bone_error_cm": _r(100 * _mean(bones[:, BODY_BONES].ravel())),
            "bone_error_by_bone_cm": {name: _r(100 * _mean(bones[:, b])) for b, name in enumerate(MEASURED_BONE_NAMES)},
            "proportion_error_cm": _r(100 * _mean(proportions[:, BODY_BONES].ravel())),
            "yaw_error_deg": {"mean": _r(_mean(yaw), 1), "median": _r(float(np.median(yaw)) if len(yaw) else None, 1)},
            "accel_error_mm_per_frame2": _r(1000 * _mean(acc)) if len(acc) else None,
            "floor_mpjpe_cm": _r(100 * _mean(floor)),
            "engine_minus_floor_cm": _r(100 * (_mean(err) - _mean(floor))),
            "frames_below_floor": _r(float(np.mean(err < floor)) if len(err) else None, 4),
            "reprojection_error_pct": _r(_mean(cat(self.reproj))),
            "reprojection_error_input_pct": _r(_mean(cat(self.reproj_input))),
            "root_error_m": _r(_mean(cat(self.root)), 3),
            "root_error_pct_distance": _r(_mean(cat(self.root_pct))),
            "foot_skating_cm_per_s": {"mean": _r(100 * _mean(skate), 1),
                                      "median": _r(100 * float(np.median(skate)) if len(skate) else None, 1)},
            "planted_foot_height_cm": {"mean": _r(100 * _mean(height), 1),
                                       "penetration_mean": _r(100 * _mean(np.maximum(-height, 0.0)), 1),
                                       "frames_below_2cm": _r(_share(height < -0.02), 4),
                                       "float_mean": _r(100 * _mean(np.maximum(height, 0.0)), 1)},
            "frames_with_pop": _r(float(np.mean(cat(self.pops))) if self.pops else None, 4),
            "engine_person_frames_per_s": _r(self.person_frames / self.seconds if self.seconds else None, 1),
        }


def _share(flags: np.ndarray) -> float | None:
    """The fraction of True in ``flags`` (None when empty)."""
    return float(np.mean(flags)) if len(flags) else None


def _cat(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0)


def _mean(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(values.mean()) if len(values) else float("nan")


def _r(value: float | None, digits: int = 2) -> float | None:
    return None if value is None or not np.isfinite(value) else round(float(value), digits)


@dataclass
class ScenarioResult:
    """One scenario's results, per engine variant; :meth:`report` is its JSON entry."""

    scenario: Scenario
    variants: dict[str, VariantStats] = field(default_factory=lambda: {name: VariantStats() for name in REPORTED})
    person_frames: int = 0
    camera_distances_m: list[float] = field(default_factory=list)
    heights_m: list[float] = field(default_factory=list)  # the rendered bodies' statures
    queries: list[Person] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.scenario.world_sd_m > 0:
            self.variants.setdefault(PEER_VARIANT, VariantStats())

    def extend(self, other: ScenarioResult) -> None:
        for name, stats in other.variants.items():
            self.variants.setdefault(name, VariantStats()).extend(stats)
        self.person_frames += other.person_frames
        self.camera_distances_m.extend(other.camera_distances_m)
        self.heights_m.extend(other.heights_m)

    def report(self) -> dict:
        out = {"scenario": asdict(self.scenario), "person_frames": self.person_frames,
               "camera_distance_m": {"min": _r(min(self.camera_distances_m, default=np.nan)),
                                     "max": _r(max(self.camera_distances_m, default=np.nan))},
               "body_height_m": {"min": _r(min(self.heights_m, default=np.nan)),
                                 "max": _r(max(self.heights_m, default=np.nan))}}
        out.update({name: stats.summary() for name, stats in self.variants.items()})
        pub, ref, take = (_mean(_cat(self.variants[name].mpjpe13)) for name in REPORTED)
        out["mpjpe13_change_pct"] = _r(100 * (ref - pub) / pub, 1) if pub > 0 else None
        out["whole_take_mpjpe13_change_pct"] = _r(100 * (take - pub) / pub, 1) if pub > 0 else None
        return out


def engine_scale(scenario: Scenario) -> float:
    """Body size the engine is told, relative to the database skeleton (1 unless ``height_given``)."""
    return scenario.subject_height_m / UNIVERSAL_HEIGHT_M if scenario.height_given else 1.0


def floor_key(clip_index: int, yaw_index: int, scenario: Scenario) -> tuple:
    """The key of :func:`compute_floors`' result for one rendered clip, yaw and scenario: renderings
    of the same truth at the same engine scale share it."""
    if scenario.body == "universal":
        return (clip_index, -1, scenario.body, scenario.subject_height_m, engine_scale(scenario))
    return (clip_index, yaw_index, scenario.body, 0.0, engine_scale(scenario))


def compute_floors(db: MotionDatabase, truths: list[Truth], scenarios: tuple[Scenario, ...],
                   config: EvalConfig, log=None) -> dict[tuple, np.ndarray]:
    """Per-frame database floors (metres) of every truth each scenario renders, keyed by
    :func:`floor_key`.

    The floor is against the database at the size the engine is told (1.75 m unless the scenario
    gives the subject's height): min over frames of MPJPE(truth, s·db) = s · floor(truth / s).
    """
    index = FloorIndex.from_positions(db.positions)
    poses: dict[tuple, np.ndarray] = {}
    for scenario in scenarios:
        for i, truth in enumerate(truths):
            for j, _ in enumerate(truth.yaws_deg or config.yaws_deg):
                key = floor_key(i, j, scenario)
                if key not in poses:
                    positions, _ = scenario_positions(truth, scenario, i, j, config.seed)
                    poses[key] = positions / key[-1]
    floors = {}
    for scale in sorted({key[-1] for key in poses}):
        keys = [key for key in poses if key[-1] == scale]
        t0 = time.perf_counter()
        result = scale * database_floor(index, np.concatenate([poses[k] for k in keys])).mpjpe_m
        bounds = np.cumsum([0] + [len(poses[k]) for k in keys])
        floors.update({k: result[a:b] for k, a, b in zip(keys, bounds[:-1], bounds[1:])})
        if log:
            log(f"floor: {bounds[-1]} truth frames x {index.n_frames} database frames in "
                f"{time.perf_counter() - t0:.2f} s (engine scale {scale:.3f})")
    return floors


def variant_config(base: EngineConfig, refine: bool) -> EngineConfig:
    """``base`` with ``refine`` set. 1€ filters left at their defaults follow the variant (the engine
    picks different defaults for refined and retrieved poses); filters set explicitly are kept."""
    # None: the filter chosen per variant
    if base == replace(base, rotation_filter=None, root_filter=None, keypoint_filter=None):
        return replace(base, refine=refine, rotation_filter=None, root_filter=None, keypoint_filter=None)
    return replace(base, refine=refine)


def _engine_config(config: EvalConfig, scenario: Scenario | None = None, refine: bool | None = None
                   ) -> EngineConfig:
    cfg = replace(config.engine, fps=config.fps, focal_px=config.focal_px, image_size=config.image_size)
    if refine is not None:
        cfg = variant_config(cfg, refine)
    if scenario is not None and scenario.height_given:
        cfg = replace(cfg, subject_height_m=scenario.subject_height_m)
    if scenario is not None and scenario.camera_height_given and cfg.refine:
        cfg = replace(cfg, camera_height_m=scenario.camera_height_m)
    return cfg


def _new_engine(db: MotionDatabase, config: EvalConfig) -> Engine:
    return Engine(db, _engine_config(config))


def evaluate_scenario(db: MotionDatabase, truths: list[Truth], scenario: Scenario, config: EvalConfig,
                      rng: np.random.Generator, floors: dict, bar: tqdm | None = None) -> ScenarioResult:
    """Every clip and yaw of one scenario, rendered once and run through each engine variant."""
    result = ScenarioResult(scenario)
    for i, truth in enumerate(truths):
        for j, yaw in enumerate(truth.yaws_deg or config.yaws_deg):
            positions, height = scenario_positions(truth, scenario, i, j, config.seed)
            distance = camera_distance(positions, yaw, config)
            camera = (scenario.camera_height_m, distance, scenario.pitch_deg, scenario.roll_deg)
            view = View(camera_view(positions, yaw, *camera), *camera)
            frames = render(view.cam, scenario, config.focal_px, config.image_size, rng)
            floor = floors[floor_key(i, j, scenario)]
            if PEER_VARIANT in result.variants:
                center = (config.image_size[0] / 2.0, config.image_size[1] / 2.0)
                peer = world_landmarks_run(frames, view.cam[:, PELVIS], config.focal_px, center)
                result.variants[PEER_VARIANT].add(peer, view, floor, frames, config)
            for name, refine in VARIANTS:
                engine = _engine_config(config, scenario, refine)
                result.variants[name].add(run_sequence(Engine(db, engine), frames), view, floor, frames, config)
                if refine:
                    for lag, run in stream_runs(db, engine, frames, config.stream_lags).items():
                        stats = result.variants.setdefault(stream_variant(lag), VariantStats())
                        stats.add(run, view, floor, frames, config, person_frames=len(frames))
                    given = scenario.camera_height_m if scenario.camera_height_given else None
                    take = track_files_take(db, engine, frames, config.fps, given)
                    result.variants[TAKE_VARIANT].add(take, view, floor, frames, config, person_frames=len(frames))
            result.person_frames += len(frames)
            result.camera_distances_m.append(distance)
            result.heights_m.append(height)
            result.queries.extend(f.people[0] for f in frames[::4])
            if bar is not None:
                bar.update(len(frames))
    return result


def search_benchmark(engine: Engine, people: list[Person], threshold: float) -> dict:
    """Recall@1 of the clustered search against exact search, and the time of each."""
    cfg = engine.config
    prepared = []
    for person in people:
        vis = person.confidence >= threshold
        query, _, scale = normalize_pose_2d(person.points_px, vis)
        if scale > 0:
            prepared.append((query, vis))
    index = engine.pipeline.index
    search_clustered(index, *prepared[0], descents=cfg.grid_descents)
    search_exact(index, *prepared[0])
    t0 = time.perf_counter()
    clustered = [search_clustered(index, q, v, engine.pipeline.n_clusters, cfg.per_cluster,
                                  cfg.grid_descents)[0] for q, v in prepared]
    t1 = time.perf_counter()
    exact = [search_exact(index, q, v, 1)[0][0] for q, v in prepared]
    t2 = time.perf_counter()
    recall = float(np.mean([e in c for c, e in zip(clustered, exact)]))
    return {"queries": len(prepared), "recall_at_1": round(recall, 4),
            "clustered_us": round(1e6 * (t1 - t0) / len(prepared), 1),
            "exact_us": round(1e6 * (t2 - t1) / len(prepared), 1),
            "speedup": round((t2 - t1) / (t1 - t0), 1)}


def two_view(db: MotionDatabase, truths: list[Truth], config: EvalConfig, separation_deg: float) -> dict:
    """Mean distance (cm) between independent reconstructions from two cameras ``separation_deg`` apart."""
    rng = np.random.default_rng(config.seed + 1)
    scenario = Scenario("two-view")
    dists = []
    for truth in truths:
        for yaw in config.yaws_deg[::2]:
            views = []
            for turn in (yaw, yaw + separation_deg):
                cam = view_of(truth, turn, scenario.camera_height_m, camera_distance(truth.positions, turn, config))
                frames = render(cam, scenario, config.focal_px, config.image_size, rng)
                views.append(run_sequence(_new_engine(db, config), frames).local)
            ok = ~np.isnan(views[0][:, PELVIS, 0]) & ~np.isnan(views[1][:, PELVIS, 0])
            dists.append(mpjpe(views[0][ok], views[1][ok]))
    return {"separation_deg": separation_deg, "variant": "refined" if config.engine.refine else "published",
            "mean_distance_cm": round(100 * float(np.concatenate(dists).mean()), 2)}


def engine_summary(engine: EngineConfig) -> dict:
    return {"search": engine.search, "n_clusters": engine.n_clusters, "per_cluster": engine.per_cluster,
            "grid_descents": engine.grid_descents,
            "window_weights": engine.window_weights, "weight_2d": engine.weight_2d, "smoothing": engine.smoothing,
            "variants": {name: {"refine": refine} for name, refine in VARIANTS}}


def _stderr(message: str) -> None:
    """Progress of a long evaluation, logged at info level (``mocapdb eval`` shows it; ``-q`` hides it)."""
    LOG.info(message)


def evaluate(db: MotionDatabase, heldout: list[Path], config: EvalConfig) -> dict:
    """The full report of one database against held-out clips (see the module docstring)."""
    truths = load_heldout(heldout, config.fps)
    t0 = time.perf_counter()
    floors = compute_floors(db, truths, config.scenarios, config, log=_stderr)
    floor_seconds = time.perf_counter() - t0
    rng = np.random.default_rng(config.seed)
    total = sum(len(t.positions) for t in truths) * len(config.yaws_deg) * len(config.scenarios)
    bar = progress(total=total, desc="eval", unit="frame")
    results = [evaluate_scenario(db, truths, scenario, config, rng, floors, bar) for scenario in config.scenarios]
    bar.close()
    engine = _new_engine(db, config)
    return {
        "database": {"projections": db.n_projections, "frames": db.n_frames, "clusters": db.n_clusters},
        "heldout_clips": [t.name for t in truths],
        "engine": engine_summary(config.engine),
        "floor_seconds": round(floor_seconds, 2),
        "scenarios": [r.report() for r in results],
        "search": search_benchmark(engine, results[0].queries, config.engine.confidence_threshold),
        "two_view": [two_view(db, truths, config, 135.0), two_view(db, truths, config, 75.0)],
    }
