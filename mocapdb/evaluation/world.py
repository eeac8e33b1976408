"""`mocapdb eval --world`: several people in one camera's world, scored against the truth.

A **take** is a handful of held-out clips (``data_specs/evaluation_split.md``) rendered together by
one pinhole camera (:mod:`mocapdb.evaluation.world_takes`: scenarios, bodies, placement, noise).
Each take runs through the engine as ``reconstruct`` runs it (``EngineConfig.for_track_files``) and the
whole-take world (:func:`mocapdb.runtime.world.fuse.fit_world`) twice (:data:`MODES`): with the camera
height given and with nothing given (:func:`run_take`). Its tracks are scored against its people
(:mod:`mocapdb.evaluation.world_scores`: matching, stature, root and floor errors, plausibility
flags, pair stature ratios). This module holds the run (:func:`evaluate_world`), its report's
tables (:func:`format_table`) and the checks against issue 27's targets (:func:`check_lines`).
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.outputs import TrackRecording
from mocapdb.core.progress import progress
from mocapdb.core.skeleton import N_KEYPOINTS_2D
from mocapdb.evaluation.heldout import UNIVERSAL_HEIGHT_M, load_heldout
from mocapdb.evaluation.world_camera import score_world_camera, summary_lines
from mocapdb.evaluation.world_scores import HUMAN_STATURE_RANGE_M, IMPLAUSIBLE, TrackFit, by_role, score_take, summarise
from mocapdb.evaluation.world_takes import CAMERA_HEIGHT_RANGE_M, WorldConfig, WorldTake, build_take
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.take import take_joints
from mocapdb.runtime.world.fuse import World, fit_world

LOG = logging.getLogger(__name__)

MODES = (("camera_height_given", True), ("nothing_given", False))  # report name, camera height given

TARGET_STATURE_GIVEN_PCT = 3.0  # camera height given: median stature error
TARGET_ROOT_GIVEN_M = 0.25      # camera height given: median root error
TARGET_STATURE_MAX_PCT = 15.0   # nothing given: no stature off by more
TARGET_RATIO_PCT = 5.0          # nothing given: no pair's stature ratio off by more
TARGET_ROOT_PCT = 10.0          # nothing given: median root error, % of the distance
TARGET_CHILD_PCT = 10.0         # the child's stature error, both modes


def track_fit(rec: TrackRecording, fitted: TrackRecording, fps: float) -> TrackFit:
    """A track as the engine recorded it (``rec``: its input keypoints) and as the whole-take world
    fitted it (``fitted``); ``fps``: the take's frame rate (Hz)."""
    frames, joints, root = take_joints(fitted, fps)
    up = None if fitted.up_view is None else np.asarray(fitted.up_view, dtype=np.float64)
    return TrackFit(rec.track, frames, joints, root, UNIVERSAL_HEIGHT_M * float(fitted.scales[-1]), up,
                    fitted.floor_offset_m, rec.column("keypoints").reshape(-1, N_KEYPOINTS_2D, 3), rec.static)


def run_take(db: MotionDatabase, take: WorldTake, camera_height_m: float | None,
             config: WorldConfig) -> tuple[list[TrackFit], World, float, float]:
    """The take through the engine and the whole-take world (``camera_height_m`` given or None):
    every track (static ones too), the world, and the seconds of each."""
    engine_config = replace(config.engine, fps=config.fps, focal_px=config.focal_px, image_size=config.image_size,
                            camera_height_m=camera_height_m)
    engine = Engine(db, engine_config.for_track_files())   # as reconstruct runs it
    t0 = time.perf_counter()
    for frame in take.frames:
        engine.step(frame)
    recordings = engine.finish()
    t1 = time.perf_counter()
    fitted, world = fit_world(recordings, config.fps, camera_height_m=camera_height_m)
    t2 = time.perf_counter()
    return [track_fit(rec, fit, config.fps) for rec, fit in zip(recordings, fitted)], world, t1 - t0, t2 - t1


def run_takes(db: MotionDatabase, takes: list[WorldTake], config: WorldConfig) -> dict[str, list[dict]]:
    """Every take through :func:`run_take` and :func:`score_take` in each of :data:`MODES`: per mode
    the takes' results with their engine and world seconds (progress at info level)."""
    bar = progress(total=len(takes) * len(MODES), desc="world", unit="take")
    results: dict[str, list[dict]] = {mode: [] for mode, _ in MODES}
    for take in takes:
        for mode, given in MODES:
            fits, world, engine_s, world_s = run_take(db, take, take.camera.height_m if given else None, config)
            result = score_take(take, fits, config)
            result["camera"] = score_world_camera(world, {"height_m": take.camera.height_m,
                                                          "pitch_deg": take.camera.pitch_deg, "roll_deg": 0.0})
            results[mode].append({**result, "mode": mode, "engine_seconds": engine_s, "world_seconds": world_s})
            LOG.info(f"world: {take.scenario.name} #{take.repeat + 1}, {mode.replace('_', ' ')}: {len(fits)} "
                     f"tracks for {len(take.people)} people, engine {engine_s:.1f} s, world {world_s:.2f} s")
            bar.update(1)
    bar.close()
    return results


def evaluate_world(db: MotionDatabase, heldout: list[Path], config: WorldConfig) -> dict:
    """Every scenario's takes, each with the camera height given and with nothing given, scored
    (module docstring): a JSON-able report with per-take detail, summaries and timings (seconds)."""
    t_start = time.perf_counter()
    truths = load_heldout(heldout, config.fps)
    takes = [build_take(truths, s, i, r, config) for i, s in enumerate(config.scenarios) for r in range(config.repeats)]
    results = run_takes(db, takes, config)
    every = [t for mode, _ in MODES for t in results[mode]]
    return {
        "database": {"projections": db.n_projections, "frames": db.n_frames, "clusters": db.n_clusters},
        "heldout_clips": [t.name for t in truths],
        "config": {"repeats": config.repeats, "frames": config.frames, "fps": config.fps, "focal_px": config.focal_px,
                   "image_size": list(config.image_size), "seed": config.seed, "jitter": config.jitter,
                   "camera_height_range_m": list(CAMERA_HEIGHT_RANGE_M),
                   "human_stature_range_m": list(HUMAN_STATURE_RANGE_M)},
        "scenarios": [asdict(s) for s in config.scenarios],
        "summary": [{"scenario": s.name, "mode": mode, **summarise([t for t in takes if t["scenario"] == s.name])}
                    for s in config.scenarios for mode, takes in results.items()],
        "overall": {mode: summarise(results[mode]) for mode, _ in MODES},
        "world_camera": {mode: [t["camera"] for t in results[mode]] for mode, _ in MODES},
        "by_role": {mode: by_role(results[mode]) for mode, _ in MODES},
        "takes": every,
        "seconds": {"engine": sum(t["engine_seconds"] for t in every), "world": sum(t["world_seconds"] for t in every),
                    "total": time.perf_counter() - t_start},
    }


def _cell(value: float, digits: int = 1) -> str:
    return "–" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


_SUMMARY_HEADER = ("| scenario | camera height | people (missed) | stature error median / max | pair ratio max | "
                   "root error | root / distance | child | camera height error / floor angle | implausible tracks: "
                   "any (size / behind camera / under own floor) | soles under the true floor | false tracks |")
_ROLE_HEADER = "| role | camera height | people (missed) | stature error median / max | root error | root / distance |"


def format_table(report: dict) -> str:
    """Markdown tables of :func:`evaluate_world`'s report: per scenario and mode, then per role."""
    lines = [_SUMMARY_HEADER, "|---" * 12 + "|"]
    for row in report["summary"]:
        lines.append(_summary_row(row["scenario"], row["mode"], row))
    for mode, row in report["overall"].items():
        lines.append(_summary_row("**all**", mode, row))
    lines += ["", _ROLE_HEADER, "|---" * 6 + "|"]
    for mode, roles in report["by_role"].items():
        for role, r in roles.items():
            lines.append(f"| {role} | {_mode_label(mode)} | {r['people']} ({r['missed']}) | "
                         f"{_cell(r['stature_error_pct']['median'])} / {_cell(r['stature_error_pct']['max'])} % | "
                         f"{_cell(r['root_error_m'], 2)} m | {_cell(r['root_error_pct'])} % |")
    takes = {f"take {i}": score for i, score in enumerate(report["world_camera"]["nothing_given"])}
    return "\n".join(lines + ["", "Nothing given: " + summary_lines(takes)[0]])


def _mode_label(mode: str) -> str:
    return "given" if mode == "camera_height_given" else "not given"


def _summary_row(name: str, mode: str, r: dict) -> str:
    return (f"| {name} | {_mode_label(mode)} | {r['people']} ({r['missed']}) | "
            f"{_cell(r['stature_error_pct']['median'])} / {_cell(r['stature_error_pct']['max'])} % | "
            f"{_cell(r['pair_ratio_error_pct_max'])} % | {_cell(r['root_error_m'], 2)} m | "
            f"{_cell(r['root_error_pct'])} % | {_cell(r['child_stature_error_pct_max'])} % | "
            f"{_cell(r['camera_height_error_m'], 2)} m / {_cell(r['floor_angle_deg'])}° | "
            f"{r['implausible_tracks']} ({' / '.join(str(r['flagged_tracks'][f]) for f in IMPLAUSIBLE)}) of "
            f"{r['tracks']} | {r['flagged_tracks']['below_true_floor']} | {r['false_tracks']} |")


def check_lines(report: dict) -> list[str]:
    """A PASS/FAIL line per target of issue 27 (over every scenario's takes of the mode named)."""
    given, nothing = report["overall"]["camera_height_given"], report["overall"]["nothing_given"]
    both = [(given, "camera height given"), (nothing, "nothing given")]
    checks: list[tuple[str, Any, float, str]]
    checks = [(f"{label}: tracks outside the human range {HUMAN_STATURE_RANGE_M[0]}-{HUMAN_STATURE_RANGE_M[1]} m",
               r["out_of_range_tracks"], 0, "tracks") for r, label in both]
    checks += [(f"{label}: implausible tracks (size, behind the camera, soles > 5 cm under its own floor)",
                r["implausible_tracks"], 0, "tracks") for r, label in both]
    checks += [(f"{label}: people without a track", r["missed"], 0, "people") for r, label in both]
    checks += [("camera height given: median stature error", given["stature_error_pct"]["median"],
                TARGET_STATURE_GIVEN_PCT, "%"),
               ("camera height given: median root error", given["root_error_m"], TARGET_ROOT_GIVEN_M, "m"),
               ("nothing given: largest stature error", nothing["stature_error_pct"]["max"],
                TARGET_STATURE_MAX_PCT, "%"),
               ("nothing given: largest pair stature-ratio error", nothing["pair_ratio_error_pct_max"],
                TARGET_RATIO_PCT, "%"),
               ("nothing given: median root error / distance", nothing["root_error_pct"], TARGET_ROOT_PCT, "%")]
    checks += [(f"{label}: child's largest stature error", r["child_stature_error_pct_max"], TARGET_CHILD_PCT, "%")
               for r, label in both]
    return [f"{_verdict(value, target)}  {label}: {_cell(value, 0 if unit in ('tracks', 'people') else 2)} {unit} "
            f"≤ {target:g} {unit}" for label, value, target, unit in checks]


def _verdict(value: float, target: float) -> str:
    """PASS, FAIL, or n/a where there is nothing to score (no child in the run, nobody tracked)."""
    if not np.isfinite(value):
        return "n/a "
    return "PASS" if value <= target else "FAIL"
