"""The result stream opens as a table with integer frame numbers (polars, pandas)."""
import json

import numpy as np
import pandas as pd
import polars as pl

from mocapdb.core.outputs import STREAM_VERSION, Match, PersonPose, frame_line, header_line
from mocapdb.core.skeleton import N_POINTS, N_RIG_JOINTS


def _stream(tmp_path, n_frames=3):
    pose = PersonPose(track=0, joints_m=np.zeros((N_POINTS, 3)), quaternions=np.tile([1.0, 0, 0, 0], (N_RIG_JOINTS, 1)),
                      root_m=np.zeros(3), match=Match("002_01", 7, 84.0, 0.2))
    lines = [header_line(30.0)] + [frame_line(i, i / 30.0, [pose]) for i in range(n_frames)]
    path = tmp_path / "result.jsonl"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_header_has_no_key_of_a_frame_line():
    header = json.loads(header_line(30.0))
    frame = json.loads(frame_line(5, 0.1, []))
    assert header["version"] == STREAM_VERSION == 2 and not set(header) & set(frame)
    assert header["coordinate_frame"].startswith("camera-aligned")


def test_polars_reads_integer_frames(tmp_path):
    table = pl.read_ndjson(_stream(tmp_path)).filter(pl.col("frame").is_not_null())
    assert table.schema["frame"] == pl.Int64 and table["frame"].to_list() == [0, 1, 2]
    assert table["people"][2][0]["match"]["frame"] == 7


def test_pandas_reads_integer_frames(tmp_path):
    table = pd.read_json(_stream(tmp_path), lines=True, dtype={"frame": "Int64"}).iloc[1:]
    assert str(table["frame"].dtype) == "Int64" and table["frame"].tolist() == [0, 1, 2]
