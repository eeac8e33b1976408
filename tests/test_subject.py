"""The take's subject and --people (runtime/world/subject.py), and the world.json reconstruct writes."""
import json

import numpy as np
import pytest

from mocapdb.core.motion import FrameRecorder
from mocapdb.core.outputs import TrackRecording
from mocapdb.runtime.world.subject import chosen, main_track, parse_people, subject_score


def _track(track: int, centre_x: float, height_px: float, speed_px: float, frames: int = 50) -> TrackRecording:
    """A track whose 14 keypoints fill a box ``height_px`` tall centred at ``centre_x``, moving
    ``speed_px`` a frame to the right."""
    t = np.arange(frames)[:, None]
    x = centre_x + speed_px * t + np.linspace(-0.2, 0.2, 14)[None, :] * height_px
    y = 500.0 + np.linspace(-0.5, 0.5, 14)[None, :] * height_px + 0.0 * t
    keypoints = np.stack([x, y, np.ones_like(x)], axis=-1)
    return TrackRecording(track=track, first_frame=0, frames=FrameRecorder.of(keypoints=keypoints))


def test_the_score_by_hand():
    """A still 400 px box in the middle of a 1000 px image: 50 frames × 400 px × centrality 1 × (1 + 0)."""
    assert subject_score(_track(0, 500.0, 400.0, 0.0), 1000.0) == pytest.approx(50 * 400.0)
    # at the edge: centrality 0.5; moving 4 px a frame: 49 × 4 px = 0.49 box heights of motion
    assert subject_score(_track(0, 0.0, 400.0, 0.0), 1000.0) == pytest.approx(50 * 400.0 * 0.5)
    moving = subject_score(_track(0, 500.0, 400.0, 4.0), 1000.0)
    centrality = 1.0 - 0.5 * np.abs(500.0 + 4.0 * np.arange(50) - 500.0) / 500.0
    assert moving == pytest.approx(np.sum(400.0 * centrality) * (1.0 + 49 * 4.0 / 400.0))


def test_the_subject_is_the_large_central_moving_track_not_the_bystander():
    performer = _track(3, 520.0, 600.0, 3.0)
    bystander = _track(1, 60.0, 300.0, 0.0)        # still, at the edge, further away
    far = _track(2, 500.0, 120.0, 2.0, frames=80)  # longer, but small
    assert main_track([bystander, far, performer], 1000.0) == 3
    assert main_track([], 1000.0) is None


def test_people_choices():
    recs = [_track(t, 500.0, 300.0, 0.0) for t in (0, 4, 7)]
    assert [r.track for r in chosen(recs, "all", 4)] == [0, 4, 7]
    assert [r.track for r in chosen(recs, "main", 4)] == [4]
    assert [r.track for r in chosen(recs, parse_people("7, 0"), 4)] == [0, 7]
    assert parse_people(" MAIN ") == "main"
    for bad in ("", "x", "1,,2", "-1", "main,1"):
        with pytest.raises(ValueError, match="--people"):
            parse_people(bad)


def test_reconstruct_names_the_subject_writes_only_it_with_people_main_and_says_so(small_db_path, tmp_path, capsys):
    from mocapdb.cli.main import main

    from .conftest import SAMPLE_KEYPOINTS

    out = tmp_path / "rec"
    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--fps", "60", "--image-size",
                 "1088x1920", "--focal", "1681", "--out", str(out), "--people", "main", "--keep-static"]) == 0
    world = json.loads((out / "world.json").read_text())
    assert world["format"] == "mocapdb-world" and world["main_track"] == 1  # the balancing person, not the edge
    assert sorted(p.name for p in out.glob("track_*")) == ["track_1.bvh"]
    written = {t["track"]: t["written"] for t in world["tracks"]}
    assert written[1] and not any(w for track, w in written.items() if track != 1)
    lines = capsys.readouterr().out
    assert "track 1 (main):" in lines and "world: camera" in lines
    for track in world["tracks"]:
        assert 0.8 <= track["stature_m"] <= 2.3 and track["in_front"]
    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(tmp_path / "x"),
                 "--people", "main,2"]) == 2


def _recorded(track: int, first: int, frames: int, x0: float, speed_px: float = 4.0) -> TrackRecording:
    """A track as the engine keeps it for the whole take: ``frames`` entries from input frame ``first``,
    its keypoints' box 300 px tall at ``x0 + speed_px * frame``."""
    rec = _track(track, 0.0, 300.0, speed_px, frames=first + frames)
    keypoints = rec.column("keypoints")[first:]
    for k in keypoints:
        k[:, 0] += x0
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (frames, 11, 1)) * (track + 1)
    roots = np.tile([float(track), 0.0, -5.0], (frames, 1))
    columns = FrameRecorder.of(quaternions=quats, root_view_m=roots, scales=np.ones(frames), fit_quaternions=quats,
                               fit_root_view_m=roots, keypoints=keypoints,
                               extremities=np.full((frames, 14, 3), 0.0))
    return TrackRecording(track=track, first_frame=first, frames=columns, first_s=first / 30.0,
                          last_s=(first + frames - 1) / 30.0)


def test_a_person_lost_and_found_again_is_one_track():
    """Track 4 starts 12 frames (0.4 s) after track 1 ends, where track 1's box was heading: joined,
    the 12 frames between holding track 1's last pose with no keypoint; track 7, 600 px away, and
    track 9, overlapping track 1 in time, are not."""
    from mocapdb.runtime.world.subject import join_fragments

    first = _recorded(1, 0, 40, 300.0)
    again = _recorded(4, 52, 30, 300.0)
    elsewhere = _recorded(7, 52, 30, 900.0)
    overlapping = _recorded(9, 30, 30, 300.0)
    tracks, joined = join_fragments([again, elsewhere, first, overlapping], 30.0)
    assert joined == {4: 1}
    assert sorted(t.track for t in tracks) == [1, 7, 9]
    whole = next(t for t in tracks if t.track == 1)
    assert len(whole.quaternions) == len(whole.column("keypoints")) == len(whole.column("fit_root_view_m")) == 82
    np.testing.assert_array_equal(whole.quaternions[45], first.quaternions[-1])   # held over the gap
    np.testing.assert_array_equal(whole.quaternions[60], again.quaternions[8])
    assert not np.any(whole.column("keypoints")[45][:, 2]) and whole.last_s == again.last_s
    assert join_fragments([first, _recorded(4, 52 + 31, 30, 300.0)], 30.0)[1] == {}  # lost for more than 1 s
