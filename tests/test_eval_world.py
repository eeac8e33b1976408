"""The multi-person world evaluation (`mocapdb eval --world`): synthetic takes and their scoring,
against hand-computed cases."""
import json
from dataclasses import replace

import numpy as np
import pytest

from mocapdb.core.skeleton import (
    ANKLE_HEIGHT_M,
    MEASURED_BONE_NAMES,
    N_KEYPOINTS_2D,
    PELVIS,
    bone_lengths_m,
    stature_m,
    universal_bone_lengths_m,
)
from mocapdb.evaluation.bodies import (
    CHILD_HEAD_FACTOR,
    CHILD_HEIGHT_RANGE_M,
    CHILD_LEG_FACTOR,
    HEIGHT_RANGE_M,
    child_proportions,
    sample_body,
)
from mocapdb.evaluation.heldout import load_heldout, project
from mocapdb.evaluation.world import check_lines, evaluate_world, format_table
from mocapdb.evaluation.world_scores import TrackFit, floor_errors, match_tracks, ratio_error_pct, score_take
from mocapdb.evaluation.world_takes import (
    ANKLES,
    BOX_HEIGHT_M,
    PersonSpec,
    WorldConfig,
    WorldScenario,
    build_take,
)

from .conftest import SAMPLE_BVH

HELDOUT = [SAMPLE_BVH / "005_01.bvh", SAMPLE_BVH / "006_02.bvh"]  # not in the small test database
ALL_KINDS = WorldScenario("all kinds, pitched 10 deg", (
    PersonSpec("adult", distance_m=6.0, lateral_m=-1.5),
    PersonSpec("child", kind="child", distance_m=5.5, lateral_m=0.5, heading_deg=180.0),
    PersonSpec("on box", still=True, support_m=BOX_HEIGHT_M, distance_m=5.0, lateral_m=2.0),
    PersonSpec("far", distance_m=15.0, lateral_m=-6.0, heading_deg=90.0),
    PersonSpec("partial", distance_m=5.0, edge_inside_m=0.15)), pitch_deg=10.0, noise_px=0.0, dropout=0.0, swap=0.0)
TINY = WorldConfig(scenarios=(ALL_KINDS,), repeats=1, frames=24)


@pytest.fixture(scope="module")
def truths():
    return load_heldout(HELDOUT, TINY.fps)


@pytest.fixture(scope="module")
def take(truths):
    return build_take(truths, ALL_KINDS, 0, 0, TINY)


def test_child_proportions_match_the_documented_figures():
    # data_specs/evaluation_bodies.md: sitting height 55.5 % of stature (child) against 52.5 % (adult),
    # 6.5 against 7.75 statures per head height
    assert CHILD_LEG_FACTOR == pytest.approx(0.445 / 0.475)
    assert CHILD_HEAD_FACTOR == pytest.approx(7.75 / 6.5)
    child = dict(zip(MEASURED_BONE_NAMES, child_proportions(universal_bone_lengths_m())))
    # universal legs 0.43 + 0.42 = 0.85 m → 0.79632; neck→nose hypot(0.19, 0.08) = 0.20616 → 0.24580;
    # the torso takes the difference: 0.52 + 0.05368 − 0.03964 = 0.53404
    assert child["thigh"] + child["shank"] == pytest.approx(0.79632, abs=2e-5)
    assert child["neck_nose"] == pytest.approx(0.24580, abs=2e-5)
    assert child["torso"] == pytest.approx(0.53404, abs=4e-5)
    for bone in ("upper_arm", "forearm", "hip_width", "shoulder_width"):
        assert child[bone] == pytest.approx(dict(zip(MEASURED_BONE_NAMES, universal_bone_lengths_m()))[bone])
    assert stature_m(np.array(list(child.values()))) == pytest.approx(1.75)


def test_sample_body_keeps_its_draws_and_takes_a_height_range():
    default = sample_body(np.random.default_rng(3))
    assert default.height_m == pytest.approx(np.random.default_rng(3).uniform(*HEIGHT_RANGE_M))
    heights = [sample_body(np.random.default_rng(i), CHILD_HEIGHT_RANGE_M).height_m for i in range(50)]
    assert min(heights) >= 1.0 and max(heights) <= 1.4 and max(heights) - min(heights) > 0.2


def test_take_people_have_their_bodies_places_and_visibility(take):
    by_role = {p.spec.role: p for p in take.people}
    assert 1.0 <= take.camera.height_m <= 2.0 and take.camera.pitch_deg == 10.0
    for person in take.people:  # the rendered bones are the body's, its stature as drawn
        lengths = bone_lengths_m(person.cam_m)
        assert np.ptp(lengths, axis=0).max() < 1e-9
        assert stature_m(lengths[0]) == pytest.approx(person.stature_m)
        low, high = CHILD_HEIGHT_RANGE_M if person.spec.kind == "child" else HEIGHT_RANGE_M
        assert low <= person.stature_m <= high
    # soles on the floor, the box person's on the box: the lowest ankle 8 cm × leg / universal leg above
    ankle = take.camera.heights_m(by_role["adult"].cam_m[:, ANKLES]).min()
    on_box = take.camera.heights_m(by_role["on box"].cam_m[:, ANKLES]).min()
    assert 0.8 * ANKLE_HEIGHT_M < ankle < 1.25 * ANKLE_HEIGHT_M
    assert 0.8 * ANKLE_HEIGHT_M < on_box - BOX_HEIGHT_M < 1.25 * ANKLE_HEIGHT_M
    assert np.array_equal(by_role["on box"].cam_m[0], by_role["on box"].cam_m[-1])  # held still
    far = np.linalg.norm(by_role["far"].cam_m[:, PELVIS] * [1.0, 0.0, 1.0], axis=-1)
    assert 14.0 < np.median(far) < 17.5
    # the partial person: keypoints outside the image, unseen; the others wholly inside
    partial = by_role["partial"]
    px = project(partial.cam_m[:, :N_KEYPOINTS_2D], TINY.focal_px, TINY.image_size)
    outside = (px[..., 0] < 0) | (px[..., 0] >= TINY.image_size[0])
    assert 0.05 < outside.mean() < 0.5
    assert partial.outside_share(TINY.focal_px, TINY.image_size) == pytest.approx(outside.mean())
    assert (partial.confidence[outside] == 0).all() and (partial.confidence[~outside] > 0).all()
    assert by_role["adult"].outside_share(TINY.focal_px, TINY.image_size) == 0.0
    assert all(len(frame.people) == len(take.people) for frame in take.frames)


def test_takes_are_deterministic(truths, take):
    again = build_take(truths, ALL_KINDS, 0, 0, TINY)
    assert again.camera == take.camera
    for a, b in zip(again.people, take.people):
        assert np.array_equal(a.cam_m, b.cam_m) and np.array_equal(a.points_px, b.points_px)
    other = build_take(truths, ALL_KINDS, 0, 1, TINY)
    assert other.camera.height_m != take.camera.height_m


def _fit(person, camera, track, scale=1.0, down_m=0.0, height_error_m=0.0):
    """A track that is the person's truth scaled by ``scale`` about the camera and moved ``down_m``
    along the true up, on a floor ``height_error_m`` further down than the true one."""
    up_cam = camera.up_view() * [1.0, 1.0, -1.0]
    joints = scale * person.cam_m - down_m * up_cam
    frames = np.arange(len(joints))
    return TrackFit(track, frames, joints, joints[:, PELVIS].copy(), scale * person.stature_m, camera.up_view(),
                    -camera.height_m - height_error_m, np.dstack([person.points_px, person.confidence]))


def test_the_truth_fed_as_the_fit_scores_no_error(take):
    fits = [_fit(p, take.camera, track=10 + i) for i, p in enumerate(take.people)]
    result = score_take(take, fits, TINY)
    assert [p["track"] for p in result["people"]] == [10, 11, 12, 13, 14]
    for person in result["people"]:
        assert person["stature_error_pct"] == pytest.approx(0.0, abs=1e-9)
        assert person["root_error_m"] == pytest.approx(0.0, abs=1e-9)
        assert person["camera_height_error_m"] == pytest.approx(0.0, abs=1e-9)
        assert person["floor_angle_deg"] == pytest.approx(0.0, abs=1e-4)
    assert max(result["pair_ratio_error_pct"]) == pytest.approx(0.0, abs=1e-9)
    assert not any(t["implausible"] for t in result["tracks"]) and result["false_tracks"] == 0


def test_a_person_ten_percent_too_big_about_the_camera(take):
    fits = [_fit(p, take.camera, track=i, scale=1.1 if i == 0 else 1.0) for i, p in enumerate(take.people)]
    result = score_take(take, fits, TINY)
    big = result["people"][0]
    assert big["stature_error_pct"] == pytest.approx(10.0)
    distance = np.linalg.norm(take.people[0].cam_m[:, PELVIS], axis=-1)
    assert big["root_error_m"] == pytest.approx(0.1 * np.median(distance))
    assert big["root_error_pct"] == pytest.approx(10.0)
    # every pair with the big person is 10 % off, the others exact
    assert sorted(result["pair_ratio_error_pct"])[-4:] == pytest.approx([10.0] * 4)
    assert sorted(result["pair_ratio_error_pct"])[:6] == pytest.approx([0.0] * 6, abs=1e-9)


def test_ratio_and_floor_errors_by_hand(take):
    assert ratio_error_pct(1.1, 1.0, 1.0, 1.0) == pytest.approx(10.0)
    assert ratio_error_pct(1.0, 1.1, 1.0, 1.0) == pytest.approx(10.0)  # either way round
    assert ratio_error_pct(1.8, 0.9, 1.6, 1.0) == pytest.approx(25.0)  # 2 against 1.6
    fit = _fit(take.people[0], take.camera, 0, height_error_m=0.1)
    tilt = np.radians(take.camera.pitch_deg + 2.0)
    fit.up_view = np.array([0.0, np.cos(tilt), np.sin(tilt)])
    height_error, angle = floor_errors(fit, take.camera)
    assert height_error == pytest.approx(0.1) and angle == pytest.approx(2.0)
    fit.up_view, fit.floor_offset_m = None, None
    assert np.isnan(floor_errors(fit, take.camera)).all()


def test_implausible_tracks_are_flagged(take):
    people = take.people
    behind = _fit(people[0], take.camera, 0)
    behind.root_m[5, 2] = -0.5
    sunk = _fit(people[1], take.camera, 1, down_m=0.2)     # 20 cm into the floor it stands on
    huge = _fit(people[3], take.camera, 3, scale=1.6)     # the far person at 2.4-3.1 m, feet under the floor
    floor_too_low = _fit(people[4], take.camera, 4, height_error_m=0.2)
    result = score_take(take, [behind, sunk, _fit(people[2], take.camera, 2), huge, floor_too_low], TINY)
    flags = [t["flags"] for t in result["tracks"]]
    assert flags[0] == {"out_of_range": False, "behind_camera": True, "below_fitted_floor": False,
                        "below_true_floor": False}
    assert flags[1]["below_fitted_floor"] and flags[1]["below_true_floor"] and not flags[1]["behind_camera"]
    assert not any(flags[2].values())  # the person on the box stands on the box, not under the floor
    assert flags[3]["out_of_range"] and flags[3]["below_true_floor"]
    assert not flags[4]["below_fitted_floor"] and not flags[4]["below_true_floor"]  # 20 cm above its floor
    assert [t["implausible"] for t in result["tracks"]] == [True, True, False, True, False]


def test_tracks_match_people_by_keypoints_and_a_stray_track_is_false(take):
    fits = [_fit(p, take.camera, track=i) for i, p in enumerate(take.people)]
    stray = _fit(take.people[0], take.camera, track=9)
    stray.keypoints = stray.keypoints + [2000.0, 0.0, 0.0]  # 2000 px aside: nobody's
    half = _fit(take.people[1], take.camera, track=7)
    for name in ("frames", "joints_m", "root_m", "keypoints"):  # a fragment of the child's track
        setattr(half, name, getattr(half, name)[12:])
    owners = match_tracks([*fits, stray, half], take.people, TINY.focal_px, TINY.image_size)
    assert owners == [0, 1, 2, 3, 4, None, 1]
    result = score_take(take, [*fits, stray, half], TINY)
    assert result["false_tracks"] == 1 and result["people"][1]["tracks"] == [1, 7]
    assert result["people"][1]["track"] == 1  # the longest


def test_end_to_end_on_the_small_database(small_db):
    config = replace(TINY, scenarios=(WorldScenario("two", (
        PersonSpec("adult", distance_m=6.0, lateral_m=-1.0),
        PersonSpec("bystander", still=True, distance_m=5.0, lateral_m=1.0)), noise_px=2.0),), frames=24)
    report = evaluate_world(small_db, HELDOUT, config)
    assert [(r["scenario"], r["mode"]) for r in report["summary"]] == [
        ("two", "camera_height_given"), ("two", "nothing_given")]
    assert len(report["takes"]) == 2 and all(len(t["people"]) == 2 for t in report["takes"])
    given = report["takes"][0]
    assert given["people"][0]["track"] is not None  # the walking person is tracked
    json.dumps(report)  # JSON-able
    table = format_table(report)
    assert "| two | given |" in table and "| two | not given |" in table and "| bystander | given |" in table
    lines = check_lines(report)
    assert len(lines) == 13 and all(line.split()[0] in ("PASS", "FAIL", "n/a") for line in lines)
    assert any(line.startswith("n/a") and "child" in line for line in lines)  # no child in this run


def test_eval_world_command_line(small_db_path, tmp_path, capsys):
    from mocapdb.cli.main import main

    assert main(["eval", "--world", str(HELDOUT[0])]) == 2  # no --db
    assert "--world needs --db" in capsys.readouterr().err
    assert main(["eval", "--db", str(small_db_path), "--world", str(HELDOUT[0]), "--bvh", str(HELDOUT[0])]) == 2
    assert main(["eval", "--db", str(small_db_path), "--world", str(tmp_path)]) == 2  # no BVH there
