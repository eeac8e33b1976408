"""The image's verticals (runtime/world/image_vertical.py) on a standing body projected by hand through a
pitched and rolled pinhole: each frame's plane holds the true up, a candidate up's misfit is least at
the true roll, and in the world they pull a roll that the bodies' own up misreads back to the truth."""
import numpy as np
import pytest

from mocapdb.core.skeleton import KP
from mocapdb.runtime.world.fuse import estimate_world
from mocapdb.runtime.world.image_vertical import plane_angles_deg, vertical_misfit, vertical_planes, vertical_sd_deg
from mocapdb.runtime.world.tilt import tilted_normals
from tests.test_world import _person

FOCAL_PX, CENTRE_PX = 1000.0, (960.0, 540.0)
# A person standing upright facing the camera (x to the image's right, y up, metres above the floor)
STANDING = {"head": (0.0, 1.62), "r_shoulder": (-0.19, 1.44), "l_shoulder": (0.19, 1.44),
            "r_elbow": (-0.22, 1.15), "l_elbow": (0.22, 1.15), "r_wrist": (-0.24, 0.88), "l_wrist": (0.24, 0.88),
            "r_hip": (-0.10, 0.93), "l_hip": (0.10, 0.93), "r_knee": (-0.10, 0.50), "l_knee": (0.10, 0.50),
            "r_ankle": (-0.10, 0.08), "l_ankle": (0.10, 0.08), "neck": (0.0, 1.44)}


def _view_from_world(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """The rotation taking a level camera's frame (x right, y up, z towards the camera) to one
    pitched down by ``pitch_deg``, then rolled by ``roll_deg`` (the world's up leaning to the left)."""
    p, r = np.radians(pitch_deg), np.radians(roll_deg)
    pitch = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(p), -np.sin(p)], [0.0, np.sin(p), np.cos(p)]])
    roll = np.array([[np.cos(r), -np.sin(r), 0.0], [np.sin(r), np.cos(r), 0.0], [0.0, 0.0, 1.0]])
    return roll @ pitch


def _keypoints(x_m: float, depth_m: float, camera_height_m: float, pitch_deg: float, roll_deg: float,
               frames: int = 30, sway_deg: float = 0.0, seed: int = 0) -> np.ndarray:
    """``[frames, 14, 3]`` pixel keypoints (confidence 1) of the standing body ``x_m`` right of and
    ``depth_m`` in front of the camera, leaning sideways by a random ±``sway_deg`` per frame."""
    rng = np.random.default_rng(seed)
    rotation = _view_from_world(pitch_deg, roll_deg)
    out = np.zeros((frames, 14, 3))
    for f in range(frames):
        lean = np.radians(rng.uniform(-sway_deg, sway_deg))
        for name, (x, y) in STANDING.items():
            world = np.array([x_m + x * np.cos(lean) - y * np.sin(lean), x * np.sin(lean) + y * np.cos(lean)
                              - camera_height_m, -depth_m])
            view = rotation @ world
            out[f, KP[name]] = (CENTRE_PX[0] + FOCAL_PX * view[0] / -view[2],
                                CENTRE_PX[1] - FOCAL_PX * view[1] / -view[2], 1.0)
    return out


def _true_up(pitch_deg: float, roll_deg: float) -> np.ndarray:
    return _view_from_world(pitch_deg, roll_deg) @ [0.0, 1.0, 0.0]


@pytest.mark.parametrize("x_m, pitch_deg, roll_deg", [(0.0, 0.0, 0.0), (-1.5, 15.0, 8.0), (2.0, 25.0, -20.0)])
def test_every_plane_holds_the_true_up(x_m, pitch_deg, roll_deg):
    keypoints = _keypoints(x_m, 6.0, 1.6, pitch_deg, roll_deg)
    planes = vertical_planes(keypoints, (FOCAL_PX, *CENTRE_PX), 6.0, _true_up(pitch_deg, roll_deg))
    assert planes.shape == (30, 3)
    np.testing.assert_allclose(np.linalg.norm(planes, axis=1), 1.0)
    # the picture's centre of mass is the mean of projected points, not the projected centre of
    # mass: perspective leaves it off the vertical's image by a few hundredths of a degree
    assert np.abs(plane_angles_deg(planes, _true_up(pitch_deg, roll_deg)[None])).max() < 0.1


def test_a_frame_missing_a_keypoint_with_mass_gives_no_plane_but_a_missing_nose_sits_between_the_shoulders():
    keypoints = _keypoints(0.5, 5.0, 1.5, 10.0, 6.0, frames=12)
    keypoints[3, KP["l_wrist"], 2] = 0.0
    keypoints[7, KP["r_ankle"], 2] = 0.0
    keypoints[9, KP["neck"], 2] = 0.0   # the neck has no mass of its own: not needed
    keypoints[:, KP["head"], 2] = 0.0   # a detector that drops the nose
    planes = vertical_planes(keypoints, (FOCAL_PX, *CENTRE_PX), 5.0, _true_up(10.0, 6.0))
    assert len(planes) == 10
    # the head's 8 % of the mass moved from the nose (0.18 m above the shoulders) to between them
    assert np.abs(plane_angles_deg(planes, _true_up(10.0, 6.0)[None])).max() < 0.2
    keypoints[5, KP["l_shoulder"], 2] = 0.0   # no shoulders, no stand-in for the nose
    assert len(vertical_planes(keypoints, (FOCAL_PX, *CENTRE_PX), 5.0, _true_up(10.0, 6.0))) == 9


def test_the_misfit_is_least_at_the_true_roll_and_its_error_shrinks_with_more_frames():
    keypoints = _keypoints(1.0, 6.0, 1.8, 12.0, 6.0, frames=120, sway_deg=4.0)
    planes = vertical_planes(keypoints, (FOCAL_PX, *CENTRE_PX), 6.0, _true_up(12.0, 6.0))
    rolls = np.arange(-10.0, 20.01, 0.1)
    ups = tilted_normals(np.array([0.0, 1.0, 0.0]), np.column_stack([np.full_like(rolls, 12.0), rolls]))
    sd = vertical_sd_deg(planes, _true_up(12.0, 6.0), duration_s=4.0)
    assert rolls[np.argmin(vertical_misfit(planes, sd, ups))] == pytest.approx(6.0, abs=0.6)
    assert vertical_sd_deg(planes, _true_up(12.0, 6.0), duration_s=40.0) < sd  # more independent frames
    assert sd >= 2.0    # never below the posture's own lean


def test_the_image_verticals_pull_a_misread_roll_back_to_the_truth():
    # three people near the image's centre walking in depth (neither their contacts nor their sizes
    # fix the roll) whose own up estimates all
    # read the roll 7 deg off (each reporting a 6 deg error, as the fit's estimates of walks do); the
    # image shows their verticals as a camera with no roll sees them
    rng = np.random.default_rng(3)
    pitch = 10.0
    people = [_person(t, s, x, d, 1.6, pitch, rng, walk_m=2.0, in_depth=True)
              for t, s, x, d in ((1, 1.80, -0.4, 6.0), (2, 1.65, 0.1, 7.0), (3, 1.72, 0.5, 5.5))]
    misread = tilted_normals(np.array([0.0, 1.0, 0.0]), np.array([[pitch, 7.0]]))[0]
    people = [type(e)(e.track, e.nominal_stature_m, e.contacts_m, misread, 6.0) for e in people]
    without = estimate_world(people, camera_height_m=1.6)
    seen = []
    for e, x, d in zip(people, (-0.4, 0.1, 0.5), (6.0, 7.0, 5.5)):
        planes = vertical_planes(_keypoints(x, d, 1.6, pitch, 0.0, sway_deg=3.0, seed=e.track),
                                 (FOCAL_PX, *CENTRE_PX), d, misread)
        seen.append(type(e)(e.track, e.nominal_stature_m, e.contacts_m, misread, 6.0,
                            vertical_planes=planes, vertical_sd_deg=vertical_sd_deg(planes, misread, 1.0)))
    with_planes = estimate_world(seen, camera_height_m=1.6)
    assert abs(without.roll_deg) > 4.0
    assert abs(with_planes.roll_deg) < 1.5
    assert with_planes.pitch_deg == pytest.approx(without.pitch_deg, abs=1.0)  # the roll alone
