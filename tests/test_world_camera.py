"""The calibrated camera's height, pitch and roll (evaluation.world_camera) against cameras built by hand."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.cameras import CameraModel
from mocapdb.evaluation.world_camera import camera_checks, score_camera, true_camera
from mocapdb.runtime.world.fuse import World


def _camera(height_m: float, pitch_deg: float, roll_deg: float, yaw_deg: float = 30.0) -> CameraModel:
    """An OpenCV camera at ``height_m`` above z = 0, facing ``yaw_deg`` round the vertical, looking
    ``pitch_deg`` down and rolled ``roll_deg`` (the world's up leaning to the image's left)."""
    # camera axes in the world when level and facing +y: x right = +x, y down = −z, z forward = +y
    level = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])        # rows: camera axes
    yaw = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    # pitch down: turn about the camera's x axis; roll: about its optical axis (z)
    pitch = Rotation.from_euler("x", pitch_deg, degrees=True).as_matrix()
    roll = Rotation.from_euler("z", -roll_deg, degrees=True).as_matrix()
    r = roll @ pitch @ level @ yaw.T
    centre = np.array([2.0, -3.0, height_m])
    return CameraModel(np.eye(3), np.zeros(4), r, -r @ centre, (1920, 1080))


@pytest.mark.parametrize("pitch, roll", [(0.0, 0.0), (23.0, 0.0), (-10.0, 0.0), (15.0, 12.0), (20.0, -26.0)])
def test_the_true_camera_is_the_one_built(pitch, roll):
    """Rolled about its optical axis after pitching, the floor's normal in the view frame is
    (sin r cos p, cos r cos p, sin p) up to the sign of x: the roll is r, the pitch atan(tan p / cos r)."""
    truth = true_camera(_camera(1.9, pitch, roll))
    assert truth["height_m"] == pytest.approx(1.9)
    p, r = np.radians(pitch), np.radians(roll)
    assert truth["pitch_deg"] == pytest.approx(np.degrees(np.arctan2(np.sin(p), np.cos(r) * np.cos(p))), abs=1e-9)
    assert truth["roll_deg"] == pytest.approx(roll, abs=1e-9)


def test_a_world_is_scored_against_the_calibration():
    cam = _camera(2.0, 20.0, 0.0)
    normal = np.array([0.0, np.cos(np.radians(25.0)), np.sin(np.radians(25.0))])   # 25° down, no roll
    world = World(normal, camera_height_m=1.4, camera_height_log_sd=0.2, camera_height_given=False)
    score = score_camera(world, cam)
    assert score["height_error_pct"] == pytest.approx(-30.0)
    assert score["pitch_error_deg"] == pytest.approx(5.0)
    assert score["roll_error_deg"] == pytest.approx(0.0, abs=1e-9)
    assert score["height_inside_2sd"]          # 1.4 m · e^0.4 = 2.09 m ≥ 2 m
    lines = camera_checks({"a": score})
    assert [line.split()[0] for line in lines] == ["FAIL", "FAIL", "FAIL", "PASS", "PASS"]


def test_the_tilts_spread_is_the_posteriors_sd():
    """A Gaussian posterior over the tilt grid (SD 4° in pitch, 6° in roll, any height) gives those SDs."""
    from mocapdb.runtime.world.tilt import tilt_spread_deg

    offsets = np.arange(-20.0, 20.0 + 1e-9, 2.0)
    tilts = np.stack(np.meshgrid(offsets, offsets, indexing="ij"), axis=-1).reshape(-1, 2)
    cost = (0.5 * (tilts[:, 0] / 4.0) ** 2 + 0.5 * (tilts[:, 1] / 6.0) ** 2)[:, None].repeat(3, axis=1)
    pitch_sd, roll_sd = tilt_spread_deg(tilts, cost, 2.0)
    assert pitch_sd == pytest.approx(4.0, rel=0.02) and roll_sd == pytest.approx(6.0, rel=0.05)
    flat_top = np.where(np.abs(tilts).max(axis=1) == 0, 0.0, 50.0)[:, None]   # all mass on one grid point
    assert tilt_spread_deg(tilts, flat_top, 2.0) == pytest.approx((2.0 / np.sqrt(12), 2.0 / np.sqrt(12)))


def test_the_heights_spread_takes_the_pitch_it_trades_with():
    """A Gaussian posterior in (pitch t, log height y) along a valley, y − 0.03 t of SD 0.1 and t of
    SD 5°: the height's marginal SD is √(0.1² + (0.03 · 5)²) = 0.18 (closed form), while at the best
    pitch alone it is 0.1. One height (given) has none."""
    from mocapdb.runtime.world.tilt import height_spread_log

    offsets = np.arange(-20.0, 20.0 + 1e-9, 2.0)
    tilts = np.stack(np.meshgrid(offsets, offsets, indexing="ij"), axis=-1).reshape(-1, 2)
    log_h = np.arange(-1.5, 1.5, 0.01)
    cost = 0.5 * ((log_h[None, :] - 0.03 * tilts[:, :1]) / 0.1) ** 2 + 0.5 * (tilts[:, :1] / 5.0) ** 2
    assert height_spread_log(log_h, cost) == pytest.approx(np.hypot(0.1, 0.15), rel=0.03)
    at_best_pitch = cost[np.abs(tilts).max(axis=1) == 0]
    assert height_spread_log(log_h, at_best_pitch) == pytest.approx(0.1, rel=0.02)
    assert height_spread_log(np.array([0.4]), cost[:, :1]) == 0.0


def test_the_camera_heights_prior_is_usual_heights_with_a_flat_tail():
    """−log of 0.8 N(log h; log 1.5 m, 0.7) + 0.2 / width, by hand: least at 1.5 m, even in log about
    it, and never dearer than the flat tail alone (a camera on the ground or a drone stays possible)."""
    from mocapdb.runtime.world.tilt import height_cost

    width = np.log(60.0 / 0.1)
    usual = 0.8 / (0.7 * np.sqrt(2.0 * np.pi))
    assert height_cost(np.log([1.5]), width)[0] == pytest.approx(-np.log(usual + 0.2 / width))
    z = np.log(3.0 / 1.5) / 0.7
    assert height_cost(np.log([3.0]), width)[0] == pytest.approx(-np.log(usual * np.exp(-0.5 * z * z) + 0.2 / width))
    assert height_cost(np.log([0.75]), width)[0] == pytest.approx(height_cost(np.log([3.0]), width)[0])
    far = height_cost(np.log([0.1, 60.0]), width)
    assert np.all(far < -np.log(0.2 / width)) and np.all(far > -np.log(0.2 / width) - 0.01)


def test_reconstruct_reports_the_world_the_evaluation_scores(small_db, small_db_path, tmp_path, capsys):
    """The bundled BlazePose take of camera 1 holds the subject and a bystander standing still at the
    image's edge (a static track: no files). ``reconstruct``'s ``world.json`` is the world that
    ``world_of_frames`` (the camera's evaluation) finds, the bystander's evidence included."""
    import json
    from pathlib import Path

    from mocapdb.cli.main import main
    from mocapdb.core.formats.openpose import read_openpose_folder
    from mocapdb.evaluation.world_camera import world_of_frames
    from mocapdb.runtime.engine_config import EngineConfig

    folder = Path(__file__).resolve().parents[1] / "data" / "sample_keypoints" / "blazepose_cam01"
    out = tmp_path / "rec"
    assert main(["reconstruct", str(folder), "--db", str(small_db_path), "--focal", "1681", "--out", str(out)]) == 0
    record = json.loads((out / "world.json").read_text())
    still = [t for t in record["tracks"] if not t["written"]]
    assert len(still) == 1 and record["main_track"] != still[0]["track"]
    assert f"track {still[0]['track']} (no files: static)" in capsys.readouterr().out
    world = world_of_frames(small_db, list(read_openpose_folder(folder, fps=60.0)),
                            EngineConfig(fps=60.0, focal_px=1681.0, image_size=(1080, 1920)))
    assert record["camera"]["height_m"] == pytest.approx(world.camera_height_m, rel=1e-3)
    assert record["camera"]["pitch_deg"] == pytest.approx(world.pitch_deg, abs=0.01)
    assert record["camera"]["roll_deg"] == pytest.approx(world.roll_deg, abs=0.01)
