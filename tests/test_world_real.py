"""The take's world on real footage: the bundled detector output of the shared videos
(``data/sample_keypoints/video_*``: several people, a bystander, a man on a shed roof), through
``mocapdb reconstruct … --floor`` as a new user runs it (nothing else given). Every track file of
at least 1 s must have a human size, lie in front of the camera, and stand on the floor (its
planted lower ankle within 5 cm of it) unless the world says it stands on something."""
import json

import numpy as np
import pytest

from mocapdb.core.skeleton import ANKLE_HEIGHT_M, KEYPOINTS

from .conftest import ROOT, SAMPLE_BVH

VIDEOS = ROOT / "data" / "sample_keypoints"
FLOOR_TOLERANCE_M = 0.05
PLANTED_MPS = 0.2  # a lower ankle slower than this is planted


@pytest.fixture(scope="module")
def sample_db_path(tmp_path_factory):
    """The demo database: every bundled clip (what tools/quickstart.sh builds)."""
    from mocapdb.builder.config import BuildConfig
    from mocapdb.builder.pipeline import build

    out = tmp_path_factory.mktemp("sample_db") / "db"
    build([str(SAMPLE_BVH)], out, BuildConfig(workers=1))
    return out


def _reconstruct(folder, db, out):
    from mocapdb.cli.main import main

    assert main(["reconstruct", str(folder), "--db", str(db), "--out", str(out), "--format", "bvh,csv",
                 "--floor"]) == 0
    return json.loads((out / "world.json").read_text())


def _planted_gap_m(csv_path, fps: float) -> np.ndarray:
    """Per planted frame, the lower ankle's height above the floor (y = 0) less the ankle height
    (metres), from a track's CSV (on the floor: y up)."""
    data = np.loadtxt(csv_path, delimiter=",", skiprows=1)
    joints = data[:, 2:2 + 3 * len(KEYPOINTS)].reshape(len(data), len(KEYPOINTS), 3)   # the face points after
    ankles = joints[:, [KEYPOINTS.index("r_ankle"), KEYPOINTS.index("l_ankle")]]
    lower = ankles[np.arange(len(ankles)), np.argmin(ankles[..., 1], axis=1)]
    speed = np.linalg.norm(np.gradient(lower, axis=0), axis=1) * fps
    return lower[speed < PLANTED_MPS, 1] - ANKLE_HEIGHT_M


@pytest.mark.parametrize("name, fps", [("video_balancing_cam01", 60.0), ("video_sports2d", 30.0)])
def test_every_track_on_real_footage_has_a_human_size_in_front_on_its_floor(name, fps, sample_db_path, tmp_path):
    out = tmp_path / name
    world = _reconstruct(VIDEOS / name, sample_db_path, out)
    checked = 0
    for track in world["tracks"]:
        csv = out / f"track_{track['track']}.csv"
        frames = len(np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2))
        if frames < fps:
            continue
        checked += 1
        assert 0.8 <= track["stature_m"] <= 2.3 and track["in_front"], track
        assert not track["flags"], track
        if track["kind"] == "floor":
            gaps = _planted_gap_m(csv, fps)
            assert len(gaps) and np.median(np.abs(gaps)) <= FLOOR_TOLERANCE_M, (track, np.median(gaps))
        elif track["feet_above_floor_m"] is not None:
            assert track["feet_above_floor_m"] > -FLOOR_TOLERANCE_M, track  # never below it
    assert checked >= 2


def test_the_bystander_does_not_change_the_subjects_size(sample_db_path, tmp_path):
    """The balancing take's video: the subject's size with the bystander's detections and without
    them (the bystander's keypoints removed from every frame) within 5 %; both stand on one floor."""
    import shutil

    with_bystander = _reconstruct(VIDEOS / "video_balancing_cam01", sample_db_path, tmp_path / "both")
    alone_input = tmp_path / "alone_input"
    shutil.copytree(VIDEOS / "video_balancing_cam01", alone_input)
    for path in alone_input.glob("*_keypoints.json"):
        frame = json.loads(path.read_text())
        frame["people"] = [p for p in frame["people"] if np.mean(p["pose_keypoints_2d"][0::3]) > 300.0]
        path.write_text(json.dumps(frame))
    alone = _reconstruct(alone_input, sample_db_path, tmp_path / "alone")
    subject = next(t for t in with_bystander["tracks"] if t["main"])
    assert [t["kind"] for t in with_bystander["tracks"]] == ["floor", "floor"]
    (subject_alone,) = alone["tracks"]
    assert subject["stature_m"] == pytest.approx(subject_alone["stature_m"], rel=0.05)


def test_the_footage_check_passes_real_tracks_and_fails_a_broken_one(sample_db_path, monkeypatch):
    """`eval --world … --videos`: the bundled balancing video's two tracks pass; each of them with
    its root put behind the camera (the failure of issue 27) fails."""
    from mocapdb.core.formats.database_reader import load_database
    from mocapdb.evaluation import real_footage

    db = load_database(sample_db_path)
    check = real_footage.check_footage(db, VIDEOS / "video_balancing_cam01")
    assert [t["ok"] for t in check["tracks"]] == [True, True] and check["passed"] == 2
    assert real_footage.footage_check_line([check]).startswith("PASS")
    original = real_footage._track_check

    def flipped(rec, kind, fps):
        flipped_motion = rec.motion(fps)
        flipped_motion.root_m = -flipped_motion.root_m  # behind the camera
        return original(rec.with_motion(flipped_motion), kind, fps)

    monkeypatch.setattr(real_footage, "_track_check", flipped)
    broken = real_footage.check_footage(db, VIDEOS / "video_balancing_cam01")
    assert not any(t["ok"] or t["in_front"] for t in broken["tracks"])
    assert real_footage.footage_check_line([broken]).startswith("FAIL")
