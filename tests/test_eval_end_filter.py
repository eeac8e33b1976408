"""tools/eval_end_filter.py replays the online take's calls into its end joints: replayed with the stream's own
filters, a rendered view gives exactly the end rotations of the stream run on it (mocapdb.evaluation.ends)."""
import sys
from pathlib import Path

import numpy as np

from mocapdb.evaluation.bodies import reshape_body, stature_m
from mocapdb.evaluation.ends import SCENARIOS, ends_truths, stream_ends, view_frames
from mocapdb.evaluation.gate import GATE_BODIES, gate_engine_config
from mocapdb.evaluation.heldout import EvalConfig
from mocapdb.runtime.online_take import CAUSAL_ROTATIONS

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
from eval_end_filter import recorded_stream, replayed  # noqa: E402

CLIP = ROOT / "data" / "gate" / "cmu_bvh" / "007_12.bvh"


def test_a_replayed_stream_is_the_stream_run(small_db):
    config = EvalConfig()
    truth, ends = ends_truths([CLIP], 48, (63.0,), config.fps)[0]
    lengths = GATE_BODIES[0].lengths_m()
    posed = reshape_body(truth.source_joints(), lengths)
    frames = view_frames(posed, ends, float(stature_m(lengths)), 63.0, SCENARIOS[1], config)[0]
    engine = gate_engine_config(config)
    tracks = recorded_stream(small_db, engine, frames)
    direct = stream_ends(small_db, engine, frames).ends[0]
    again = replayed(tracks, len(frames), "feet", 3, CAUSAL_ROTATIONS)
    assert np.isfinite(direct).any()
    np.testing.assert_array_equal(again, direct)
