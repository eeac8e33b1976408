"""The stream's causal filters of the end joints at lag 0, measured on the synthetic takes (mocapdb/evaluation/ends.py):
per 1-euro setting, the stream's error (median geodesic, degrees) and acceleration (mean frame-to-frame change of
the angular step, deg/frame^2) beside the truth's, exact and noisy. ``--end head``: the head on frames the face
mesh fixed (runtime/online_ends.MESH_HEAD_FILTER; the mesh rendered, its frames only); ``feet`` or ``hands``: the
feet's and hands' directions (OnlineEnds.direction_filter, the online take's ``causal_rotations``), every frame
(a steady foot's share goes to its Kalman filter, online_ends.SteadyFeet, whatever the setting);
``hands`` with ``--hand-points 21``: where the hand model saw the hand (online_ends.HAND_MODEL_FILTER). The engine
runs once per view; each setting replays the online take's calls into its end joints (OnlineEnds) on that run
(the same outputs as a run of its own: the stream's end joints depend on nothing else).

    .venv/bin/python tools/eval_end_filter.py [--end head|feet|hands] [--hand-points 21] [--every-yaw 2]
        [--bvh data/gate/cmu_bvh/007_01.bvh ...] [--settings 0.5,0.3 2,2 ...]

The views: the clips (default the gate's; ``--bvh`` to choose on others) on the gate's bodies from every
--every-yaw-th of the 6 yaws (with --end head, those with more than 10 frames of mesh). Prints a Markdown table
(docs/benchmarks.md, "The head from the face mesh", "The feet's and hands' filter in the stream").
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import mocapdb.runtime.online_ends as online_ends
import mocapdb.runtime.online_take as online_take
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.geometry import matrix_to_quat
from mocapdb.core.motion import Motion
from mocapdb.evaluation.bodies import reshape_body, stature_m
from mocapdb.evaluation.ends import (
    ENDS_YAWS_DEG,
    SCENARIOS,
    end_globals,
    ends_truths,
    gate_clip_files,
    geodesic_deg,
    stream_ends,
    view_frames,
)
from mocapdb.evaluation.gate import GATE_BODIES, MAX_FRAMES, gate_engine_config
from mocapdb.evaluation.heldout import EvalConfig
from mocapdb.runtime.filters import OneEuroFilter, OneEuroParams

ROWS = {"head": (4,), "feet": (0, 1), "hands": (2, 3)}   # END_JOINTS rows
UNFILTERED = OneEuroParams(min_cutoff_hz=1000.0, beta=0.0)   # the highest cut-off allowed: no smoothing at 24 fps


def step_change_deg(rotations: np.ndarray) -> np.ndarray:
    """``[F - 2]`` the angle (degrees) between successive frame-to-frame turns of ``rotations [F, 3, 3]``."""
    q = matrix_to_quat(np.swapaxes(rotations[:-1], -1, -2) @ rotations[1:])
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    steps = 2.0 * q[:, 1:]                                   # small turns: rotation vectors (rad), own frame
    return np.degrees(np.linalg.norm(np.diff(steps, axis=0), axis=-1))


class RecordedEnds(online_ends.OnlineEnds):
    """The online take's end joints, their arguments and every call into them (in order) kept in :data:`MADE`."""

    def __init__(self, *args) -> None:
        super().__init__(*args)
        self.args, self.calls = args, []
        MADE.append(self)

    def add(self, *call) -> None:
        self.calls.append(call)
        super().add(*call)

    def output(self, *call) -> tuple[np.ndarray, np.ndarray]:
        self.calls.append(call)
        return super().output(*call)


MADE: list[RecordedEnds] = []


def recorded_stream(db, engine, frames: list) -> list[RecordedEnds]:
    """The default stream of ``frames`` run once: each track's end joints with their calls."""
    MADE.clear()
    online_take.OnlineEnds = RecordedEnds   # type: ignore[misc]
    try:
        stream_ends(db, engine, frames)
    finally:
        online_take.OnlineEnds = online_ends.OnlineEnds   # type: ignore[misc]
    return list(MADE)


def replayed(tracks: list[RecordedEnds], n: int, end: str, hand_points: int, params: OneEuroParams) -> np.ndarray:
    """``[n, 5, 3, 3]`` the end globals (view frame; NaN: no output) of the stream ``tracks`` recorded, replayed
    with the filter of ``end`` at ``params`` (:func:`use_filter`); per frame the first track's output, as the
    stream scored gives each frame's first person (the synthetic takes hold one)."""
    use_filter(end, hand_points, params)
    outputs: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for track in tracks:
        ends = online_ends.OnlineEnds(*track.args)
        if end == "feet" or (end == "hands" and hand_points == 3):
            ends.direction_filter = OneEuroFilter(params)
        for call in track.calls:
            if len(call) == 2:
                ends.add(*call)
            else:
                outputs.setdefault(call[0], (call[1], ends.output(*call)[0]))
    out = np.full((n, 5, 3, 3), np.nan)
    if outputs:
        index = np.array(sorted(outputs))
        quats, turned = (np.array([outputs[i][k] for i in index]) for k in (0, 1))
        motion = Motion(quats, np.zeros((len(index), 3)), tracks[0].args[0], "view", end_rotations=turned)
        out[index] = end_globals(motion)
    return out


def views(files: list[Path], every_yaw: int, config: EvalConfig, mesh: bool, hand_points: int
          ) -> list[tuple[str, list, np.ndarray, np.ndarray]]:
    """(scenario, keypoint frames, true end rotations, frames scored) of each view of the ``files`` (the hands as
    ``hand_points`` 3 or 21); with ``mesh`` the face mesh rendered, the views showing a face and their frames with a
    mesh."""
    out = []
    for truth, ends in ends_truths(files, MAX_FRAMES, ENDS_YAWS_DEG, config.fps):
        for body in GATE_BODIES:
            lengths = body.lengths_m()
            posed, stature = reshape_body(truth.source_joints(), lengths), float(stature_m(lengths))
            for scenario in SCENARIOS:
                for yaw in ENDS_YAWS_DEG[::every_yaw]:
                    frames, true_view = view_frames(posed, ends, stature, yaw, scenario, config, hand_points, mesh)
                    seen = np.array([not mesh or (bool(f.people) and f.people[0].face is not None
                                                  and f.people[0].face[1, 3] > 0) for f in frames])
                    if seen.sum() > 10:
                        out.append((scenario.name, frames, true_view, seen))
    return out


def score(estimates: list[np.ndarray], rendered, rows: tuple[int, ...]) -> dict[str, tuple[float, float, float]]:
    """Per scenario: the end joints' (``rows`` of END_JOINTS) median error on the scored frames of the ``estimates``
    (end globals ``[F, 5, 3, 3]`` of each rendered view), their mean step change and the truth's."""
    errors: dict[str, list[list[np.ndarray]]] = {}
    for estimate, (name, _, true_view, seen) in zip(estimates, rendered):
        scored = errors.setdefault(name, [[], [], []])
        for row in rows:
            end = estimate[:, row]
            given = np.isfinite(end).all(axis=(1, 2))
            inner = (seen & given)[1:-1] & (seen & given)[2:] & (seen & given)[:-2]
            scored[0].append(geodesic_deg(end, true_view[:, row])[seen])
            scored[1].append(step_change_deg(np.where(given[:, None, None], end, np.eye(3)))[inner])
            scored[2].append(step_change_deg(true_view[:, row])[inner])
    return {name: (float(np.nanmedian(np.concatenate(e))), float(np.mean(np.concatenate(a))),
                   float(np.mean(np.concatenate(t)))) for name, (e, a, t) in errors.items()}


def use_filter(end: str, hand_points: int, params: OneEuroParams) -> None:
    """The stream's filter of ``end`` becomes ``params``: the head's on mesh frames, the hands' where the hand
    model saw them (``hand_points`` 21); the feet's and the hands' 3-point directions' are set by :func:`replayed`."""
    if end == "head":
        online_ends.MESH_HEAD_FILTER = params
    elif end == "hands" and hand_points == 21:
        online_ends.HAND_MODEL_FILTER = params


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", type=Path, default=Path("demo/sample.db"))
    parser.add_argument("--end", choices=list(ROWS), default="head")
    parser.add_argument("--every-yaw", type=int, default=2)
    parser.add_argument("--bvh", type=Path, nargs="+", default=gate_clip_files(Path("data/gate/cmu_bvh")))
    parser.add_argument("--hand-points", type=int, choices=(3, 21), default=3,
                        help="the hands as BlazePose's 3 points or with the hand model's 21 (detect --hands)")
    parser.add_argument("--settings", nargs="+", default=["none", "0.5,0.3", "1,0.5", "1.5,1", "2,2", "3,3"],
                        help="1-euro cut-off (Hz),beta pairs; 'none': unfiltered")
    args = parser.parse_args()
    config = EvalConfig()
    db, engine = load_database(args.db), gate_engine_config(config)
    rendered = views(args.bvh, args.every_yaw, config, args.end == "head", args.hand_points)
    tracks = [recorded_stream(db, engine, frames) for _, frames, _, _ in rendered]
    print(f"{len(rendered)} views{' with a face mesh' if args.end == 'head' else ''}\n")
    print(f"| cut-off Hz / beta | input | {args.end} error | acceleration deg/frame² | truth's |")
    print("|---|---|---|---|---|")
    for setting in args.settings:
        params = UNFILTERED if setting == "none" else OneEuroParams(*map(float, setting.split(",")))
        estimates = [replayed(t, len(frames), args.end, args.hand_points, params)
                     for t, (_, frames, _, _) in zip(tracks, rendered)]
        for name, (error, accel, truth) in score(estimates, rendered, ROWS[args.end]).items():
            print(f"| {setting} | {name} | {error:.2f}° | {accel:.2f} | {truth:.2f} |", flush=True)


if __name__ == "__main__":
    main()
