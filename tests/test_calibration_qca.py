"""Qualisys QTM calibrations (.qca.txt) read as Pose2Sim reads them (mocapdb.core.cameras.read_calibration_qca):
hand-made files of cameras with known K, R, t, against the TOML camera model and OpenCV's projection."""
import json
import re

import cv2
import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.cameras import (
    QTM_TO_OPENCV,
    CalibrationError,
    CameraModel,
    format_calibration_toml,
    read_calibration,
    read_calibration_toml,
)

from .conftest import SAMPLE_KEYPOINTS

BUNDLED = SAMPLE_KEYPOINTS.parent


def _camera(name: str, rvec, centre_m, size=(1088, 1920), dist=(-0.02, 0.05, 0.001, -0.0005, 0.0)) -> CameraModel:
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]
    k = np.array([[1681.2, 0.0, 532.9], [0.0, 1680.4, 948.1], [0.0, 0.0, 1.0]])
    return CameraModel(k, np.asarray(dist, dtype=np.float64), R, -R @ np.asarray(centre_m, dtype=np.float64),
                       size, name)


CAMERAS = [_camera("cam_01", [1.69, 1.05, -0.42], [1.46, -1.91, 1.90]),
           _camera("cam_04", [0.31, -2.10, 1.22], [-3.76, -1.42, 1.88], dist=(0.01, -0.03, 0.0, 0.0, 0.002))]


def _n(value) -> str:
    return repr(float(value))


def qca_text(cams: list[CameraModel], crop=(0, 0), video_lines: int | None = None, active=None) -> str:
    """A QTM calibration of ``cams``: the image a crop at ``crop`` (left, top) of the sensor, recorded at
    ``video_lines`` (e.g. 720: scaled 720/1080) when given; every ``cams[k]`` active unless ``active[k]`` is 0."""
    scale = 1.0 if video_lines is None else video_lines / 1080
    left, top = crop
    body = []
    for k, cam in enumerate(cams):
        m = QTM_TO_OPENCV @ cam.R                          # world → QTM camera (y up, looking along −z)
        x, y, z = cam.center_m * 1000.0                    # mm
        fu, fv = cam.K[0, 0] / scale * 64, cam.K[1, 1] / scale * 64
        cu, cv = (cam.K[0, 2] / scale + left) * 64, (cam.K[1, 2] / scale + top) * 64
        k1, k2, p1, p2, k3 = np.resize(cam.dist, 5) * 64
        right, bottom = left + cam.size[0] / scale - 1, top + cam.size[1] / scale - 1
        rotation = " ".join(f'r{i + 1}{j + 1}="{_n(m[i, j])}"' for i in range(3) for j in range(3))
        resolution = "" if video_lines is None else f' video_resolution="{video_lines}p"'
        body.append(f"""    <camera active="{1 if active is None else active[k]}" avg-residual="0.4" model="Miqus Video"
            point-count="999" serial="{cam.name}" viewrotation="0"{resolution}>
      <fov_marker bottom="{bottom:g}" left="{left}" right="{right:g}" top="{top}"/>
      <fov_video bottom="{bottom:g}" left="{left}" right="{right:g}" top="{top}"/>
      <transform {rotation} x="{_n(x)}" y="{_n(y)}" z="{_n(z)}"/>
      <intrinsic focallength="9.31" sensorMinU="0" sensorMaxU="122816" sensorMinV="0" sensorMaxV="69568"
        focalLengthU="{_n(fu)}" focalLengthV="{_n(fv)}" centerPointU="{_n(cu)}" centerPointV="{_n(cv)}" skew="0"
        radialDistortion1="{_n(k1)}" radialDistortion2="{_n(k2)}" radialDistortion3="{_n(k3)}"
        tangentalDistortion1="{_n(p1)}" tangentalDistortion2="{_n(p2)}"/>
    </camera>""")
    return ("<?xml version='1.0' encoding='ASCII'?>\n<calibration source=\"test\" type=\"regular\">\n"
            "  <results std-dev=\"0.\"/>\n  <cameras>\n" + "\n".join(body) + "\n  </cameras>\n</calibration>\n")


def _write(tmp_path, text: str, name: str = "Calib.qca.txt"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _same(a: CameraModel, b: CameraModel) -> None:
    assert a.name == b.name and tuple(a.size) == tuple(b.size)
    np.testing.assert_allclose(a.K, b.K, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.resize(a.dist, 5), np.resize(b.dist, 5), atol=1e-12)
    np.testing.assert_allclose(a.R, b.R, atol=1e-12)
    np.testing.assert_allclose(a.t, b.t, atol=1e-9)


def test_a_qca_file_gives_the_cameras_it_was_made_of(tmp_path):
    cams = read_calibration(_write(tmp_path, qca_text(CAMERAS)))
    assert list(cams) == ["cam_01", "cam_04"]
    for cam in CAMERAS:
        _same(cams[cam.name], cam)


def test_the_same_cameras_as_the_toml_camera_model(tmp_path):
    """Cameras without k3 written as Pose2Sim's TOML and as a QCA file read back the same."""
    cams = [CameraModel(c.K, c.dist[:4], c.R, c.t, c.size, c.name) for c in CAMERAS]
    toml = read_calibration(_write(tmp_path, format_calibration_toml(cams), "calibration.toml"))
    qca = read_calibration(_write(tmp_path, qca_text(cams)))
    assert list(toml) == list(qca)
    for name in toml:
        _same(qca[name], toml[name])


@pytest.mark.parametrize("crop, video_lines", [((0, 0), None), ((96, 40), None), ((0, 0), 720), ((64, 8), 540)])
def test_a_point_projects_as_opencv_projects_it(tmp_path, crop, video_lines):
    """The image a crop of the sensor (``fov_video``) and a video recorded below the sensor's 1080 lines."""
    cams = read_calibration(_write(tmp_path, qca_text(CAMERAS, crop, video_lines)))
    points = np.array([[0.2, -0.4, 1.1], [-0.5, 0.3, 0.2], [0.0, 0.0, 1.7]])
    for cam in CAMERAS:
        expected, _ = cv2.projectPoints(points, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, cam.dist)
        np.testing.assert_allclose(cams[cam.name].project(points), expected.reshape(-1, 2), atol=1e-6)
        assert cams[cam.name].size == cam.size


def test_inactive_cameras_are_left_out_and_the_suffix_chooses_the_reader(tmp_path):
    path = _write(tmp_path, qca_text(CAMERAS, active=[0, 1]))
    assert list(read_calibration(path)) == ["cam_04"]
    with pytest.raises(CalibrationError, match="not valid TOML"):
        read_calibration_toml(path)
    with pytest.raises(CalibrationError, match="every camera is inactive"):
        read_calibration(_write(tmp_path, qca_text(CAMERAS, active=[0, 0])))


GOOD = qca_text(CAMERAS[:1])


@pytest.mark.parametrize("change, message", [
    (lambda t: t.replace('focalLengthU="', 'focalLengthX="'), '<camera serial="cam_01">: <intrinsic focalLengthU=...> '
                                                               "is missing"),
    (lambda t: re.sub(r'r11="[^"]*"', 'r11="abc"', t), "<transform r11=...> is 'abc', not a number"),
    (lambda t: re.sub(r'x="[^"]*"', 'x="nan"', t), "<transform x=...> is not a finite number"),
    (lambda t: re.sub(r'r11="[^"]*"', 'r11="3.0"', t), "<transform r11..r33>"),
    (lambda t: t.replace('skew="0"', 'skew="2.5"'), "<intrinsic skew=...> is not 0"),
    (lambda t: re.sub(r'focalLengthU="[^"]*"', 'focalLengthU="-64000"', t), "focal lengths fx = -1000"),
    (lambda t: t.replace("<fov_video ", "<fov_other "), "no <fov_video>"),
    (lambda t: t.replace('serial="cam_01"', 'serial="cam_01" video_resolution="big"'), "video_resolution 'big'"),
    (lambda t: t.replace("</cameras>", ""), "line 16, column 3: not valid XML"),
    (lambda t: t.replace("<cameras>", "<cams>").replace("</cameras>", "</cams>"), "no <calibration><cameras><camera>"),
    (lambda t: t.replace("<calibration", '<!DOCTYPE c [<!ENTITY a "x">]>\n<calibration'), "entity declaration"),
    (lambda t: t.replace("  </cameras>", GOOD.split("<cameras>\n")[1].split("  </cameras>")[0] + "  </cameras>"),
     "two cameras with serial 'cam_01'"),
])
def test_unusable_qca_files_name_the_file_camera_and_attribute(tmp_path, change, message):
    text = change(GOOD)
    assert text != GOOD
    path = _write(tmp_path, text)
    with pytest.raises(CalibrationError, match=re.escape(str(path)) + ".*" + re.escape(message)):
        read_calibration(path)


def test_stereo_reads_a_qca_calibration(tmp_path, capsys):
    """The bundled pair with its calibration given as a QCA file: the same intrinsics as from the TOML."""
    toml = read_calibration_toml(BUNDLED / "calibration.toml")
    path = _write(tmp_path, qca_text(list(toml.values())))
    out = tmp_path / "out"
    assert main(["stereo", str(BUNDLED / "pose2sim_cam01"), str(BUNDLED / "pose2sim_cam04"), "--calibration",
                 str(path), "--cameras", "cam_01", "cam_04", "--fps", "60", "--out", str(out)]) == 0
    written = json.loads((out / "cameras.json").read_text())["cameras"]
    for record, name in zip(written, ("cam_01", "cam_04")):
        np.testing.assert_allclose(record["K"], toml[name].K, rtol=1e-12)
        np.testing.assert_allclose(record["dist"][:4], toml[name].dist, atol=1e-15)
    assert main(["stereo", str(BUNDLED / "pose2sim_cam01"), str(BUNDLED / "pose2sim_cam04"), "--calibration",
                 str(path), "--cameras", "cam_01", "cam_09", "--out", str(tmp_path / "o2")]) == 2
    assert f"{path} has no camera cam_09 (it has cam_01, cam_02, cam_03, cam_04)" in capsys.readouterr().err
