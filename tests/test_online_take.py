"""The fixed lag of the stream: every frame out once, in order, L frames late, smoothed around it."""
import json

import numpy as np
import pytest

from mocapdb.core.outputs import Match, PersonPose
from mocapdb.core.skeleton import N_RIG_JOINTS, bone_lengths_m, universal_bone_lengths_m
from mocapdb.runtime.lag import FixedLag

MATCH = Match("clip", 0, 0.0, 0.1)


def _pose(track: int, root: np.ndarray, angle: float = 0.0) -> PersonPose:
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (N_RIG_JOINTS, 1))
    quats[3] = [np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)]
    return PersonPose(track, np.zeros((15, 3)), quats, np.asarray(root, dtype=np.float64), MATCH,
                      1.75, universal_bone_lengths_m())


def test_frames_come_out_once_in_order_lag_frames_late():
    lag = FixedLag(3, fps=30.0)
    out = []
    for t in range(10):
        due = lag.push(t, t / 30.0, [_pose(0, [0.0, 0.0, 5.0])])
        assert [f[0] for f in due] == ([t - 3] if t >= 3 else [])
        out += due
    out += lag.flush()
    assert [f[0] for f in out] == list(range(10))
    short = FixedLag(5, fps=30.0)
    assert short.push(0, 0.0, []) == [] and [f[0] for f in short.flush()] == [0]  # fewer frames than the lag


def test_smoothing_is_centred_calms_jitter_and_keeps_each_person_apart():
    rng = np.random.default_rng(0)
    n, fps = 120, 30.0
    truth = np.column_stack([np.linspace(-1, 1, n), np.zeros(n), np.full(n, 5.0)])   # a steady walk
    noisy = truth + rng.normal(scale=0.03, size=truth.shape)
    lag = FixedLag(6, fps)
    out = []
    for t in range(n):
        people = [_pose(0, noisy[t], 0.3 * np.sin(t / 10)), _pose(1, [2.0, 0.0, 6.0])]
        if t % 4 == 0:
            people = people[:1]  # person 1 missed in some frames
        out += lag.push(t, t / fps, people)
    out += lag.flush()
    roots = np.array([f[2][0].root_m for f in out])
    assert np.abs(roots - truth)[10:-10].mean() < 0.5 * np.abs(noisy - truth)[10:-10].mean()
    assert abs(np.mean((roots - truth)[10:-10, 0])) < 0.005   # no lag: no trailing offset along the walk
    other = [p for f in out for p in f[2] if p.track == 1]
    np.testing.assert_allclose([p.root_m for p in other], np.broadcast_to([2.0, 0.0, 6.0], (len(other), 3)))
    # the joints are the person's skeleton at the smoothed pose: its bones, its root
    pose = out[50][2][0]
    np.testing.assert_allclose(pose.joints_m[14], pose.root_m, atol=1e-12)
    np.testing.assert_allclose(bone_lengths_m(pose.joints_m), universal_bone_lengths_m(), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(pose.quaternions, axis=-1), 1.0)


def test_reconstruct_with_a_lag_writes_every_frame_steadier(small_db_path, tmp_path):
    from mocapdb.cli.main import main

    from .conftest import SAMPLE_KEYPOINTS

    common = [str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--fps", "60", "--image-size", "1088x1920",
              "--focal", "1681", "--per-frame"]
    joints = {}
    for lag in (0, 8):
        out = tmp_path / f"lag{lag}"
        assert main(["reconstruct", *common, "--out", str(out), "--lag-frames", str(lag)]) == 0
        lines = [json.loads(x) for x in (out / "result.jsonl").read_text().splitlines()[1:]]
        assert [x["frame"] for x in lines] == sorted(x["frame"] for x in lines) and len(lines) == 100
        joints[lag] = np.array([p["joints"] for x in lines for p in x["people"] if p["track"] == 1])
    accel = {lag: np.linalg.norm(np.diff(j, 2, axis=0), axis=-1).mean() for lag, j in joints.items()}
    assert accel[8] < 0.5 * accel[0]
    assert main(["reconstruct", *common, "--out", str(tmp_path / "bad"), "--lag-frames", "-1"]) == 2


@pytest.mark.parametrize("bad", [(-1, 30.0, 4.0), (3, 0.0, 4.0), (3, 30.0, -1.0)])
def test_fixed_lag_refuses_bad_settings(bad):
    with pytest.raises(ValueError):
        FixedLag(*bad)
