"""`mocapdb render` draws what the track files hold (issue 27, item 3): the whole take re-projected
over the input and in 3D on its floor at a scale that shows the people; `--stream` the stream."""
import argparse
import json
import math
import re

import numpy as np
import pytest

from mocapdb.core.skeleton import KEYPOINTS, PELVIS
from mocapdb.render import draw
from mocapdb.render.contact_sheet import contact_sheet
from mocapdb.render.frame_layout import image_camera
from mocapdb.render.results import read_result
from mocapdb.render.tracks import (
    WorldFloor,
    files_frame,
    read_bvh_joints,
    read_csv_joints,
    read_track_files,
    read_world,
)
from mocapdb.render.video import render_result
from tests.conftest import SAMPLE_KEYPOINTS
from tests.test_render import standing_pose

PITCH = math.radians(30.0)
HEIGHT = 1.5            # the camera above the floor, metres
FOCAL, SIZE = 1000.0, (1280, 720)
FRAMES = 40


def floor_to_camera(p: np.ndarray) -> np.ndarray:
    """Floor-frame points (x right, y up, z towards the camera, the origin on the floor under a
    camera HEIGHT up and pitched PITCH down) in the camera-aligned frame, written out by hand:
    view = Rᵀ (p − (0, h, 0)) with R the turn about x taking the floor's normal (0, cos, sin) to +y;
    camera-aligned = view with z negated."""
    c, s = math.cos(PITCH), math.sin(PITCH)
    x, y, z = np.moveaxis(np.asarray(p, dtype=np.float64) - [0.0, HEIGHT, 0.0], -1, 0)
    return np.stack([x, c * y - s * z, -(s * y + c * z)], axis=-1)


def test_the_floor_frame_goes_back_to_the_camera_as_computed_by_hand():
    world = WorldFloor(np.array([0.0, math.cos(PITCH), math.sin(PITCH)]), HEIGHT, None, {})
    foot = np.array([1.0, 0.0, -4.0])   # on the floor, 4 m ahead of the camera's foot point
    view = world.to_view(foot)
    # the optical axis meets the floor 1.5 / tan 30 = 2.6 m ahead: the foot lies above the axis, at
    # 4 cos 30 + 1.5 sin 30 = 4.214 m along it, 4 sin 30 − 1.5 cos 30 = 0.701 m above it
    assert view == pytest.approx([1.0, 0.701, -4.214], abs=1e-3)
    assert floor_to_camera(foot) == pytest.approx(view * [1, 1, -1], abs=1e-12)
    assert world.to_floor(view) == pytest.approx(foot, abs=1e-12)


def write_take(folder, with_world: bool = True, far_frames: int = 2) -> dict[int, np.ndarray]:
    """A hand-built reconstruction: on a floor seen by a camera 1.5 m up, pitched 30° down, the main
    track #1 walking from x = 0.5 to 1.5 m 4 m ahead, a bystander #2 6 m ahead, and a false
    detection #3 60 m away for ``far_frames`` frames. The track files (CSV) hold the floor-frame
    joints, the stream their camera-aligned joints (:func:`floor_to_camera`). Returns the files'
    joints per track."""
    folder.mkdir(parents=True, exist_ok=True)
    xs = np.linspace(0.5, 1.5, FRAMES)
    tracks = {1: np.stack([standing_pose((x, 0.93, -4.0)) for x in xs]),
              2: np.stack([standing_pose((-1.5, 0.93, -6.0))] * FRAMES),
              3: np.stack([standing_pose((30.0, 0.93, -60.0))] * far_frames)}
    header = {"format": "mocapdb-stream", "version": 2, "fps": 30.0, "joints": list(KEYPOINTS), "units": "m",
              "image_size": list(SIZE), "focal_px": FOCAL}
    lines = [json.dumps(header)]
    for t in range(FRAMES):
        people = [{"track": k, "joints": floor_to_camera(j[t]).tolist(), "match": {"distance_2d": 0.2}}
                  for k, j in tracks.items() if t < len(j)]
        lines.append(json.dumps({"frame": t, "time": t / 30, "people": people}))
    (folder / "result.jsonl").write_text("\n".join(lines) + "\n")
    columns = ["frame", "time_s"] + [f"{n}_{a}" for n in KEYPOINTS for a in "xyz"]
    for k, joints in tracks.items():
        rows = [",".join([str(t), f"{t / 30:.6f}"] + [f"{v:.5f}" for v in j.ravel()]) for t, j in enumerate(joints)]
        (folder / f"track_{k}.csv").write_text(",".join(columns) + "\n" + "\n".join(rows) + "\n")
    if with_world:
        facts = {1: (1.62, "floor", 0.0), 2: (1.80, "floor", 0.0), 3: (1.75, "elevated", 1.9)}
        world = {"format": "mocapdb-world", "version": 1, "main_track": 1,
                 "camera": {"height_m": HEIGHT, "pitch_deg": 30.0, "roll_deg": 0.0,
                            "floor_normal_view": [0.0, math.cos(PITCH), math.sin(PITCH)]},
                 "tracks": [{"track": k, "main": k == 1, "stature_m": s, "stature_log_sd": 0.1, "size_from": "floor",
                             "kind": kind, "legs_m": 0.8, "feet_above_floor_m": feet, "flags": []}
                            for k, (s, kind, feet) in facts.items()]}
        (folder / "world.json").write_text(json.dumps(world))
    return tracks


def record_drawing(monkeypatch) -> dict[str, list]:
    """Capture what the render draws: the 3D skeletons (joints, view, label) and the image's (pixels, label)."""
    drawn = {"3d": [], "image": []}
    real_3d, real_px = draw.draw_skeleton_3d, draw.draw_skeleton_px
    monkeypatch.setattr(draw, "draw_skeleton_3d", lambda img, view, joints, colour, label=None, **k: (
        drawn["3d"].append((joints, view, label)), real_3d(img, view, joints, colour, label, **k)))

    def image(img, px, colour, label=None, **k):
        if "width" not in k:   # the 3D panel's skeletons pass their width; the image panel's do not
            drawn["image"].append((px, label))
        return real_px(img, px, colour, label, **k)

    monkeypatch.setattr(draw, "draw_skeleton_px", image)
    return drawn


def test_render_draws_the_track_files_on_their_floor_at_a_scale_that_shows_the_people(tmp_path, monkeypatch):
    tracks = write_take(tmp_path / "rec")
    drawn = record_drawing(monkeypatch)
    notes = []
    summary = render_result(tmp_path / "rec", tmp_path / "frames", view="both", scale=0.25, progress=False,
                            note=notes.append, camera=image_camera(FOCAL, SIZE))
    assert notes == [] and "the track files (on their floor)" in summary.report()
    first = [(j, v, label) for j, v, label in drawn["3d"][:3]]   # frame 0: tracks 1, 2, 3
    by_label = {label.split()[0]: (j, v) for j, v, label in first}
    assert {label for _, _, label in first} == {"#1 main 1.62 m", "#2 1.80 m", "#3 1.75 m"}
    joints, view = by_label["#1"]
    assert joints == pytest.approx(tracks[1][0] * [1, 1, -1], abs=1e-5)   # the file, z away from the camera
    assert np.array_equal(view.basis, np.eye(3)) and view.floor == 0.0
    # the grid holds the main track's path and the bystander, not the detection 60 m away
    inside = lambda p: np.max(np.abs(p[[0, 2]] * [1, -1] - view.centre)) <= view.half_extent  # noqa: E731
    assert all(inside(tracks[1][t, PELVIS]) for t in (0, FRAMES - 1)) and inside(tracks[2][0, PELVIS])
    assert not inside(tracks[3][0, PELVIS]) and view.half_extent < 10.0
    assert 1.9 <= view.top < 3.0   # heads at 1.63 m, room for labels; not the far person, not the camera 5 m off
    # the image: the main track's pelvis where the camera sees it (hand: view y = 1.524, z = 3.739 m)
    px, label = next((px, label) for px, label in drawn["image"] if label.startswith("#1 main"))
    layout_margin = round(0.06 * max(SIZE) * 0.25)
    pelvis = (px[PELVIS] - layout_margin) / 0.25
    x = 0.5
    c, s = math.cos(PITCH), math.sin(PITCH)
    y, z = -0.57 * c + 4 * s, 0.57 * s + 4 * c   # pelvis 0.93 m up: 0.57 m below the camera
    assert pelvis == pytest.approx([640 + FOCAL * x / z, 360 - FOCAL * y / z], abs=0.5)


def test_stream_draws_the_per_frame_stream(tmp_path, monkeypatch):
    write_take(tmp_path / "rec")
    stream = read_result(tmp_path / "rec")
    drawn = record_drawing(monkeypatch)
    summary = render_result(tmp_path / "rec", tmp_path / "frames", scale=0.25, progress=False, stream=True,
                            camera=image_camera(FOCAL, SIZE))
    assert "the per-frame stream" in summary.report()
    joints, view, label = drawn["3d"][0]
    assert label in {"#1", "#2", "#3"}
    assert any(np.allclose(joints, p.joints) for p in stream.frames[0].people)   # camera-aligned, as streamed
    assert all(not label.endswith("m") for _, label in drawn["image"])


def test_without_world_or_files_the_stream_is_drawn_with_a_note(tmp_path, monkeypatch, capsys):
    from mocapdb.cli.main import main

    write_take(tmp_path / "noworld", with_world=False)
    assert main(["render", str(tmp_path / "noworld"), "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    out = capsys.readouterr()
    assert out.err.count("note:") == 1 and "has no world.json" in out.err and "per-frame stream" in out.err
    assert "of the per-frame stream" in out.out
    write_take(tmp_path / "nofiles")
    for path in (tmp_path / "nofiles").glob("track_*.csv"):
        path.unlink()
    notes = []
    render_result(tmp_path / "nofiles", tmp_path / "b", progress=False, note=notes.append)
    assert len(notes) == 1 and "no track files" in notes[0]


def test_files_that_do_not_line_up_with_the_stream_are_not_drawn(tmp_path):
    write_take(tmp_path / "rec")
    world = json.loads((tmp_path / "rec" / "world.json").read_text())
    world["camera"]["floor_normal_view"] = [0.0, 1.0, 0.0]   # a floor the files were not put on
    (tmp_path / "rec" / "world.json").write_text(json.dumps(world))
    stream = read_result(tmp_path / "rec")
    frame, why = files_frame(read_track_files(tmp_path / "rec", stream), read_world(tmp_path / "rec"), stream)
    assert frame is None and "do not line up with the stream" in why


# --------------------------------------------------------------------------- a real reconstruction


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory, small_db_path):
    """The bundled Pose2Sim take reconstructed on the floor (the default) and in the view frame
    (--view-frame; CSV and BVH files on the universal rig, whose every joint the BVH holds exactly)."""
    from mocapdb.cli.main import main

    root = tmp_path_factory.mktemp("files")
    common = [str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--fps", "60", "--image-size", "1088x1920",
              "--focal", "1681", "--format", "csv,bvh",
              "--rig", "universal"]
    assert main(["reconstruct", *common, "--out", str(root / "floor")]) == 0
    assert main(["reconstruct", *common, "--out", str(root / "view"), "--view-frame"]) == 0
    return root / "floor", root / "view"


def test_the_floor_files_go_back_to_the_camera_within_a_millimetre(two_runs):
    floor, view = two_runs
    world = read_world(floor)
    worlds = [json.loads((folder / "world.json").read_text()) for folder in (floor, view)]
    assert [w.pop("files") for w in worlds] == ["floor", "view"]
    pose = {key: worlds[0]["camera"].pop(key) for key in ("position_m", "view_to_files")}
    assert worlds[0] == worlds[1]
    on_floor = read_csv_joints(floor / "track_1.csv")[1]
    in_view = read_csv_joints(view / "track_1.csv")[1]
    assert np.abs(world.to_view(on_floor) - in_view).max() < 1e-3   # world.json's 5 decimals of the normal
    # the camera's pose in world.json takes the view-frame files onto the floor files
    assert np.abs(in_view @ np.array(pose["view_to_files"]).T + pose["position_m"] - on_floor).max() < 1e-3
    assert np.abs(in_view[:, PELVIS, 2]).min() > 1.0                 # not trivially close: metres from the camera
    for folder, expected in ((floor, "floor"), (view, "view")):
        stream = read_result(folder)
        frame, why = files_frame(read_track_files(folder, stream), read_world(folder), stream)
        assert frame == expected, why


def test_the_bvh_gives_the_csv_joints(two_runs):
    floor, _ = two_runs
    frames, csv = read_csv_joints(floor / "track_1.csv")
    bvh = read_bvh_joints(floor / "track_1.bvh")   # padded back to input frame 0: BVH frame k is input frame k
    assert frames[0] == 0 and len(bvh) == frames[-1] + 1
    assert np.abs(bvh[frames] - csv).max() < 1e-4
    (floor / "track_1.csv").rename(floor / "track_1.csv.away")
    try:
        from_bvh = read_track_files(floor, read_result(floor))
    finally:
        (floor / "track_1.csv.away").rename(floor / "track_1.csv")
    assert [t.track for t in from_bvh] == [1]
    assert np.array_equal(from_bvh[0].frames, frames) and np.abs(from_bvh[0].joints - csv).max() < 1e-4


def test_in_the_view_frame_the_3d_view_still_stands_the_files_on_the_take_floor(two_runs, tmp_path, monkeypatch):
    """reconstruct --view-frame writes view-frame files; the picture puts them on world.json's
    floor, where the default run's own files (exports.on_floor) stand."""
    floor, view = two_runs
    drawn = record_drawing(monkeypatch)
    contact_sheet(view, SAMPLE_KEYPOINTS, tmp_path / "sheet.png", n=3, focal=1681, image_size=(1088, 1920),
                  tile_height=200)
    frames, on_floor = read_csv_joints(floor / "track_1.csv")
    picked = np.round(np.linspace(0, 99, 3)).astype(int)
    assert len(drawn["3d"]) == 3
    for index, (joints, view3d, label) in zip(picked, drawn["3d"]):
        assert label.startswith("#1 main")
        assert np.abs(joints - on_floor[index] * [1, 1, -1]).max() < 1e-3


def test_cli_draws_the_files_and_with_stream_the_stream(two_runs, tmp_path, capsys, monkeypatch):
    from mocapdb.cli.render import add_render_parser

    floor, _ = two_runs
    stature = read_world(floor).tracks[1]["stature_m"]
    top = argparse.ArgumentParser(prog="mocapdb")
    add_render_parser(top.add_subparsers(dest="command"))
    labels = {}
    for extra in ([], ["--stream"]):
        drawn = record_drawing(monkeypatch)
        args = top.parse_args(["render", str(floor), "--keypoints", str(SAMPLE_KEYPOINTS), "--contact-sheet", "2",
                               "--out", str(tmp_path / f"sheet{len(extra)}.png"), *extra])
        assert args.run(args) == 0 and capsys.readouterr().err == ""
        labels[bool(extra)] = {label for _, _, label in drawn["3d"]}
    assert labels[False] == {f"#1 main {stature:.2f} m"}      # the track file, sized by the world
    assert "#1" in labels[True] and all(re.fullmatch(r"#\d+", label) for label in labels[True])


def test_bvh_parts_are_placed_on_the_input_frames():
    """BVH has no frame numbers: a padded file (--bvh-start input) starts at input frame 0, an
    unpadded one ends on the track's last frame in the stream, parts back to back; a frame two
    padded parts hold is the earlier part's."""
    from mocapdb.render.tracks import _bvh_frames, _merge

    assert [f.tolist() for f in _bvh_frames([10], 9)] == [list(range(10))]           # padded
    assert [f.tolist() for f in _bvh_frames([5], 9)] == [[5, 6, 7, 8, 9]]           # the track's own frames
    assert [f.tolist() for f in _bvh_frames([4, 3], 9)] == [[3, 4, 5, 6], [7, 8, 9]]
    padded = _bvh_frames([7, 10], 9)
    frames, joints = _merge(padded, [np.full((7, 1), 1.0), np.full((10, 1), 2.0)])
    assert frames.tolist() == list(range(10)) and joints[:, 0].tolist() == [1.0] * 7 + [2.0] * 3
