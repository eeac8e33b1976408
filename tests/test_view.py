"""`mocapdb view` and `live --view` (issue 38): the page in a real browser (Debian's Chromium, headless,
through Playwright), the server's limits, the live sink that never waits for a page."""
from __future__ import annotations

import fnmatch
import hashlib
import importlib.util
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import tomllib
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from mocapdb.core.formats.keypoints import Person
from mocapdb.core.outputs import PersonPose
from mocapdb.core.skeleton import KP
from mocapdb.render.tracks import read_csv_joints
from mocapdb.runtime.stream.sinks import FileSink, TeeSink
from mocapdb.view import payload
from mocapdb.view.live import QUEUE_FRAMES, LiveFeed, PageSink
from mocapdb.view.server import ViewServer
from mocapdb.view.take import open_take
from tests.conftest import ROOT, SAMPLE_KEYPOINTS, skip_missing

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
STATIC = ROOT / "mocapdb" / "view" / "static"
THREE = ROOT / "mocapdb" / "view" / "vendor" / "three"
SAMPLE = ["--fps", "60", "--image-size", "1088x1920", "--focal", "1681"]
FRAME_K = 57
HAND_STEP_PX = 25.0   # the test's hand: each finger's points this far apart, fanned out upwards from the wrist
RIGHT_HAND_RGB = (0x00, 0xe5, 0xff)   # viewer.js HAND_COLOURS[0]


@pytest.fixture(scope="module")
def take_folder(tmp_path_factory, small_db_path) -> Path:
    """The bundled Pose2Sim take reconstructed with the small database (CSV and BVH track files)."""
    from mocapdb.cli.main import main

    out = tmp_path_factory.mktemp("view") / "take"
    assert main(["reconstruct", str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), *SAMPLE, "--format", "csv,bvh",
                 "--out", str(out)]) == 0
    return out


def fanned_hand(wrist_px: np.ndarray) -> np.ndarray:
    """A hand ``[21, 4]`` (x, y, z px, confidence): five straight fingers fanned upwards from ``wrist_px``."""
    hand = np.zeros((21, 4))
    hand[:, 3] = 0.9
    hand[0, :2] = wrist_px
    for finger in range(5):
        angle = -np.pi / 2 + (finger - 2) * 0.3
        for k in range(1, 5):
            hand[1 + 4 * finger + k - 1, :2] = wrist_px + k * HAND_STEP_PX * np.array([np.cos(angle), np.sin(angle)])
    return hand


@pytest.fixture(scope="module")
def hands_keypoints(tmp_path_factory) -> tuple[Path, np.ndarray]:
    """The bundled keypoints with a right hand (:func:`fanned_hand`) added to the first person of frame
    :data:`FRAME_K` at their right wrist (OpenPose's hand field), and that hand."""
    folder = shutil.copytree(SAMPLE_KEYPOINTS, tmp_path_factory.mktemp("hands") / "keypoints")
    path = folder / f"cam01.{FRAME_K:04d}.json"
    frame = json.loads(path.read_text())
    body = np.array(frame["people"][0]["pose_keypoints_2d"]).reshape(-1, 3)
    hand = fanned_hand(body[4, :2])   # BODY_25's RWrist
    frame["people"][0]["hand_right_keypoints_2d"] = hand[:, [0, 1, 3]].ravel().tolist()
    path.write_text(json.dumps(frame))
    return folder, hand


@pytest.fixture(scope="module")
def browser():
    """Headless Chromium from Debian's packages (never a browser Playwright would download)."""
    if CHROMIUM is None:
        skip_missing("chromium on PATH (apt-get install chromium): the page is not tested in a browser")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")
    with sync_api.sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, args=["--enable-unsafe-swiftshader"])
        yield chromium
        chromium.close()


def open_page(browser, url: str):
    """A page at ``url`` and the list its console errors and uncaught exceptions go to."""
    page = browser.new_page(viewport={"width": 1400, "height": 800})
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    return page, errors


def page_address(process: subprocess.Popen) -> re.Match:
    """The page's address a command prints on stderr (after any warnings)."""
    lines = []
    while len(lines) < 20 and (line := process.stderr.readline()):
        lines.append(line)
        if match := re.search(r"the page is at (http://127\.0\.0\.1:\d+/)", line):
            return match
    raise AssertionError("".join(lines))


def variance_of(png: bytes) -> float:
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
    return float(img.astype(np.float64).var())


def test_three_js_is_vendored_as_pinned_and_installed_with_the_package():
    sums = (THREE / "SHA256SUMS").read_text().splitlines()
    for line in sums:
        digest, name = line.split()
        assert hashlib.sha256((THREE / name).read_bytes()).hexdigest() == digest, name
    doc = (ROOT / "data_specs" / "viewer.md").read_text()
    assert all(line.split()[0] in doc for line in sums)
    page = (STATIC / "index.html").read_text() + (STATIC / "viewer.js").read_text()
    assert not re.search(r"https?://", page), "the page fetches nothing from elsewhere"
    assert '"three": "/vendor/three/three.module.js"' in page
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    globs = setuptools["package-data"]["mocapdb.view.vendor.three"]
    shipped = [p.name for p in THREE.iterdir()]
    assert "mocapdb.view.vendor.three" in setuptools["packages"]
    assert len(shipped) == 5 and all(any(fnmatch.fnmatch(f, glob) for glob in globs) for f in shipped), (shipped, globs)
    assert not list(STATIC.rglob("three*")), "three.js lives in vendor/, not among the page's own files"


def test_the_vendoring_tools_check_finds_a_changed_file(tmp_path):
    run = subprocess.run([sys.executable, str(ROOT / "tools" / "vendor_three.py"), "--check"], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 0 and "all files match" in run.stdout, run.stdout + run.stderr
    spec = importlib.util.spec_from_file_location("vendor_three", ROOT / "tools" / "vendor_three.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    assert tool.DEST == THREE
    copy = shutil.copytree(THREE, tmp_path / "three")
    assert tool.check(copy) == []
    (copy / "OrbitControls.js").write_text((copy / "OrbitControls.js").read_text() + "// changed\n")
    (copy / "LICENSE").unlink()
    assert tool.check(copy) == ["OrbitControls.js", "LICENSE"]


def test_the_page_shows_the_take_and_the_track_files_joints(browser, take_folder, tmp_path):
    world = json.loads((take_folder / "world.json").read_text())
    main_track = world["main_track"]
    frames, joints = read_csv_joints(take_folder / f"track_{main_track}.csv")
    server = ViewServer(0, take=open_take(take_folder, SAMPLE_KEYPOINTS), folder=take_folder)
    try:
        start = time.perf_counter()
        page, errors = open_page(browser, server.url)
        page.wait_for_function("window.mocapdbViewer && window.mocapdbViewer.ready === true", timeout=30_000)
        load_s = time.perf_counter() - start
        canvas = page.locator("#scene canvas").screenshot()
        assert variance_of(canvas) > 20, "the 3D view is blank"
        assert variance_of(page.locator("#image").screenshot()) > 20, "the image panel is blank"
        # scrub to frame k with the slider, as a user drags it
        page.evaluate(f"""() => {{ const s = document.getElementById('scrub');
                                   s.value = {FRAME_K}; s.dispatchEvent(new Event('input')); }}""")
        page.wait_for_function(f"window.mocapdbViewer.frame() === {FRAME_K}")
        drawn = np.array(page.evaluate(f"window.mocapdbViewer.pose({main_track})"), dtype=np.float64)
        expected = joints[list(frames).index(FRAME_K)]
        assert np.abs(drawn - expected).max() < 1e-3, "the 3D view does not draw the track file's joints"
        assert f"frame {FRAME_K}" in page.text_content("#frame-label")
        assert page.text_content("#tracks").count("m ±") >= 1   # each person's stature ± its spread
        page.screenshot(path=str(tmp_path / "take.png"))
        # hide the person: nothing drawn for it
        page.locator(f"#tracks input[data-track='{main_track}']").uncheck()
        assert page.evaluate(f"window.mocapdbViewer.pose({main_track})") is None
        page.locator(f"#tracks input[data-track='{main_track}']").check()
        # play from the start at the take's rate
        page.evaluate("window.mocapdbViewer.seek(0)")
        page.click("#play")
        time.sleep(1.0)
        stats = page.evaluate("window.mocapdbViewer.stats()")
        links = page.eval_on_selector_all("#files a", "as => as.map(a => a.textContent)")
        assert {"world.json", f"track_{main_track}.bvh", f"track_{main_track}.csv"} <= set(links)
        with urllib.request.urlopen(server.url + "files/world.json") as answer:
            assert json.loads(answer.read())["main_track"] == main_track
        assert not errors, errors
        print(f"\nview: page ready in {load_s * 1000:.0f} ms (the page's own clock: {stats['loadMs']:.0f} ms); "
              f"played {stats['playFrames']} frames in {stats['playSeconds']:.2f} s: {stats['playFps']:.1f} "
              f"frames/s (the take: 60)")
        assert stats["playFps"] > 5
    finally:
        server.close()


def test_the_payload_carries_a_persons_hands_only_where_the_keypoints_have_them():
    hand = fanned_hand(np.array([100.0, 200.0]))
    hand[20, 3] = 0.1                                  # the pinky's tip below the threshold: not drawn
    with_hands = Person(np.zeros((14, 2)), np.ones(14), hands=np.stack([hand, np.zeros((21, 4))]))
    without = Person(np.zeros((14, 2)), np.ones(14))
    hands = payload.input_hands([without, with_hands])
    assert hands[0] is None and hands[1][1] is None    # no hands; an absent left hand
    right = hands[1][0]
    assert right[0] == [100.0, 200.0] and right[20] == [None, None]
    assert right[12] == [100.0, 200.0 - 4 * HAND_STEP_PX]   # the middle finger's tip, straight up
    assert payload.input_hands([without]) is None and payload.input_hands([np.zeros((14, 3))]) is None
    lines = payload.skeleton()["hand_lines"]
    assert len(lines) == 20 and [0, 1] in lines and [3, 4] in lines and [0, 17] in lines and [19, 20] in lines


def _turn(axis: int, deg: float) -> list[float]:
    q = [np.cos(np.radians(deg) / 2), 0.0, 0.0, 0.0]
    q[1 + axis] = np.sin(np.radians(deg) / 2)
    return q


def test_the_face_and_hands_directions_compose_the_chain_to_the_neck_with_the_head():
    rest = np.tile([1.0, 0.0, 0.0, 0.0], (11, 1))
    ends = np.tile([1.0, 0.0, 0.0, 0.0], (5, 1))
    ends[4] = _turn(0, 30)                     # the head pitched 30 deg about x (down: the face's z towards -y)
    pitched = [0.0, -0.5, np.sqrt(3) / 2]
    assert payload.end_directions(rest, ends, np.eye(3))["face"] == pytest.approx(pitched, abs=1e-4)
    neck = rest.copy()
    neck[6] = _turn(1, 90)                     # the neck (rotations row 6) turned 90 deg about y: x → -z, z → x
    out = payload.end_directions(neck, ends, np.eye(3))
    assert out["face"] == pytest.approx([np.sqrt(3) / 2, -0.5, 0.0], abs=1e-4)   # neck, then head: Ry(90) Rx(30) z
    assert out["hands"] == [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]                    # the arms do not hang from the neck
    pelvis = rest.copy()
    pelvis[0] = _turn(1, 90)                   # the whole body turned: its hands too
    behind = payload.scene_from_view([[-1, 0, 0], [0, -1, 0], [0, 0, 1]])   # a camera turned 180 deg about y
    assert behind == pytest.approx(np.diag([-1.0, 1.0, -1.0]))
    out = payload.end_directions(pelvis, ends, behind)
    assert out["face"] == pytest.approx([-np.sqrt(3) / 2, -0.5, 0.0], abs=1e-4)
    assert np.array(out["hands"]) == pytest.approx(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]), abs=1e-4)


def _chest_forward(joints: np.ndarray) -> np.ndarray:
    """The horizontal direction the chest faces (scene frame, y up): across the shoulders, turned about y."""
    across = np.array(joints[KP["l_shoulder"]]) - np.array(joints[KP["r_shoulder"]])
    forward = np.cross(across, [0.0, 1.0, 0.0]) * [1.0, 0.0, 1.0]
    return forward / np.linalg.norm(forward)


def test_the_takes_frames_carry_the_hands_and_the_streams_face_direction(take_folder, hands_keypoints):
    folder, hand = hands_keypoints
    take = open_take(take_folder, folder)
    frames = take.frames_json(0, 100)
    with_hands = [f for f in frames if "hands" in f]
    assert [f["frame"] for f in with_hands] == [FRAME_K]
    assert with_hands[0]["hands"][0] == [payload.numbers(hand[:, :2], 1), None] and with_hands[0]["hands"][1] is None
    assert not any("hands" in f for f in open_take(take_folder, SAMPLE_KEYPOINTS).frames_json(0, 100))
    angles = []
    for f in frames:
        for person in [p for p in f["people"] if "face" in p]:   # the frames whose stream line turns the head
            face = np.array(person["face"])
            assert np.linalg.norm(face) == pytest.approx(1.0, abs=1e-3) and np.array(person["hands"]).shape == (2, 3)
            flat = face * [1.0, 0.0, 1.0]
            angles.append(np.degrees(np.arccos(flat @ _chest_forward(person["joints"]) / np.linalg.norm(flat))))
    # the stream's head, turned into the track files' floor frame, faces where the files' chest faces
    assert len(angles) >= 90 and np.median(angles) < 30, (len(angles), np.median(angles))


def test_the_page_draws_the_hands_and_the_face_direction(browser, take_folder, hands_keypoints):
    folder, hand = hands_keypoints
    main_track = json.loads((take_folder / "world.json").read_text())["main_track"]
    server = ViewServer(0, take=open_take(take_folder, folder), folder=take_folder)
    box = f"{hand[:, 0].min():.0f}, {hand[:, 1].min():.0f}, {np.ptp(hand[:, 0]) + 1:.0f}, {np.ptp(hand[:, 1]) + 1:.0f}"
    count_hand_pixels = f"""() => {{ const d = document.getElementById('image').getContext('2d')
        .getImageData({box}).data; let n = 0;
        for (let i = 0; i < d.length; i += 4) n += Math.abs(d[i] - {RIGHT_HAND_RGB[0]}) + Math.abs(d[i + 1]
          - {RIGHT_HAND_RGB[1]}) + Math.abs(d[i + 2] - {RIGHT_HAND_RGB[2]}) < 40;
        return n; }}"""
    try:
        page, errors = open_page(browser, server.url)
        page.wait_for_function("window.mocapdbViewer && window.mocapdbViewer.ready === true", timeout=30_000)
        page.evaluate(f"window.mocapdbViewer.seek({FRAME_K - 1})")
        page.wait_for_function(f"window.mocapdbViewer.frame() === {FRAME_K - 1}")
        assert page.evaluate("window.mocapdbViewer.handSegments()") == 0 and page.evaluate(count_hand_pixels) == 0
        page.evaluate(f"window.mocapdbViewer.seek({FRAME_K})")
        page.wait_for_function(f"window.mocapdbViewer.frame() === {FRAME_K}")
        assert page.evaluate("window.mocapdbViewer.handSegments()") == 20       # one hand: wrist out along 5 fingers
        assert page.evaluate(count_hand_pixels) > 100
        person = next(p for p in page.evaluate("window.mocapdbViewer.viewer.current.people")
                      if p["track"] == main_track)
        ends = np.array(page.evaluate(f"window.mocapdbViewer.ends({main_track})"), dtype=np.float64)
        head = np.array(person["joints"][KP["head"]])
        assert ends[0] == pytest.approx(np.stack([head, head + 0.3 * np.array(person["face"])]), abs=1e-4)
        wrists = np.array(person["joints"])[[KP["r_wrist"], KP["l_wrist"]]]
        assert ends[1:, 1] == pytest.approx(wrists + 0.12 * np.array(person["hands"]), abs=1e-4)
        assert not errors, errors
    finally:
        server.close()


def test_the_live_page_gets_the_face_direction_of_a_turned_head():
    feed = LiveFeed()
    page = feed.subscribe()
    pose = _pose(1)
    pose.quaternions[:] = [1.0, 0.0, 0.0, 0.0]
    pose.end_quaternions = np.tile([1.0, 0.0, 0.0, 0.0], (5, 1))
    pose.end_quaternions[4] = _turn(1, -90)             # the head turned to the person's right: +z → -x
    feed.frame(0, 0.0, [pose, _pose(2)])
    people = json.loads(feed.event(page.take(1.0), page))["people"]
    assert people[0]["face"] == pytest.approx([-1.0, 0.0, 0.0]) and "face" not in people[1]


def test_the_stereo_output_shows_both_cameras(browser, tmp_path):
    from mocapdb.cli.main import main

    out = tmp_path / "stereo"
    assert main(["stereo", str(SAMPLE_KEYPOINTS), str(SAMPLE_KEYPOINTS.parent / "pose2sim_cam04"), "--calibration",
                 str(SAMPLE_KEYPOINTS.parent / "calibration.toml"), "--cameras", "cam_01", "cam_04", "--fps", "60",
                 "--camera-distance", "5.24", "--out", str(out)]) == 0
    take = open_take(out)
    assert take.meta["kind"] == "stereo" and [c["name"] for c in take.meta["cameras"]] == ["cam_01", "cam_04"]
    centres = [np.array(c["position"]) for c in take.meta["cameras"]]
    assert np.linalg.norm(centres[1] - centres[0]) == pytest.approx(5.24, abs=0.01)
    people = [p for f in take.frames_json(0, 100) for p in f["people"]]
    assert people and not any("face" in p or "hands" in p for p in people)   # a stereo stream turns no end joints
    server = ViewServer(0, take=take, folder=out)
    try:
        page, errors = open_page(browser, server.url)
        page.wait_for_function("window.mocapdbViewer && window.mocapdbViewer.ready === true", timeout=30_000)
        assert variance_of(page.locator("#scene canvas").screenshot()) > 20
        assert not errors, errors
    finally:
        server.close()


def _get(url: str, host: str | None = None) -> int:
    request = urllib.request.Request(url, headers={"Host": host} if host else {})
    try:
        with urllib.request.urlopen(request) as answer:
            return answer.status
    except urllib.error.HTTPError as exc:
        return exc.code


def test_the_server_answers_the_loopback_only_and_serves_only_the_listed_files(take_folder):
    server = ViewServer(0, take=open_take(take_folder), folder=take_folder)
    try:
        url = server.url
        assert server.url.startswith("http://127.0.0.1:")
        assert _get(url) == 200 and _get(url + "vendor/three/OrbitControls.js") == 200
        assert _get(url + "static/three/OrbitControls.js") == 404 and _get(url + "vendor/../server.py") == 404
        assert _get(url + "files/world.json") == 200
        assert _get(url + "files/..%2Fworld.json") == 404 and _get(url + "static/../take.py") == 404
        assert _get(url + "files/take.json") == 404                       # not a file the run wrote
        assert _get(url, host="example.com") == 403                      # a page elsewhere rebinding its name
        with urllib.request.urlopen(url + "api/frames?from=10&count=3") as answer:
            frames = json.loads(answer.read())
        assert [f["frame"] for f in frames] == [10, 11, 12]
    finally:
        server.close()


def _pose(track: int) -> PersonPose:
    joints = np.zeros((15, 3)) + [0.0, 0.0, 4.0]
    return PersonPose(track, joints, np.zeros((11, 4)), joints[14], None)


def test_the_live_sink_never_waits_for_a_page_and_counts_what_it_drops(tmp_path):
    feed = LiveFeed()
    slow = feed.subscribe()   # a page that never reads
    sink = TeeSink([FileSink(tmp_path / "out.jsonl"), PageSink(feed)])
    sink.write('{"format": "mocapdb-stream", "version": 2, "fps": 30.0, "image_size": [640, 480], "focal_px": 500}')
    start = time.perf_counter()
    for k in range(500):
        sink.write_frame(k, k / 30, [_pose(1)])
    per_frame_us = (time.perf_counter() - start) / 500 * 1e6
    sink.close()
    assert slow is not None and len(slow.queue) == QUEUE_FRAMES
    assert feed.frames == 500 and feed.dropped == 500 + 2 - QUEUE_FRAMES   # the header and the end queued too
    assert len((tmp_path / "out.jsonl").read_text().splitlines()) == 501   # the command's own sink has every line
    assert per_frame_us < 1000, per_frame_us
    print(f"\nview: the page sink takes {per_frame_us:.0f} µs a frame (JSON line to a file included)")


def test_the_live_page_receives_the_frames_of_a_running_live(browser, small_db_path, tmp_path):
    source = tmp_path / "incoming"
    source.mkdir()
    command = [sys.executable, "-m", "mocapdb", "live", "--source", str(source), "--db", str(small_db_path), *SAMPLE,
               "--sink", str(tmp_path / "out.jsonl"), "--view", "0", "--no-browser", "--idle-timeout", "180"]
    live = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        match = page_address(live)
        page, errors = open_page(browser, match[1])
        page.wait_for_function("window.mocapdbViewer && window.mocapdbViewer.ready === true", timeout=30_000)
        files = sorted(SAMPLE_KEYPOINTS.glob("cam01.*.json"))
        for f in files:   # a detector writing frames at about 60 fps
            shutil.copy(f, source / (f.name + ".part"))
            os.replace(source / (f.name + ".part"), source / f.name)
            time.sleep(1 / 60)
        page.wait_for_function("window.mocapdbViewer.stats().received >= 30", timeout=150_000)
        time.sleep(1.0)
        stats = page.evaluate("window.mocapdbViewer.stats()")
        assert variance_of(page.locator("#scene canvas").screenshot()) > 20
        assert "frames/s" in page.text_content("#status") and "latency" in page.text_content("#status")
        page.screenshot(path=str(tmp_path / "live.png"))
        assert not errors, errors
    finally:
        live.send_signal(signal.SIGINT)
        _, err = live.communicate(timeout=120)
    assert live.returncode == 0, err
    report = re.search(r"view: 1 page\(s\) watched, (\d+) frame\(s\) sent, (\d+) dropped", err)
    assert report and int(report[1]) >= stats["received"], err
    print(f"\nview: live page received {stats['received']} of {len(files)} frames, {stats['fps']:.1f} frames/s, "
          f"latency {stats['latencyMs']:.0f} ms (engine's write to the page), {report[2]} dropped")


def test_the_view_command_serves_until_interrupted(take_folder):
    view = subprocess.Popen([sys.executable, "-m", "mocapdb", "view", str(take_folder), "--keypoints",
                             str(SAMPLE_KEYPOINTS), "--no-browser"], stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        match = page_address(view)
        with urllib.request.urlopen(match[1] + "api/take") as answer:
            meta = json.loads(answer.read())
        assert meta["kind"] == "take" and meta["keypoints"] and len(meta["frames"]) == 100
    finally:
        view.send_signal(signal.SIGINT)
        _, err = view.communicate(timeout=60)
    assert view.returncode == 0, err
