"""The stream's causal filters of the end joints at lag 0, measured on the synthetic takes (mocapdb/evaluation/ends.py):
per 1-euro setting, the stream's error (median geodesic, degrees) and acceleration (mean frame-to-frame change of
the angular step, deg/frame^2) beside the truth's, exact and noisy. ``--end head``: the head on frames the face
mesh fixed (runtime/online_ends.MESH_HEAD_FILTER; the mesh rendered, its frames only); ``feet`` or ``hands``: the
feet's and hands' directions (OnlineEnds.direction_filter, the online take's ``causal_rotations``), every frame;
``hands`` with ``--hand-points 21``: where the hand model saw the hand (online_ends.HAND_MODEL_FILTER).

    .venv/bin/python tools/eval_end_filter.py [--end head|feet|hands] [--hand-points 21] [--every-yaw 2]
        [--settings 0.5,0.3 2,2 ...]

The views: the gate's clips on its bodies from every --every-yaw-th of the 6 yaws (with --end head, those with more
than 10 frames of mesh). Prints a Markdown table (docs/benchmarks.md, "The head from the face mesh", "The feet and
hands in the stream").
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import mocapdb.runtime.online_ends as online_ends
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.geometry import matrix_to_quat
from mocapdb.evaluation.bodies import reshape_body, stature_m
from mocapdb.evaluation.ends import (
    ENDS_YAWS_DEG,
    SCENARIOS,
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
ONLINE_ENDS_INIT = online_ends.OnlineEnds.__init__
UNFILTERED = OneEuroParams(min_cutoff_hz=1000.0, beta=0.0)   # the highest cut-off allowed: no smoothing at 24 fps


def step_change_deg(rotations: np.ndarray) -> np.ndarray:
    """``[F - 2]`` the angle (degrees) between successive frame-to-frame turns of ``rotations [F, 3, 3]``."""
    q = matrix_to_quat(np.swapaxes(rotations[:-1], -1, -2) @ rotations[1:])
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    steps = 2.0 * q[:, 1:]                                   # small turns: rotation vectors (rad), own frame
    return np.degrees(np.linalg.norm(np.diff(steps, axis=0), axis=-1))


def views(every_yaw: int, config: EvalConfig, mesh: bool, hand_points: int
          ) -> list[tuple[str, list, np.ndarray, np.ndarray]]:
    """(scenario, keypoint frames, true end rotations, frames scored) of each view (the hands as ``hand_points``
    3 or 21); with ``mesh`` the face mesh rendered, the views showing a face and their frames with a mesh."""
    out = []
    for truth, ends in ends_truths(gate_clip_files(Path("data/gate/cmu_bvh")), MAX_FRAMES, ENDS_YAWS_DEG, config.fps):
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


def score(db, engine, rendered, rows: tuple[int, ...]) -> dict[str, tuple[float, float, float]]:
    """Per scenario: the end joints' (``rows`` of END_JOINTS) median error on the scored frames, their mean step
    change and the truth's."""
    errors: dict[str, list[list[np.ndarray]]] = {}
    for name, frames, true_view, seen in rendered:
        estimate = stream_ends(db, engine, frames).ends[0]
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
    model saw them (``hand_points`` 21), else the directions'."""
    if end == "head":
        online_ends.MESH_HEAD_FILTER = params
        return
    if end == "hands" and hand_points == 21:
        online_ends.HAND_MODEL_FILTER = params
        return
    init = ONLINE_ENDS_INIT

    def with_directions(self: online_ends.OnlineEnds, *args, **kwargs) -> None:
        init(self, *args, **kwargs)
        self.direction_filter = OneEuroFilter(params)

    online_ends.OnlineEnds.__init__ = with_directions   # type: ignore[method-assign]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", type=Path, default=Path("demo/sample.db"))
    parser.add_argument("--end", choices=list(ROWS), default="head")
    parser.add_argument("--every-yaw", type=int, default=2)
    parser.add_argument("--hand-points", type=int, choices=(3, 21), default=3,
                        help="the hands as BlazePose's 3 points or with the hand model's 21 (detect --hands)")
    parser.add_argument("--settings", nargs="+", default=["none", "0.5,0.3", "1,0.5", "1.5,1", "2,2", "3,3"],
                        help="1-euro cut-off (Hz),beta pairs; 'none': unfiltered")
    args = parser.parse_args()
    config = EvalConfig()
    db, engine = load_database(args.db), gate_engine_config(config)
    rendered = views(args.every_yaw, config, args.end == "head", args.hand_points)
    print(f"{len(rendered)} views{' with a face mesh' if args.end == 'head' else ''}\n")
    print(f"| cut-off Hz / beta | input | {args.end} error | acceleration deg/frame² | truth's |")
    print("|---|---|---|---|---|")
    for setting in args.settings:
        params = UNFILTERED if setting == "none" else OneEuroParams(*map(float, setting.split(",")))
        use_filter(args.end, args.hand_points, params)
        for name, (error, accel, truth) in score(db, engine, rendered, ROWS[args.end]).items():
            print(f"| {setting} | {name} | {error:.2f}° | {accel:.2f} | {truth:.2f} |", flush=True)


if __name__ == "__main__":
    main()
