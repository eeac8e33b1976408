"""The camera's rotation from the background (mocapdb/detect/camera_motion.py) and the keypoints seen
from the reference camera (mocapdb/core/formats/camera_path.py), against independent references:
images warped by OpenCV with rotations made by SciPy, the closed form of a pan and a roll, a scene
of two planes filmed by a camera that moves."""
import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.formats.camera_path import (
    CAMERA_PATH_FILE,
    CameraPath,
    CameraPathError,
    derotate_points,
    intrinsic_matrix,
    read_camera_path,
    write_camera_path,
)
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.formats.openpose import is_frame_file
from mocapdb.detect.camera_motion import BackgroundMotion, fit_rotation, people_mask, rays, shrink_factor
from mocapdb.detect.errors import DetectError

SIZE = (640, 480)
FOCAL = 600.0
K = intrinsic_matrix(FOCAL, (SIZE[0] / 2, SIZE[1] / 2))
TOLERANCE_DEG = 0.1   # a rotation recovered from a clean warp, at the shrunk image's 480 px


def texture(seed: int = 0, size: tuple[int, int] = SIZE) -> np.ndarray:
    """A BGR image full of corners: blurred noise with rectangles."""
    rng = np.random.default_rng(seed)
    image = cv2.GaussianBlur(rng.integers(0, 255, (size[1], size[0])).astype(np.uint8), (0, 0), 2.0)
    for _ in range(60):
        x, y = rng.integers(0, size[0]), rng.integers(0, size[1])
        cv2.rectangle(image, (int(x), int(y)), (int(x) + 25, int(y) + 18), int(rng.integers(0, 255)), -1)
    return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)


def turned(image: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """``image`` as the camera turned by ``rotation`` (reference → it) sees it: ``K R K⁻¹``."""
    return cv2.warpPerspective(image, K @ rotation @ np.linalg.inv(K), SIZE)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between two rotation matrices, by SciPy."""
    return float(np.degrees((Rotation.from_matrix(a) * Rotation.from_matrix(b).inv()).magnitude()))


def run(images: list[np.ndarray], focal: float = FOCAL) -> CameraPath:
    motion = BackgroundMotion(focal)
    for number, image in enumerate(images):
        motion.see(number, image, np.zeros((0, 17, 3)))
    return motion.path()


@pytest.mark.parametrize("euler", [(4.0, 0.0, 0.0), (0.0, -3.0, 2.0), (2.5, 1.5, -4.0)])
def test_a_rotation_only_pair_gives_its_rotation(euler):
    truth = Rotation.from_euler("yxz", euler, degrees=True).as_matrix()
    image = texture()
    path = run([image, turned(image, truth)])
    assert not path.still
    assert angle_deg(path.rotations[1], truth) < TOLERANCE_DEG
    assert angle_deg(path.rotations[0], np.eye(3)) == 0.0
    assert not path.moved.any()


def test_a_turn_over_many_frames_keeps_its_error_through_new_keyframes():
    """A 20 deg pan with tilt and roll over 60 frames: the image leaves most of its first corners
    behind, so keyframes are renewed; every frame's rotation stays within 0.3 deg (SciPy's)."""
    truths = Rotation.from_euler("yxz", np.linspace(0, 1, 60)[:, None] * [20.0, 3.0, 4.0], degrees=True).as_matrix()
    path = run(_panning_frames(truths))
    errors = [angle_deg(m, t) for m, t in zip(path.rotations, truths)]
    assert max(errors) < 0.3


def test_a_frame_of_no_whole_factor_is_cut_and_averaged_and_its_turn_found():
    """A 1000 x 700 frame (no whole factor gives 320 px): shrunk by 3 to 333 x 233, each pixel the mean
    of its 3 x 3 box of the green channel (NumPy's, within a grey level of rounding), the last row and
    column cut; a turn through its own camera is found to the tolerance."""
    size, focal = (1000, 700), 900.0
    assert shrink_factor(size) == 3 and shrink_factor((1768, 994)) == 6 and shrink_factor((1080, 1920)) == 6
    intrinsics = intrinsic_matrix(focal, (size[0] / 2, size[1] / 2))
    image = texture(11, size)
    image[:, :, 1] = cv2.GaussianBlur(texture(12, size)[:, :, 1], (0, 0), 1.0)   # green unlike blue and red
    motion = BackgroundMotion(focal)
    motion.see(0, image, np.zeros((0, 17, 3)))
    shrunk = motion._shrink(image)
    boxes = image[:699, :999, 1].reshape(233, 3, 333, 3).mean(axis=(1, 3))
    assert shrunk.shape == (233, 333) and np.abs(shrunk - boxes).max() <= 1.0
    truth = Rotation.from_euler("yxz", (3.0, -1.5, 1.0), degrees=True).as_matrix()
    motion.see(1, cv2.warpPerspective(image, intrinsics @ truth @ np.linalg.inv(intrinsics), size),
               np.zeros((0, 17, 3)))
    assert angle_deg(motion.path().rotations[1], truth) < TOLERANCE_DEG


def test_a_still_camera_is_still_and_the_identity():
    image = texture(2)
    rng = np.random.default_rng(3)
    noisy = [np.clip(image + rng.normal(0, 2.0, image.shape), 0, 255).astype(np.uint8) for _ in range(12)]
    path = run(noisy)
    assert path.still
    assert np.array_equal(path.rotations, np.broadcast_to(np.eye(3), (12, 3, 3)))
    frame = KeypointFrame(5, None, [Person(np.array([[10.0, 20.0]] * 14), np.ones(14))])
    assert path.derotate(frame) is frame



def test_a_background_with_too_few_corners_holds_the_camera_still():
    """Flat frames whose only corners are a counter's changing digits (as tests' synthetic videos are):
    a handful of tracks that once read a 10 deg turn; now fewer than MIN_AGREE agree, so nothing turns."""
    frames = []
    for i in range(20):
        image = np.full((SIZE[1], SIZE[0], 3), (i * 7) % 256, np.uint8)
        cv2.putText(image, str(i), (10, SIZE[1] - 20), cv2.FONT_HERSHEY_SIMPLEX, 2, (255, 255, 255), 3)
        frames.append(image)
    path = run(frames)
    assert path.still

def test_people_are_masked_and_their_motion_does_not_turn_the_camera():
    """A quarter of the image is a 'person' that slides 30 px a frame: inside its box nothing is
    tracked, and the camera stays still."""
    background, person = texture(4), texture(5)
    frames, boxes = [], []
    for k in range(8):
        image = background.copy()
        x = 100 + 30 * k
        image[100:400, x:x + 160] = person[100:400, 100:260]
        frames.append(image)
        boxes.append(np.array([[[x + 20.0, 140.0, 1.0], [x + 140.0, 360.0, 1.0]]]))
    motion = BackgroundMotion(FOCAL)
    for number, (image, box) in enumerate(zip(frames, boxes)):
        motion.see(number, image, box)
    assert motion.path().still
    mask = people_mask((480, 640), boxes[0], 1.0)
    assert mask[250, 180] == 0 and mask[20, 20] == 255


def test_fit_rotation_ignores_outliers():
    rng = np.random.default_rng(6)
    truth = Rotation.from_euler("xyz", [3.0, -5.0, 1.0], degrees=True).as_matrix()
    a = rays(rng.uniform([0, 0], SIZE, (200, 2)), K)
    b = a @ truth.T
    b[:60] = rays(rng.uniform([0, 0], SIZE, (60, 2)), K)      # 30 % wrong matches
    rotation, inliers = fit_rotation(a, b, 1.0 / FOCAL, rng)
    assert angle_deg(rotation, truth) < 1e-6
    assert not inliers[:60].any() and inliers[60:].all()


def two_planes(translation_m: np.ndarray) -> np.ndarray:
    """A wall 8 m away with a panel 2 m away in front of its left half, seen by the camera moved by
    ``translation_m`` (each plane warped by its own plane-induced homography ``K (I − t nᵀ / d) K⁻¹``)."""
    normal = np.array([0.0, 0.0, 1.0])

    def seen(depth: float) -> np.ndarray:
        return K @ (np.eye(3) - np.outer(translation_m, normal) / depth) @ np.linalg.inv(K)

    out = cv2.warpPerspective(texture(7), seen(8.0), SIZE, borderMode=cv2.BORDER_REFLECT)
    panel = np.zeros((SIZE[1], SIZE[0]), np.uint8)
    panel[:, :300] = 255
    cover = cv2.warpPerspective(panel, seen(2.0), SIZE) > 0
    out[cover] = cv2.warpPerspective(texture(8), seen(2.0), SIZE)[cover]
    return out


def test_a_camera_that_moves_is_flagged_and_one_that_turns_is_not():
    """A sideways step of 15 cm: the panel 2 m away shifts 45 px, the wall 8 m away 11 px: no
    rotation (and no homography) explains both."""
    steps = [two_planes(np.array([x, 0.0, 0.0])) for x in np.linspace(0.0, 0.15, 6)]
    assert run(steps).moved[-1]
    image = two_planes(np.zeros(3))
    turn = Rotation.from_euler("y", 3.0, degrees=True).as_matrix()   # 31 px between two frames
    assert not run([image, turned(image, turn)]).moved.any()


def test_derotation_is_the_closed_form_of_a_pan_and_a_roll():
    cx, cy = SIZE[0] / 2, SIZE[1] / 2
    pan = np.radians(7.0)
    pan_matrix = Rotation.from_euler("y", 7.0, degrees=True).as_matrix()
    xs = np.array([50.0, 320.0, 600.0])
    seen = derotate_points(np.stack([xs, np.full(3, cy)], axis=1), pan_matrix, K)
    np.testing.assert_allclose(seen[:, 0], cx + FOCAL * np.tan(np.arctan((xs - cx) / FOCAL) - pan), atol=1e-9)
    np.testing.assert_allclose(seen[:, 1], cy, atol=1e-9)
    roll = np.radians(-12.0)
    points = np.array([[100.0, 50.0], [500.0, 400.0]])
    seen = derotate_points(points, Rotation.from_euler("z", -12.0, degrees=True).as_matrix(), K)
    c, s = np.cos(-roll), np.sin(-roll)
    expected = (points - [cx, cy]) @ np.array([[c, s], [-s, c]]) + [cx, cy]
    np.testing.assert_allclose(seen, expected, atol=1e-9)


def test_derotation_inverts_the_turn_and_drops_rays_behind_the_camera():
    rotation = Rotation.from_euler("yxz", [20.0, -8.0, 5.0], degrees=True).as_matrix()
    points = np.array([[10.0, 10.0], [320.0, 240.0], [630.0, 470.0]])
    ahead = np.c_[points, np.ones(3)] @ (K @ rotation @ np.linalg.inv(K)).T
    np.testing.assert_allclose(derotate_points(ahead[:, :2] / ahead[:, 2:], rotation, K), points, atol=1e-6)
    behind = derotate_points(np.array([[320.0, 240.0]]), Rotation.from_euler("y", 120, degrees=True).as_matrix(), K)
    assert np.isnan(behind).all()


def _path(rotation: np.ndarray, still: bool = False) -> CameraPath:
    return CameraPath(np.array([0, 1]), np.stack([np.eye(3), rotation]), FOCAL, (SIZE[0] / 2, SIZE[1] / 2),
                      np.array([np.nan, 0.4]), np.array([False, True]), still)


def test_a_person_is_seen_from_the_reference_camera():
    rotation = Rotation.from_euler("yxz", [6.0, 3.0, 3.0], degrees=True).as_matrix()
    points = np.tile([[300.0, 200.0]], (14, 1))
    points[3] = np.nan
    world = np.arange(42, dtype=float).reshape(14, 3) / 40.0
    person = Person(points, np.where(np.isnan(points[:, 0]), 0.0, 0.9), world_m=world,
                    extremities=np.array([[310.0, 400.0, 0.8]] * 8), face=np.array([[280.0, 150.0, 4.0, 0.7]] * 468))
    out = _path(rotation).derotate(KeypointFrame(1, 0.1, [person])).people[0]
    np.testing.assert_allclose(out.points_px[0], derotate_points(points[0], rotation, K))
    assert out.confidence[3] == 0.0 and np.isnan(out.points_px[3]).all()
    np.testing.assert_allclose(out.extremities[0, :2], derotate_points(np.array([310.0, 400.0]), rotation, K))
    assert out.extremities[0, 2] == 0.8
    np.testing.assert_allclose(out.face[5, :2], derotate_points(np.array([280.0, 150.0]), rotation, K))
    assert out.face[5, 2:].tolist() == [4.0, 0.7]                            # the mesh's depth and confidence kept


def test_the_path_file_round_trips_and_is_not_a_frame(tmp_path):
    rotation = Rotation.from_euler("yxz", [6.0, 3.0, 3.0], degrees=True).as_matrix()
    write_camera_path(tmp_path, _path(rotation))
    back = read_camera_path(tmp_path)
    assert angle_deg(back.rotations[1], rotation) < 1e-4
    assert back.moved.tolist() == [False, True] and np.isnan(back.residual_px[0])
    np.testing.assert_allclose(back.rotation(7), back.rotations[1])           # past its end: the last one
    assert not is_frame_file(CAMERA_PATH_FILE)
    assert read_camera_path(tmp_path / "nothing") is None


def test_a_broken_path_file_names_the_file_and_the_field(tmp_path):
    write_camera_path(tmp_path, _path(np.eye(3)))
    body = json.loads((tmp_path / CAMERA_PATH_FILE).read_text())
    body["quaternions_wxyz"][1] = [2.0, 0.0, 0.0, 0.0]
    (tmp_path / CAMERA_PATH_FILE).write_text(json.dumps(body))
    with pytest.raises(CameraPathError, match="camera_path.json: quaternions_wxyz must be unit quaternions"):
        read_camera_path(tmp_path)
    (tmp_path / CAMERA_PATH_FILE).write_text("{")
    with pytest.raises(CameraPathError, match="not a camera path"):
        read_camera_path(tmp_path)


def test_live_uses_the_path_known_so_far():
    """Online (live): no rotation while the camera has not turned 0.1 deg, then each frame's own, the
    same the whole path gives at the end."""
    image = texture(9)
    truths = Rotation.from_euler("y", [[0.0], [0.02], [1.0], [2.0]], degrees=True).as_matrix()
    motion, live = BackgroundMotion(FOCAL), BackgroundMotion(FOCAL, history=False)
    online = []
    for number, turn in enumerate(truths):
        for m in (motion, live):
            m.see(number, turned(image, turn), np.zeros((0, 17, 3)))
        online.append(motion.online())
        np.testing.assert_array_equal(live.online() if online[-1] is not None else np.eye(3),
                                      online[-1] if online[-1] is not None else np.eye(3))
    assert online[0] is None and online[1] is None
    assert len(live.frames) == len(live.rotations) == 1          # live keeps the last frame only
    with pytest.raises(ValueError, match="none kept"):
        live.path()
    path = motion.path()
    for k in (2, 3):
        np.testing.assert_allclose(online[k], path.rotations[k])
        assert angle_deg(online[k], truths[k]) < TOLERANCE_DEG


def test_live_every_second_frame_extrapolates_a_steady_pan_and_holds_without_background():
    """Live measured every 2nd frame: on a pan at a steady 0.5 deg a frame the frames between are the
    measured ones turned on at that pace (within the tolerance of the truth, SciPy's; frame 1, before
    a pace is known, holds frame 0's), each measured one as every-frame live gives it; a background too
    bare to measure holds, never extrapolates.
    The whole path (history) is measured on every frame only."""
    image = texture(13)
    truths = Rotation.from_euler("y", 0.5 * np.arange(8)[:, None], degrees=True).as_matrix()
    every_frame, every_2nd = BackgroundMotion(FOCAL, history=False), BackgroundMotion(FOCAL, history=False, every=2)
    for number, turn in enumerate(truths):
        frame = turned(image, turn)
        for motion in (every_frame, every_2nd):
            motion.see(number, frame, np.zeros((0, 17, 3)))
        assert angle_deg(every_2nd.rotations[-1], turn if number != 1 else truths[0]) < TOLERANCE_DEG
        if number % 2 == 0:
            np.testing.assert_allclose(every_2nd.rotations[-1], every_frame.rotations[-1], atol=0.05 * np.pi / 180)
    bare = BackgroundMotion(FOCAL, history=False, every=2)
    for number in range(6):
        bare.see(number, np.full((SIZE[1], SIZE[0], 3), 90, np.uint8), np.zeros((0, 17, 3)))
        assert np.array_equal(bare.rotations[-1], np.eye(3))
    with pytest.raises(ValueError, match="every frame"):
        BackgroundMotion(FOCAL, every=2)


def test_world_json_carries_each_frames_floor_and_orientation():
    """world.json's camera_path: frame t's floor normal is the reference's turned into its view frame
    (a 10 deg tilt down adds 10 deg of pitch), its view → files rotation takes that frame's forward
    ray to where the reference sees it; a still camera's record is short."""
    from mocapdb.core.geometry import quat_to_matrix
    from mocapdb.runtime.world.camera_path import camera_path_record
    from mocapdb.runtime.world.fuse import World
    from mocapdb.runtime.world.summary import files_camera_pose

    pitch = np.radians(20.0)
    world = World(np.array([0.0, np.cos(pitch), np.sin(pitch)]), 1.6, 0.1, False)
    down = Rotation.from_euler("x", 10.0, degrees=True).as_matrix()   # OpenCV axes: the camera looks 10 deg lower
    record = camera_path_record(_path(down), world, files_on_floor=True)
    normal = np.array(record["floor_normal_view"][1])
    assert np.degrees(np.arctan2(normal[2], normal[1])) == pytest.approx(30.0, abs=1e-3)
    view_to_files = quat_to_matrix(np.array(record["view_to_files_wxyz"]))
    np.testing.assert_allclose(view_to_files[0], files_camera_pose(world)["view_to_files"], atol=1e-5)
    forward_then = view_to_files[1] @ [0.0, 0.0, -1.0]           # frame 1's optical axis in the files
    lower = np.radians(10.0)
    forward_ref = view_to_files[0] @ [0.0, -np.sin(lower), -np.cos(lower)]   # the reference's view: 10 deg lower
    np.testing.assert_allclose(forward_then, forward_ref, atol=1e-5)
    assert set(camera_path_record(_path(np.eye(3), still=True), world, True)) == {
        "reference_frame", "still", "focal_px", "moved_frames"}


def test_the_viewer_draws_the_turned_camera_where_it_looked():
    """`mocapdb view`'s frustums along a turning camera's path: frame t's axes, written in the
    reference camera's (right, down, forward), are R_t's rows (OpenCV axes); `render` and `view`
    re-project the files through each frame's own camera."""
    from mocapdb.render.tracks import FileScene, WorldFloor, as_filmed
    from mocapdb.runtime.world.camera_path import camera_path_record
    from mocapdb.runtime.world.fuse import World
    from mocapdb.view.take import path_cameras

    world = World(np.array([0.0, np.cos(0.3), np.sin(0.3)]), 1.7, 0.1, False)
    turn = Rotation.from_euler("yxz", [6.0, 3.0, 3.0], degrees=True).as_matrix()
    record = camera_path_record(_path(turn), world, files_on_floor=True)
    floor = WorldFloor(world.normal, 1.7, None, {}, {}, "floor", record)
    reference = (np.eye(3) * [1.0, -1.0, -1.0]) @ floor.level().T * [1.0, 1.0, -1.0]   # as render's file_scene
    scene = FileScene([], floor, "floor", True, np.array([0.0, 1.7, 0.0]), reference)
    image = {"focal": FOCAL, "cx": SIZE[0] / 2, "cy": SIZE[1] / 2, "width": SIZE[0], "height": SIZE[1]}
    (camera,) = path_cameras(scene, image)
    in_reference = np.array(camera["axes"]) @ np.linalg.inv(reference)   # rows: frame 1's axes in the reference's
    np.testing.assert_allclose(in_reference, turn, atol=1e-5)            # R's rows: the turned axes
    angle = np.degrees(Rotation.from_matrix(turn).magnitude())
    assert camera["label"] == f"frame 1, {angle:.1f} deg" and camera["position"] == [0.0, 1.7, 0.0]
    still = replace(scene, world=replace(floor, camera_path=camera_path_record(_path(turn, True), world, True)))
    assert path_cameras(still, image) == []
    # the re-projection onto the frames as filmed: a reference camera-aligned point (x right, y up, z
    # ahead) as the turned camera sees it, OpenCV's R applied in OpenCV's axes
    point = np.array([[0.4, -0.2, 5.0]])
    aligned = np.array([1.0, -1.0, 1.0])
    seen = as_filmed(floor, np.array([0, 1, 5]), np.repeat(point[None], 3, axis=0))
    np.testing.assert_allclose(seen[0], point, atol=1e-9)
    np.testing.assert_allclose(seen[1:, 0], np.tile((turn @ (point[0] * aligned)) * aligned, (2, 1)), atol=1e-4)
    np.testing.assert_array_equal(as_filmed(still.world, np.array([1]), point[None]), point[None])


@pytest.mark.parametrize(("euler", "turned_back"), [("z", True), ("y", False), ("x", False)])
def test_the_detectors_3d_turns_with_the_image_about_the_person(euler, turned_back):
    """A person at the principal point: a roll of the camera rolls the detector's 3D back by Rᵀ (the
    crop about the person rolls with the image); a pan or a tilt leaves it as it was (the crop about
    the person looks the same)."""
    rotation = Rotation.from_euler(euler, 8.0, degrees=True).as_matrix()
    centre = np.array([SIZE[0] / 2, SIZE[1] / 2])
    points = centre + np.linspace(-1.0, 1.0, 14)[:, None] * [3.0, 60.0]      # around the principal point
    seen = np.c_[points, np.ones(14)] @ (K @ rotation @ np.linalg.inv(K)).T   # where the turned camera sees them
    world = np.random.default_rng(10).normal(size=(14, 3))
    person = Person(seen[:, :2] / seen[:, 2:], np.ones(14), world_m=world)
    out = _path(rotation).derotate(KeypointFrame(1, 0.1, [person])).people[0]
    np.testing.assert_allclose(out.world_m, world @ rotation if turned_back else world, atol=2e-3)


def test_a_video_that_changes_size_is_refused_by_name():
    motion = BackgroundMotion(FOCAL)
    motion.see(0, texture(), np.zeros((0, 17, 3)))
    with pytest.raises(DetectError, match="frame 1 is 320x240 px, the video's first 640x480"):
        motion.see(1, cv2.resize(texture(), (320, 240)), np.zeros((0, 17, 3)))


def _panning_frames(turns: np.ndarray) -> list[np.ndarray]:
    """A wide textured image seen through a 600 px camera at each of ``turns [N, 3, 3]``."""
    image = texture(1, (1400, 700))
    wide = intrinsic_matrix(FOCAL, (700.0, 350.0))
    crop = np.array([[1, 0, 700 - SIZE[0] / 2], [0, 1, 350 - SIZE[1] / 2], [0, 0, 1.0]])
    return [cv2.warpPerspective(image, np.linalg.inv(crop) @ wide @ r @ np.linalg.inv(wide), SIZE) for r in turns]


def test_the_focal_comes_from_the_turn_where_none_was_given():
    """No focal given: the 26 mm default for 640 x 480 is 481 px, the camera's 600 px. A 12 deg pan
    with a tilt shows it (within 3 %), and the rotations refitted at it are within 0.3 deg; a roll
    alone shows none (the default stays)."""
    truths = Rotation.from_euler("yxz", np.linspace(0, 1, 40)[:, None] * [12.0, 4.0, 2.0], degrees=True).as_matrix()
    motion = BackgroundMotion()
    for number, image in enumerate(_panning_frames(truths)):
        motion.see(number, image, np.zeros((0, 17, 3)))
    path = motion.path()
    assert path.focal_px == pytest.approx(FOCAL, rel=0.03)
    assert max(angle_deg(m, t) for m, t in zip(path.rotations, truths)) < 0.3
    rolls = Rotation.from_euler("z", np.linspace(0, 8, 20)[:, None], degrees=True).as_matrix()
    motion = BackgroundMotion()
    for number, image in enumerate(_panning_frames(rolls)):
        motion.see(number, image, np.zeros((0, 17, 3)))
    assert motion.path().focal_px == pytest.approx(motion.focal_px)
