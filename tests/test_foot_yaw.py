"""The feet's yaw on a real take (mocapdb/evaluation/foot_yaw.py): closed forms of the yaws and headings, and the
score about the reference's circular mean."""
import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.evaluation.foot_yaw import azimuths, foot_yaws, score, view_points


def _body(hips_deg: float, right_deg: float, left_deg: float) -> np.ndarray:
    """Points ``[1, 8, 3]`` (y up) of hips turned ``hips_deg`` about y and feet pointing ``…_deg`` (headings from z
    towards x), in REFERENCE_POINTS' roles."""
    def heading(deg: float) -> np.ndarray:
        return np.array([np.sin(np.radians(deg)), 0.0, np.cos(np.radians(deg))])
    x = np.array([np.cos(np.radians(hips_deg)), 0.0, -np.sin(np.radians(hips_deg))])   # the hips' x, turned
    r_heel, l_heel = np.array([-0.1, 0.05, 0.0]), np.array([0.1, 0.05, 0.0])
    return np.array([[r_heel, r_heel + 0.2 * heading(right_deg) - [0, 0.04, 0], l_heel,
                      l_heel + 0.2 * heading(left_deg) - [0, 0.04, 0], 0.1 * -x + [0, 1, 0], 0.1 * x + [0, 1, 0],
                      0.2 * -x + [0, 1.5, 0], 0.2 * x + [0, 1.5, 0]]])


def test_yaws_against_the_hips_and_headings_in_a_frame():
    points = _body(20.0, 35.0, -10.0)
    np.testing.assert_allclose(foot_yaws(points), [[15.0, -30.0]], atol=1e-9)
    # the hips' heading is their x axis's (right -> left hip): forwards + 90 deg
    np.testing.assert_allclose(azimuths(points, np.array([0.0, 1.0, 0.0])), [[35.0, -10.0, 110.0]], atol=1e-9)


def test_view_points_is_the_cameras_frame_with_y_up_and_z_towards_it():
    camera = CameraModel(np.eye(3), np.zeros(5), np.eye(3), np.array([0.0, 0.0, 4.0]), (1920, 1080))
    np.testing.assert_allclose(view_points(np.array([1.0, 2.0, 0.5]), camera), [1.0, -2.0, -4.5])


def test_a_heading_near_180_deg_does_not_wrap():
    reference = np.array([[179.0], [-179.0], [178.0], [-177.0]])
    estimate = reference + 2.0
    s = score(estimate, reference, ("h",))
    assert abs(s.rms_deg["h"] - 2.0) < 1e-9 and abs(s.offset_deg["h"] - 2.0) < 1e-9
    assert s.reference_sd_deg["h"] < 2.5 and s.r["h"] > 0.999
