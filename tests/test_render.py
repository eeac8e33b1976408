"""mocapdb render: projection, drawing, frames/MP4/contact sheet of a small reconstruction, the stereo plot, errors."""
import argparse
import json
import shutil

import cv2
import numpy as np
import pytest

from mocapdb.core.errors import MocapdbError
from mocapdb.core.skeleton import DRAWING_LINES, KEYPOINTS, N_POINTS
from mocapdb.render import draw
from mocapdb.render.contact_sheet import contact_sheet
from mocapdb.render.frame_layout import Layout, image_camera
from mocapdb.render.results import RenderError, read_result
from mocapdb.render.stereo_plot import render_stereo_plot
from mocapdb.render.video import render_result
from tests.conftest import SAMPLE_KEYPOINTS

FOCAL, SIZE = 1681.0, (1088, 1920)
N_FRAMES = 8


def run_cli(argv: list[str]) -> int:
    """``mocapdb render ARGV`` through its own parser (as cli/main.py would run it)."""
    from mocapdb.cli.render import add_render_parser

    top = argparse.ArgumentParser(prog="mocapdb")
    sub = top.add_subparsers(dest="command", required=True)
    add_render_parser(sub)
    args = top.parse_args(["render", *argv])
    return args.run(args)


def standing_pose(root=(0.0, 0.0, 4.0)) -> np.ndarray:
    """A rough upright skeleton [15, 3], camera-aligned frame, pelvis at ``root``."""
    offsets = {"head": (0, 0.7, 0.05), "neck": (0, 0.52, 0), "r_shoulder": (-0.19, 0.52, 0),
               "r_elbow": (-0.22, 0.24, 0), "r_wrist": (-0.24, -0.02, 0), "l_shoulder": (0.19, 0.52, 0),
               "l_elbow": (0.22, 0.24, 0), "l_wrist": (0.24, -0.02, 0), "r_hip": (-0.1, 0, 0),
               "r_knee": (-0.1, -0.43, 0), "r_ankle": (-0.1, -0.85, 0), "l_hip": (0.1, 0, 0),
               "l_knee": (0.1, -0.43, 0), "l_ankle": (0.1, -0.85, 0), "pelvis": (0, 0, 0)}
    return np.array([offsets[k] for k in KEYPOINTS], dtype=np.float64) + np.asarray(root)


def write_stream(folder, frames: int, poses=None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    header = {"format": "mocapdb-stream", "version": 2, "fps": 60.0, "joints": list(KEYPOINTS), "units": "m"}
    lines = [json.dumps(header)]
    for t in range(frames):
        people = [{"track": k, "joints": p.tolist(), "root": p[-1].tolist(), "height": 1.75}
                  for k, p in enumerate(poses if poses is not None else [standing_pose()])]
        lines.append(json.dumps({"frame": t, "time": t / 60, "people": people}))
    (folder / "result.jsonl").write_text("\n".join(lines) + "\n")


# --------------------------------------------------------------------------- projection and drawing


def test_projection_by_hand():
    px = draw.project_pinhole(np.array([[0.5, 0.2, 2.0], [0.0, 0.0, -1.0]]), 1000.0, (960.0, 540.0))
    assert px[0] == pytest.approx([960 + 1000 * 0.5 / 2, 540 - 1000 * 0.2 / 2])   # 1210, 440: y up → v smaller
    assert np.all(np.isnan(px[1]))                                                 # behind the camera


def test_drawing_puts_the_track_colour_at_the_joints():
    img = np.zeros((1200, 900, 3), np.uint8)   # lines 3 px wide: their middle is the exact colour
    px = draw.project_pinhole(standing_pose(), 900.0, (450.0, 600.0))
    colour = draw.track_colour(3)
    draw.draw_skeleton_px(img, px, colour, "#3")
    for i in range(N_POINTS):
        u, v = np.round(px[i]).astype(int)
        assert tuple(img[v, u]) == colour, KEYPOINTS[i]
    a, b = DRAWING_LINES[2]
    mid = np.round((px[a] + px[b]) / 2).astype(int)
    assert tuple(img[mid[1], mid[0]]) == colour   # bones are drawn too
    assert draw.track_colour(0) != draw.track_colour(1)


def test_label_flags_the_image_edge_and_poor_matches():
    assert draw.track_label(2) == "#2"
    assert "poor match" in draw.track_label(2, distance_2d=2.5)
    assert draw.at_image_edge(np.array([[3.0, 500.0]]), (1088, 1920))
    assert not draw.at_image_edge(np.array([[500.0, 500.0], [np.nan, np.nan]]), (1088, 1920))


def test_3d_view_keeps_the_floor_below_the_feet():
    poses = np.stack([standing_pose((x, 0.0, 4.0 + x)) for x in np.linspace(-1, 1, 5)])
    view = draw.fit_view(poses)
    assert view.floor == pytest.approx(-0.85 - 0.08, abs=1e-6)
    px, depth = view.project(poses[0], (400, 400))
    assert np.all((px >= 0) & (px <= 400))
    img = np.zeros((400, 400, 3), np.uint8)
    draw.draw_floor(img, view)
    draw.draw_skeleton_3d(img, view, poses[0], draw.track_colour(1), "#1")
    u, v = np.round(px[-1]).astype(int)
    assert tuple(img[v, u]) == draw.track_colour(1)


# --------------------------------------------------------------------------- a small reconstruction


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory, small_db_path):
    """The first frames of the bundled sample, reconstructed with `mocapdb reconstruct`."""
    from mocapdb.cli.main import main

    root = tmp_path_factory.mktemp("render")
    keypoints = root / "keypoints"
    keypoints.mkdir()
    for path in sorted(SAMPLE_KEYPOINTS.glob("*.json"))[:N_FRAMES]:
        shutil.copy(path, keypoints / path.name)
    code = main(["reconstruct", str(keypoints), "--db", str(small_db_path), "--out", str(root / "recon"),
                 "--fps", "60", "--image-size", "1088x1920", "--focal", "1681"])
    assert code == 0
    return root, keypoints, root / "recon"


def test_png_frames(sample_run, capsys):
    root, keypoints, recon = sample_run
    out = root / "frames"
    (out).mkdir()
    (out / "frame_000999.png").write_bytes(b"stale")   # an earlier render's frame is removed
    code = run_cli([str(recon), "--keypoints", str(keypoints), "--out", str(out), "--focal", "1681",
                    "--image-size", "1088x1920", "--scale", "0.25", "--no-progress"])
    assert code == 0
    names = sorted(p.name for p in out.glob("*.png"))
    assert names == [f"frame_{i:06d}.png" for i in range(N_FRAMES)]
    assert not list(out.glob(".*"))   # no temporary file left
    img = cv2.imread(str(out / names[-1]))
    layout = Layout(image_camera(FOCAL, SIZE), "both", draw.fit_view(read_result(recon).all_joints()), 0.25)
    assert img.shape[1::-1] == layout.size
    tracks = read_result(recon).frames[-1].people
    assert tracks, "the sample has people by its last frames"
    for colour in {draw.track_colour(p.track) for p in tracks}:
        assert np.any(np.all(img == colour, axis=2)), colour
    assert f"rendered {N_FRAMES} frame(s)" in capsys.readouterr().out


def test_mp4(sample_run):
    root, keypoints, recon = sample_run
    summary = render_result(recon, root / "out.mp4", keypoints, mp4=True, camera=image_camera(FOCAL, SIZE), scale=0.25,
                            view="image", progress=False)
    assert summary.out == root / "out.mp4" and summary.frames == N_FRAMES
    cap = cv2.VideoCapture(str(summary.out))
    count = 0
    while cap.read()[0]:
        count += 1
    cap.release()
    assert count == N_FRAMES


def test_video_frames_are_drawn_under_the_skeletons(sample_run):
    root, keypoints, recon = sample_run
    video = root / "input.mp4"   # the input video: a flat green picture per frame, 1088×1920 like the take's
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 60.0, SIZE)
    for _ in range(N_FRAMES):
        writer.write(np.full((SIZE[1], SIZE[0], 3), (40, 160, 40), np.uint8))
    writer.release()
    out = root / "over_video"
    summary = render_result(recon, out, keypoints, video=video, camera=image_camera(FOCAL, SIZE), scale=0.25,
                            view="image", progress=False)
    assert summary.frames == N_FRAMES
    img = cv2.imread(str(out / f"frame_{N_FRAMES - 1:06d}.png")).astype(int)
    green = np.abs(img - [40, 160, 40]).max(axis=2) <= 12   # mp4v is lossy
    assert green.mean() > 0.3   # the video fills the image panel
    tracks = read_result(recon).frames[-1].people
    assert any(np.any(np.all(img == draw.track_colour(p.track), axis=2)) for p in tracks)  # skeletons on top


def test_contact_sheet(sample_run):
    root, keypoints, recon = sample_run
    out = contact_sheet(recon, keypoints, root / "sheet.png", n=4, focal=FOCAL, image_size=SIZE, tile_height=300)
    img = cv2.imread(str(out))
    scale = 300 / (SIZE[1] * 1.12)
    tile = Layout(image_camera(FOCAL, SIZE), "both", draw.fit_view(read_result(recon).all_joints()), scale).size
    cols = img.shape[1] // tile[0]
    assert cols * tile[0] + (cols - 1) * 4 == img.shape[1]
    rows = -(-4 // cols)
    assert img.shape[0] == max(30, tile[1] // 12) + rows * (tile[1] + 4)
    with pytest.raises(RenderError, match="at least 1 frame"):
        contact_sheet(recon, keypoints, root / "none.png", n=0)


def test_frame_count_mismatch_renders_the_overlap(tmp_path, sample_run):
    _, keypoints, _ = sample_run
    write_stream(tmp_path / "res", N_FRAMES + 5)
    warnings = []
    summary = render_result(tmp_path / "res", tmp_path / "frames", keypoints, camera=image_camera(FOCAL, SIZE),
                            scale=0.1, progress=False, warn=warnings.append)
    assert summary.frames == N_FRAMES
    assert len(list((tmp_path / "frames").glob("frame_*.png"))) == N_FRAMES
    assert any("drawing the 8 frame(s) in both" in w for w in warnings)


# --------------------------------------------------------------------------- stereo


def test_stereo_camera_plot(tmp_path):
    folder = tmp_path / "stereo"
    write_stream(folder, 5, [standing_pose((0.0, 0.0, 4.0))])
    k = [[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]]
    turn = np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])   # camera 2 on camera 1's right, looking at the person
    centre2 = np.array([4.0, 0.0, 4.0])
    cameras = {"frame": "camera 1 (OpenCV)", "baseline_m": float(np.linalg.norm(centre2)), "rotation_deg": 90.0,
               "cameras": [{"name": "left", "size": [1280, 720], "K": k, "dist": [0, 0, 0, 0],
                            "R": np.eye(3).tolist(), "t": [0, 0, 0]},
                           {"name": "right", "size": [1280, 720], "K": k, "dist": [0, 0, 0, 0],
                            "R": turn.tolist(), "t": (-turn @ centre2).tolist()}],
               "bvh_from_camera1": np.diag([1.0, -1.0, -1.0]).tolist()}
    (folder / "cameras.json").write_text(json.dumps(cameras))
    out = render_stereo_plot(folder, tmp_path / "plot.png", panel=400)
    img = cv2.imread(str(out))
    assert img.shape == (450, 804, 3)
    assert np.any(np.all(img == draw.track_colour(0), axis=2))
    assert run_cli([str(folder), "--out", str(tmp_path / "cli.png")]) == 0
    assert (tmp_path / "cli.png").is_file()
    with pytest.raises(MocapdbError, match="give --out NAME.png"):
        run_cli([str(folder), "--out", str(tmp_path / "frames")])


# --------------------------------------------------------------------------- errors


def test_error_messages(tmp_path, capsys):
    from mocapdb.cli.main import main

    with pytest.raises(RenderError, match="no result.jsonl in this folder"):
        read_result(tmp_path)
    with pytest.raises(RenderError, match="no such result folder"):
        read_result(tmp_path / "missing")
    (tmp_path / "result.jsonl").write_text('{"frame": 0, "people": []}\n')
    with pytest.raises(RenderError, match="not a mocapdb stream header"):
        read_result(tmp_path)
    (tmp_path / "result.jsonl").write_text('{"format": "mocapdb-stream", "version": 99}\n')
    with pytest.raises(RenderError, match="stream version 99"):
        read_result(tmp_path)
    (tmp_path / "result.jsonl").write_text('{"format": "mocapdb-stream", "version": 1}\n{"frame": 0, "peo\n')
    with pytest.raises(RenderError, match="line 2: not JSON"):
        read_result(tmp_path)
    (tmp_path / "result.jsonl").write_text('{"format": "mocapdb-stream", "version": 1}\n'
                                           '{"frame": 0, "people": [{"track": 0, "joints": [[0, 0, 1]]}]}\n')
    with pytest.raises(RenderError, match=r"shape \[1, 3\], not \[15, 3\]"):
        read_result(tmp_path)
    write_stream(tmp_path / "ok", 3)
    with pytest.raises(RenderError, match="no such keypoint folder or file"):
        render_result(tmp_path / "ok", tmp_path / "f", tmp_path / "nokeypoints", progress=False)
    with pytest.raises(RenderError, match="no such video file"):
        render_result(tmp_path / "ok", tmp_path / "f", video=tmp_path / "none.mp4", progress=False)
    with pytest.raises(RenderError, match="focal length"):
        image_camera(-5.0, (100, 100))
    assert main(["render", str(tmp_path / "ok"), "--out", str(tmp_path / "f"), "--image-size", "big"]) == 2
    assert "argument --image-size: 'big': must be WIDTHxHEIGHT" in capsys.readouterr().err
    with pytest.raises(RenderError, match="no cameras.json"):
        render_stereo_plot(tmp_path / "ok", tmp_path / "p.png")


def test_render_takes_the_camera_the_run_recorded(sample_run, capsys):
    """reconstruct recorded focal and image size in its header: render needs neither again (the same
    picture as with them given) and refuses a focal that contradicts it, naming both."""
    root, keypoints, recon = sample_run
    given, read = root / "given.png", root / "read.png"
    common = [str(recon), "--keypoints", str(keypoints), "--contact-sheet", "2", "--no-progress"]
    assert run_cli([*common, "--out", str(given), "--focal", "1681", "--image-size", "1088x1920"]) == 0
    assert run_cli([*common, "--out", str(read)]) == 0
    assert "no --focal" not in capsys.readouterr().err
    assert np.array_equal(cv2.imread(str(given)), cv2.imread(str(read)))
    from mocapdb.cli.main import main

    assert main(["render", *common, "--out", str(root / "bad.png"), "--focal", "1000"]) == 2
    err = capsys.readouterr().err
    assert "--focal 1000 contradicts the header of" in err and "1681" in err


def test_the_preview_title_names_the_output_not_the_temporary_folder(small_db_path, tmp_path, monkeypatch):
    from mocapdb.cli.main import main
    from mocapdb.render import draw

    texts = []
    real = draw.put_text
    monkeypatch.setattr(draw, "put_text", lambda img, text, *a, **k: (texts.append(text),
                                                                                    real(img, text, *a, **k)))
    out = tmp_path / "rec"
    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(out), "--fps", "60",
                 "--image-size", "1088x1920", "--focal", "1681", "--preview"]) == 0
    title = next(t for t in texts if "frames" in t and "focal" in t)
    assert title.startswith(f"{out / 'result.jsonl'}:") and ".tmp" not in title


def test_the_preview_with_floor_draws_the_track_files_on_their_floor(small_db_path, tmp_path, monkeypatch):
    # --floor puts the track files on the floor found (levelled, y = 0, the origin under the camera);
    # the preview's 3D view drew the camera-aligned stream whatever --floor said.
    from mocapdb.cli.main import main
    from mocapdb.render import draw

    drawn = []
    real = draw.draw_skeleton_3d
    monkeypatch.setattr(draw, "draw_skeleton_3d", lambda img, view, joints, *a, **k: (
        drawn.append((joints, view)), real(img, view, joints, *a, **k)))
    out = tmp_path / "rec"
    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--out", str(out), "--fps", "60",
                 "--image-size", "1088x1920", "--focal", "1681", "--floor", "--format", "csv", "--preview"]) == 0
    rows = np.loadtxt(out / "track_1.csv", delimiter=",", skiprows=1)  # the one track file (track 0 is static)
    # drawn in camera axes; the face's points after the joints
    on_floor = {int(r[0]): r[2:2 + 3 * N_POINTS].reshape(N_POINTS, 3) * [1.0, 1.0, -1.0] for r in rows}
    tiles = np.round(np.linspace(0, 99, 12)).astype(int)  # the sheet's 12 frames of 100
    assert len(drawn) == len(tiles)  # one person a tile, frame 0 included; not the static one
    for frame, (joints, view) in zip(tiles, drawn):
        np.testing.assert_allclose(joints, on_floor[frame], atol=1e-5)  # the CSV's 5 decimals
        assert np.array_equal(view.basis, np.eye(3)) and abs(view.floor) < 0.01  # the grid: that floor, level


# --------------------------------------------------------------------------- outputs and far positions (issue 20)


def test_render_replaces_its_own_outputs_and_refuses_anything_else(tmp_path, capsys):
    """PNG frames: a folder swapped in whole (an earlier render's frames replaced, a folder holding
    anything else refused naming it); an .mp4 or .png file: replaced only when it is one. Refusals
    come before any drawing and leave everything as it was."""
    from mocapdb.cli.main import main

    write_stream(tmp_path / "run", 3)
    common = [str(tmp_path / "run"), "--scale", "0.1", "--no-progress"]
    frames = tmp_path / "frames"
    assert main(["render", *common, "--out", str(frames)]) == 0
    (frames / "frame_000099.png").write_bytes(b"stale")
    assert main(["render", *common, "--out", str(frames)]) == 0
    assert sorted(p.name for p in frames.iterdir()) == [f"frame_{i:06d}.png" for i in range(3)]
    assert main(["render", *common, "--mp4", "--out", str(tmp_path / "a.mp4")]) == 0
    assert main(["render", *common, "--mp4", "--out", str(tmp_path / "a.mp4")]) == 0   # its own video: replaced
    assert main(["render", *common, "--contact-sheet", "2", "--out", str(tmp_path / "sheet.png")]) == 0
    assert main(["render", *common, "--contact-sheet", "2", "--out", str(tmp_path / "sheet.png")]) == 0
    capsys.readouterr()
    (frames / "notes.txt").write_text("mine")
    (tmp_path / "notes.mp4").write_text("my notes")
    (tmp_path / "notes.png").write_text("my notes")
    cases = [(["--out", str(frames)], "is not an output folder of `mocapdb render`: it holds notes.txt"),
             (["--mp4", "--out", str(tmp_path / "notes.mp4")], "exists and is not an MP4 video"),
             (["--contact-sheet", "2", "--out", str(tmp_path / "notes.png")], "exists and is not a PNG picture")]
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    for argv, message in cases:
        assert main(["render", *common, *argv]) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("mocapdb render: error: ") and err.count("\n") == 1 and message in err, err
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before
    assert not list(tmp_path.glob(".*"))   # no temporary file or folder left


def test_a_far_person_is_refused_and_the_floor_grid_stays_bounded(tmp_path, capsys, monkeypatch):
    """A person 1e9 m away once drew ~10 million grid lines (3.5 GB): a joint beyond 10 km is refused
    naming the file and line; within it, and for any extent, the grid has at most 13 lines each way."""
    from mocapdb.cli.main import main

    write_stream(tmp_path / "far", 2, [standing_pose(), standing_pose((1e9, 0.0, 4.0))])
    assert main(["render", str(tmp_path / "far"), "--out", str(tmp_path / "frames"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "result.jsonl, line 2: person 1 (track 1) has a joint 1e+09 m" in err, err
    assert "beyond 10,000 m" in err and not (tmp_path / "frames").exists()
    for half in (1.2, 60.0, 5e8, 1e300):
        assert 2 * half / draw.grid_step(half) <= draw.GRID_LINES
    lines = []
    monkeypatch.setattr(draw.cv2, "line", lambda img, a, b, *args: lines.append((a, b)))
    poses = np.stack([standing_pose(), standing_pose((9000.0, 0.0, 4.0))])   # 9 km apart: still drawn
    draw.draw_floor(np.zeros((400, 400, 3), np.uint8), draw.fit_view(poses))
    assert 2 < len(lines) <= 2 * (draw.GRID_LINES + 1)
