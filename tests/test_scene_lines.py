"""The camera from the room's lines (runtime/world/scene_lines.py, detect/scene.py, the world's fusion)
against independent references: the vanishing point of lines drawn through a known point is that
point; a room (floor grid, walls, door-frame verticals) rendered with a known K and R by
cv2.projectPoints and cv2.line gives back the camera's pitch, roll and focal length; a lone person
whose body leans the world 22° is set upright by the room's lines."""
import cv2
import numpy as np
import pytest

from mocapdb.core.formats.scene import SceneLines
from mocapdb.core.skeleton import UNIVERSAL_HEIGHT_M
from mocapdb.detect import scene as scene_module
from mocapdb.detect.scene import SceneSampler, line_segments, people_boxes
from mocapdb.runtime.world.fuse import TrackEvidence, estimate_world
from mocapdb.runtime.world.scene_lines import (
    SceneEvidence,
    angle_to_points_deg,
    fit_point,
    pitch_roll_deg,
    ransac_point,
    segment_lines,
    vanishing_points,
)

SIZE = (1280, 720)
FOCAL = 1000.0
K = np.array([[FOCAL, 0.0, SIZE[0] / 2], [0.0, FOCAL, SIZE[1] / 2], [0.0, 0.0, 1.0]])


def _camera(pitch_deg: float, roll_deg: float, yaw_deg: float = 0.0, height_m: float = 1.6):
    """World → camera rotation and translation (OpenCV axes; world z up) of a camera ``height_m``
    above the floor looking along +y, turned by ``yaw_deg``, pitched down, then rolled about its axis."""
    p, r, y = np.radians([pitch_deg, roll_deg, yaw_deg])
    forward = np.array([np.sin(y) * np.cos(p), np.cos(y) * np.cos(p), -np.sin(p)])
    right = np.array([np.cos(y), -np.sin(y), 0.0])
    down = np.cross(forward, right)
    right, down = np.cos(r) * right + np.sin(r) * down, -np.sin(r) * right + np.cos(r) * down
    rotation = np.stack([right, down, forward])
    return rotation, -rotation @ np.array([0.0, 0.0, height_m])


def _room_edges():
    """A 6 × 6 × 3 m room's edges (world, metres): floor grid, back and side walls' courses and studs."""
    edges = []
    for x in np.arange(-3.0, 3.01, 0.5):
        edges += [((x, 6, 0), (x, 6, 3)), ((x, 0.5, 0), (x, 6, 0))]
    for z in np.arange(0.0, 3.01, 0.5):
        edges += [((-3, 6, z), (3, 6, z)), ((-3, 0.5, z), (-3, 6, z)), ((3, 0.5, z), (3, 6, z))]
    for y in np.arange(1.0, 6.01, 0.5):
        edges += [((-3, y, 0), (3, y, 0)), ((-3, y, 0), (-3, y, 3)), ((3, y, 0), (3, y, 3))]
    return edges


def _render(rotation, translation, seed=0, size=SIZE, intrinsics=K) -> np.ndarray:
    """The room drawn (anti-aliased, 2 px, grey noise) by cv2.projectPoints and cv2.line."""
    image = np.full((size[1], size[0]), 110, np.uint8)
    rvec = cv2.Rodrigues(rotation)[0]
    for a, b in _room_edges():
        points = np.linspace(a, b, 40)
        points = points[(points @ rotation.T + translation)[:, 2] > 0.2]   # in front of the camera
        if len(points) < 2:
            continue
        ends = np.round(cv2.projectPoints(points[[0, -1]], rvec, translation, intrinsics, None)[0].reshape(2, 2) * 16)
        cv2.line(image, tuple(map(int, ends[0])), tuple(map(int, ends[1])), 30, 2, cv2.LINE_AA, 4)
    noise = np.random.default_rng(seed).normal(0.0, 4.0, image.shape)
    return np.clip(image + noise, 0, 255).astype(np.uint8)


def _truth(rotation) -> tuple[float, float]:
    """The world's up in the view frame (x right, y up, z towards the viewer): its pitch and roll."""
    up = rotation[:, 2] * np.array([1.0, -1.0, -1.0])
    pitch, roll = pitch_roll_deg(up)
    return float(pitch), float(roll)


def _scene(rotation, translation) -> SceneLines:
    return SceneLines(SIZE, (0,), (line_segments(_render(rotation, translation), np.zeros((0, 4))),), "lsd")


def test_the_vanishing_point_of_lines_through_a_point_is_that_point():
    rng = np.random.default_rng(3)
    point = np.array([0.3, -2.0, 1.0])                      # normalised image coordinates
    starts = rng.uniform(-1, 1, (30, 2))
    ends = starts + 0.2 * (point[:2] - starts) / np.linalg.norm(point[:2] - starts, axis=1, keepdims=True)
    segments = np.hstack([starts, ends])
    clutter = rng.uniform(-1, 1, (20, 4))
    found = fit_point(segment_lines(segments), np.ones(30))
    assert found[:2] / found[2] == pytest.approx(point[:2], abs=1e-9)
    both = np.vstack([segments, clutter])
    lengths = np.hypot(both[:, 2] - both[:, 0], both[:, 3] - both[:, 1])
    best, inliers = ransac_point(both, lengths, rng)
    assert best[:2] / best[2] == pytest.approx(point[:2], abs=1e-6)
    assert inliers[:30].all() and angle_to_points_deg(both[:30], best[None]).max() < 1e-6


@pytest.mark.parametrize("detector, focal_tolerance", [("lsd", 0.02), ("hough", 0.05)])
@pytest.mark.parametrize("pitch, roll, yaw", [(20.0, 5.0, 0.0), (10.0, -15.0, 30.0), (0.0, 0.0, 20.0),
                                              (25.0, 2.0, -35.0), (-8.0, 10.0, 15.0)])
def test_a_rendered_room_gives_back_pitch_roll_and_focal(pitch, roll, yaw, detector, focal_tolerance, monkeypatch):
    if detector == "lsd" and scene_module.detector_name() != "lsd":
        pytest.skip("this OpenCV has no working line segment detector (4.0-4.5.0): the Hough path runs")
    monkeypatch.setattr(scene_module, "detector_name", lambda: detector)   # OpenCV builds without LSD
    rotation, translation = _camera(pitch, roll, yaw)
    points = vanishing_points(_scene(rotation, translation))
    focal = points.focal()
    tilt = SceneEvidence(points, FOCAL, 0.0).tilt(None)   # no people: the vertical about the image's up
    true_pitch, true_roll = _truth(rotation)
    assert tilt.pitch_deg == pytest.approx(true_pitch, abs=0.5)
    assert tilt.roll_deg == pytest.approx(true_roll, abs=0.5)
    assert abs(tilt.pitch_deg - true_pitch) <= 2 * tilt.pitch_sd_deg
    assert focal.focal_px == pytest.approx(FOCAL, rel=focal_tolerance)   # three orthogonal directions are seen


def test_lines_on_the_people_are_not_the_scenes():
    rotation, translation = _camera(15.0, 0.0)
    image = _render(rotation, translation)
    box = np.array([[500.0, 200.0, 800.0, 500.0]])   # grown by BOX_MARGIN × its height: 455-845, 155-545

    def inside(segments):
        mid = 0.5 * (segments[:, :2] + segments[:, 2:])
        return (mid[:, 0] > 455) & (mid[:, 0] < 845) & (mid[:, 1] > 155) & (mid[:, 1] < 545)

    assert inside(line_segments(image, np.zeros((0, 4)))).sum() > 5
    outside = line_segments(image, box)
    assert len(outside) > 50 and not inside(outside).any()
    keypoints = np.array([[[450.0, 120.0, 0.9], [850.0, 680.0, 0.8], [0.0, 0.0, 0.0]]])
    assert people_boxes(keypoints) == pytest.approx(np.array([[450.0, 120.0, 850.0, 680.0]]))


def test_the_sampler_takes_a_frame_every_two_seconds(tmp_path):
    rotation, translation = _camera(15.0, 0.0)
    image = cv2.cvtColor(_render(rotation, translation), cv2.COLOR_GRAY2BGR)
    sampler = SceneSampler(30.0)
    for number in range(185):
        sampler.see(number, image, np.zeros((0, 33, 3)))
    assert sampler.frames == [0, 60, 120, 180]
    assert sampler.finish(tmp_path)[0].startswith("scene: ") and (tmp_path / "scene.json").exists()


def _standing(up: np.ndarray, n: int = 60) -> TrackEvidence:
    """A lone person standing 4 m away under a camera 1.6 m high (pitch 10°), whose body's up
    estimate is ``up``: contacts where both feet stand, 1 cm noise."""
    rng = np.random.default_rng(5)
    true_up = np.array([0.0, np.cos(np.radians(10.0)), np.sin(np.radians(10.0))])
    forward = np.cross(true_up, [1.0, 0.0, 0.0])
    feet = np.array([[-0.15], [0.15]])[np.arange(n) % 2] * np.array([1.0, 0.0, 0.0])
    contacts = feet + 4.0 * forward + (-1.6 + 0.08) * true_up + rng.normal(0.0, 0.01, (n, 3))
    return TrackEvidence(1, UNIVERSAL_HEIGHT_M, contacts, up, 6.0)


def test_a_stance_that_leans_the_world_is_set_upright_by_the_room():
    rotation, translation = _camera(10.0, 0.0)
    scene = SceneEvidence(vanishing_points(_scene(rotation, translation)), FOCAL, 0.0)
    lean = np.radians(22.0)
    pitch = np.radians(10.0)
    leaning = np.array([-np.sin(lean), np.cos(lean) * np.cos(pitch), np.cos(lean) * np.sin(pitch)])
    people_only = estimate_world([_standing(leaning)], camera_height_m=1.6)
    assert abs(people_only.roll_deg) > 15.0 and people_only.tilt_from == "people"
    fused = estimate_world([_standing(leaning)], camera_height_m=1.6, scene=scene)
    assert fused.roll_deg == pytest.approx(0.0, abs=1.0) and fused.pitch_deg == pytest.approx(10.0, abs=1.0)
    assert fused.tilt_from == "scene" and fused.scene_share > 0.8
    assert abs(fused.roll_deg) <= 2 * fused.roll_sd_deg


def test_nobody_standing_still_leaves_the_tilt_to_the_scene():
    rotation, translation = _camera(12.0, -6.0)
    scene = SceneEvidence(vanishing_points(_scene(rotation, translation)), FOCAL, 0.0)
    walker = TrackEvidence(1, UNIVERSAL_HEIGHT_M, np.zeros((0, 3)), np.array([0.0, 1.0, 0.0]), 6.0)
    world = estimate_world([walker], scene=scene)
    assert world.tilt_from == "scene" and not world.floor_known
    assert world.pitch_deg == pytest.approx(12.0, abs=0.5) and world.roll_deg == pytest.approx(-6.0, abs=0.5)
    assert estimate_world([walker]).tilt_from == "people"


def test_reconstruct_takes_the_focal_and_the_tilt_from_the_scene(small_db_path, tmp_path):
    """The bundled BlazePose take of the balancing camera 1 (1080 × 1920; calibrated: focal 1681 px,
    pitch 23.1°, roll −13.4°) with a ``scene.json`` of a room rendered through that camera:
    ``reconstruct`` without ``--focal`` takes the scene's focal (not the 26 mm guess, 1324 px) and
    its world's tilt comes from the scene (the people alone, focal given: roll −8.5°)."""
    import json
    import shutil
    from pathlib import Path

    from mocapdb.cli.main import main
    from mocapdb.core.formats.scene import write_scene

    folder = tmp_path / "kp"
    shutil.copytree(Path(__file__).resolve().parents[1] / "data" / "sample_keypoints" / "blazepose_cam01", folder)
    take = json.loads((folder / "take.json").read_text())
    (folder / "take.json").write_text(json.dumps({**take, "focal_px": None}))   # as detect writes it: no focal
    size, focal = (1080, 1920), 1681.0
    intrinsics = np.array([[focal, 0.0, size[0] / 2], [0.0, focal, size[1] / 2], [0.0, 0.0, 1.0]])
    rotation, translation = _camera(23.1, -13.4, 10.0, height_m=1.9)
    image = _render(rotation, translation, size=size, intrinsics=intrinsics)
    write_scene(folder, SceneLines(size, (0,), (line_segments(image, np.zeros((0, 4))),), "lsd"))
    out = tmp_path / "rec"
    assert main(["reconstruct", str(folder), "--db", str(small_db_path), "--out", str(out)]) == 0
    header = json.loads((out / "result.jsonl").read_text().splitlines()[0])
    assert header["camera_sources"]["focal_px"] == "scene"
    assert header["focal_px"] == pytest.approx(focal, rel=0.03)
    camera = json.loads((out / "world.json").read_text())["camera"]
    true_pitch, true_roll = _truth(rotation)
    assert camera["tilt_from"] in ("scene", "people and scene") and camera["scene"] is not None
    assert camera["pitch_deg"] == pytest.approx(true_pitch, abs=1.5)
    assert camera["roll_deg"] == pytest.approx(true_roll, abs=1.5)


def test_a_turning_cameras_lines_are_seen_from_its_reference_camera():
    """A camera that pans 8°, tilts 4° and rolls 5° between two sampled frames (about its centre,
    as ``camera_path.json`` holds it): its second frame's lines, turned back by the path, give the
    reference camera's tilt, as the keypoints are turned back; unturned they give their own."""
    from mocapdb.cli.scene_evidence import in_reference_camera
    from mocapdb.core.formats.camera_path import CameraPath

    rotation, translation = _camera(15.0, 3.0)
    turn = cv2.Rodrigues(np.radians([4.0, 8.0, 5.0]))[0]
    frames = (_scene(rotation, translation).segments[0], _scene(turn @ rotation, turn @ translation).segments[0])
    path = CameraPath(np.array([0, 60]), np.stack([np.eye(3), turn]), FOCAL, (SIZE[0] / 2, SIZE[1] / 2),
                      np.array([np.nan, 0.1]), np.zeros(2), False)
    second = SceneLines(SIZE, (60,), (frames[1],), "lsd")
    as_seen = SceneEvidence(vanishing_points(second), FOCAL, 0.0).tilt(None)
    turned_back = SceneEvidence(vanishing_points(in_reference_camera(second, path)), FOCAL, 0.0).tilt(None)
    assert (as_seen.pitch_deg, as_seen.roll_deg) == pytest.approx(_truth(turn @ rotation), abs=0.5)
    assert (turned_back.pitch_deg, turned_back.roll_deg) == pytest.approx(_truth(rotation), abs=0.5)
    assert np.degrees(np.arccos(as_seen.up @ turned_back.up)) > 4.0   # the turn moved the up this far
