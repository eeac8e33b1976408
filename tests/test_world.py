"""The take's world (runtime/world/fuse.py) on hand-built evidence with a known truth: people standing or
walking on a floor seen by one camera, their contacts as the whole-take fit would report them at
the nominal size (each true contact scaled about the camera by 1.75 m / its person's stature)."""
from dataclasses import replace

import numpy as np
import pytest

from mocapdb.core.skeleton import ANKLE_HEIGHT_M, UNIVERSAL_HEIGHT_M
from mocapdb.runtime.world.fuse import TrackEvidence, estimate_world, floor_stature_m
from mocapdb.runtime.world.stature import HUMAN_STATURE_M
from mocapdb.runtime.world.tilt import height_spread_log, tilt_spread_deg, track_tilt_sd_deg


def _normal(pitch_deg: float) -> np.ndarray:
    """The world's up in the view frame of a camera pitched down by ``pitch_deg``."""
    t = np.radians(pitch_deg)
    return np.array([0.0, np.cos(t), np.sin(t)])


def _person(track: int, stature_m: float, x_m: float, depth_m: float, camera_height_m: float, pitch_deg: float,
            rng: np.random.Generator, walk_m: float = 1.0, raised_m: float = 0.0, n: int = 120,
            given: float | None = None, up_error_deg: float = 0.0, in_depth: bool = False) -> TrackEvidence:
    """One person's evidence: ``n`` contacts of a walk ``walk_m`` long across the view (or in depth)
    about ``x_m`` (metres right), ``depth_m`` in front, on the floor (or ``raised_m`` above it), 1 cm
    noise; the track's up estimate ``up_error_deg`` off in pitch."""
    up = _normal(pitch_deg)
    forward = np.cross(up, [1.0, 0.0, 0.0])  # horizontal, away from the camera (−z of the view frame)
    across = np.cross(forward, up)
    along = np.linspace(-walk_m / 2, walk_m / 2, n)[:, None] * (forward if in_depth else across)
    ankle = ANKLE_HEIGHT_M * stature_m / UNIVERSAL_HEIGHT_M
    true = (along + x_m * across + depth_m * forward
            + (-camera_height_m + raised_m + ankle) * up + rng.normal(0.0, 0.01, (n, 3)))
    nominal = true * (UNIVERSAL_HEIGHT_M / stature_m)
    # the track's up is the body's own estimate; its contacts vote through their flatness
    return TrackEvidence(track, UNIVERSAL_HEIGHT_M, nominal, _normal(pitch_deg + up_error_deg), 3.0, given)


def test_a_child_beside_adults_keeps_their_sizes_with_and_without_the_camera_height():
    rng = np.random.default_rng(0)
    truth = {1: 1.82, 2: 1.64, 3: 1.12}
    people = [_person(t, s, x, d, 1.6, 10.0, rng) for (t, s), x, d in zip(truth.items(), (-1.5, 0.5, 1.8), (5, 6, 4))]
    given = estimate_world(people, camera_height_m=1.6)
    for track, stature in truth.items():
        assert given.people[track].kind == "floor"
        assert given.people[track].stature_m == pytest.approx(stature, rel=0.02)
    assert given.pitch_deg == pytest.approx(10.0, abs=0.5)
    free = estimate_world(people)
    sizes = {t: free.people[t].stature_m for t in truth}
    assert sizes[3] / sizes[1] == pytest.approx(truth[3] / truth[1], rel=0.05)  # the floor ties them together
    assert sizes[2] / sizes[1] == pytest.approx(truth[2] / truth[1], rel=0.05)
    for track, stature in truth.items():
        assert sizes[track] == pytest.approx(stature, rel=0.10)
    assert free.camera_height_m == pytest.approx(1.6, rel=0.15)  # from the people: the prior holds children too
    assert free.camera_height_log_sd > 0.0  # not given: estimated with an error (wide: children or adults?)


def test_a_person_on_a_box_does_not_drag_the_others_and_stands_on_its_box():
    rng = np.random.default_rng(1)
    floor = [_person(1, 1.70, -1.0, 5.0, 1.5, 5.0, rng), _person(2, 1.60, 1.2, 6.5, 1.5, 5.0, rng)]
    box = _person(3, 1.75, 0.0, 4.0, 1.5, 5.0, rng, walk_m=0.3, raised_m=0.4)
    world = estimate_world([*floor, box], camera_height_m=1.5)
    assert world.people[3].kind == "elevated"
    assert world.people[3].feet_above_floor_m == pytest.approx(0.4, abs=0.1)
    # the camera height ties size to pitch (1° moves a person 5 m away by ~6 %): the tilt estimate's
    # 3° let the stature prior pull both towards 1.75 m
    assert world.people[1].stature_m == pytest.approx(1.70, rel=0.06)
    assert world.people[2].stature_m == pytest.approx(1.60, rel=0.08)
    alone = estimate_world(floor, camera_height_m=1.5)  # as if the box person were not there
    free, free_alone = estimate_world([*floor, box]), estimate_world(floor)
    for track in (1, 2):
        assert world.people[track].stature_m == pytest.approx(alone.people[track].stature_m, rel=0.01)
        assert free.people[track].stature_m == pytest.approx(free_alone.people[track].stature_m, rel=0.02)


def test_contacts_above_the_camera_never_give_a_negative_or_absurd_size():
    """A false detection whose 'contacts' lie above the camera (no floor can be under them) and one
    whose floor would make it 0.3 m tall: both keep a human size; the real person is untouched."""
    rng = np.random.default_rng(2)
    person = _person(1, 1.75, 0.0, 5.0, 1.6, 0.0, rng)
    above = TrackEvidence(2, UNIVERSAL_HEIGHT_M, np.column_stack([np.linspace(-1, 1, 50), np.full(50, 0.5),
                                                                  np.full(50, -6.0)]), _normal(0.0), 3.0)
    tiny = _person(3, 1.75, 2.0, 8.0, 1.6, 0.0, rng)
    tiny = TrackEvidence(3, UNIVERSAL_HEIGHT_M, tiny.contacts_m * 6.0, tiny.up, 3.0)  # floor 6x too far down
    world = estimate_world([person, above, tiny], camera_height_m=1.6)
    for size in world.people.values():
        assert size.scale_factor > 0
        assert HUMAN_STATURE_M[0] <= size.stature_m <= HUMAN_STATURE_M[1]
    assert world.people[2].kind == "unreliable"
    assert world.people[1].stature_m == pytest.approx(1.75, rel=0.02)


def test_the_camera_height_fixes_the_size_and_the_pitch_the_tilt_estimate_missed():
    """One person of 1.58 m walking 3 m towards the camera (the contacts fix the floor's pitch), the
    camera's tilt estimate 5° off: nothing given, the size is the prior's (and said so); with the
    camera height it is the person's own."""
    rng = np.random.default_rng(3)
    person = _person(1, 1.58, 0.3, 6.0, 1.7, 12.0, rng, walk_m=3.0, up_error_deg=-5.0, in_depth=True)
    free = estimate_world([person])
    assert free.people[1].source == "prior"
    assert 1.65 <= free.people[1].stature_m <= 1.80
    given = estimate_world([person], camera_height_m=1.7)
    assert given.people[1].source == "floor"
    assert abs(given.people[1].stature_m - 1.58) < abs(free.people[1].stature_m - 1.58)
    assert given.people[1].stature_m == pytest.approx(1.58, rel=0.03)
    assert given.pitch_deg == pytest.approx(12.0, abs=1.0)


def test_one_persons_given_height_sizes_everyone_on_the_floor():
    """Two people side by side (one depth: the pitch does not change their ratio), one height given."""
    rng = np.random.default_rng(4)
    a = _person(1, 1.62, -1.2, 6.0, 1.4, 8.0, rng, given=1.62, walk_m=2.0)
    b = _person(2, 1.93, 1.2, 6.0, 1.4, 8.0, rng, walk_m=2.0)
    world = estimate_world([a, b])
    assert world.people[1].source == "given" and world.people[1].stature_m == pytest.approx(1.62, rel=0.01)
    # its own size's error (3 %: the body's fit) lets the prior pull it in a little
    assert world.people[2].stature_m == pytest.approx(1.93, rel=0.06)
    # the camera height trades with the tilt, known to 2° about the axis a walk fixes: within 10 %
    assert world.camera_height_m == pytest.approx(1.4, rel=0.10)


def test_tracks_without_contacts_take_the_priors_size():
    empty = TrackEvidence(7, UNIVERSAL_HEIGHT_M, np.zeros((0, 3)), _normal(0.0), 3.0)
    world = estimate_world([empty])
    assert world.people[7].kind == "no contacts" and world.people[7].source == "prior"
    assert 1.65 <= world.people[7].stature_m <= 1.80


def test_a_world_without_a_floor_still_says_its_tilt_and_whence():
    """The summary line of a take with no planted foot (a photo) gives the people's tilt, flagged unchecked."""
    from mocapdb.runtime.world.summary import world_line

    rolled = np.array([-np.sin(np.radians(12.0)), np.cos(np.radians(12.0)), 0.0])   # up leaning to the left
    world = estimate_world([TrackEvidence(7, UNIVERSAL_HEIGHT_M, np.zeros((0, 3)), rolled, 3.0)])
    assert world_line(world) == ("world: no floor found (no planted foot, no --camera-height): each track's size is "
                                 "the prior's; camera pitched 0.0 deg down, roll 12.0 deg, from the people alone: "
                                 "no floor checks it")


def test_a_person_cut_by_the_image_edge_does_not_drag_the_others():
    """A partial body misjudges its own depth (its nominal contacts 35 % too near): it comes out
    unreliable or sized apart, and the two whole people keep the sizes they have without it."""
    rng = np.random.default_rng(5)
    whole = [_person(1, 1.80, -1.0, 5.0, 1.5, 10.0, rng, walk_m=2.0),
             _person(2, 1.62, 1.5, 7.0, 1.5, 10.0, rng, walk_m=2.0)]
    cut = _person(3, 1.70, -2.5, 6.0, 1.5, 10.0, rng, walk_m=2.0)
    cut = TrackEvidence(3, UNIVERSAL_HEIGHT_M, cut.contacts_m * 0.65, cut.up, 3.0)
    for height in (1.5, None):
        alone, world = estimate_world(whole, height), estimate_world([*whole, cut], height)
        for track in (1, 2):
            assert world.people[track].stature_m == pytest.approx(alone.people[track].stature_m, rel=0.02)
        assert HUMAN_STATURE_M[0] <= world.people[3].stature_m <= HUMAN_STATURE_M[1]


def test_a_walk_whose_depth_drifts_does_not_tilt_the_world():
    """A 1.75 m person walking 3 m away from a camera 1.6 m high, pitched 10°, in six steps whose
    contacts lie on a line tilted 4° (the depth's drift along a walk seen from behind: its strides
    come out short, so the far contacts rise): the body's own up is right. With the camera height
    given, the world keeps the pitch within 1° and the size within 8 %; when the line's normal
    stood in for the body's up it took the 4° and made the person 1.33 m."""
    rng = np.random.default_rng(5)
    up = _normal(10.0)
    forward = np.cross(up, [1.0, 0.0, 0.0])
    along = np.repeat(np.linspace(-1.5, 1.5, 6), 15)   # six steps, 15 planted frames each
    rise = np.tan(np.radians(4.0)) * along
    contacts = ((along + 7.0)[:, None] * forward + (-1.6 + ANKLE_HEIGHT_M + rise)[:, None] * up
                + np.repeat(rng.normal(0.0, 0.01, (6, 3)), 15, axis=0))
    world = estimate_world([TrackEvidence(1, UNIVERSAL_HEIGHT_M, contacts, up, 3.0)], camera_height_m=1.6)
    assert world.pitch_deg == pytest.approx(10.0, abs=1.0)
    assert world.people[1].stature_m == pytest.approx(UNIVERSAL_HEIGHT_M, rel=0.08)


def test_floor_stature_puts_the_contacts_on_the_floor_it_is_given():
    # contacts 1.0 m below a level camera at the nominal 1.75 m: the floor 0.08 m lower (the ankle's
    # height); on a floor 1.62 m down the body scales by 1.62 / 1.08
    contacts = np.column_stack([np.linspace(-1.0, 1.0, 40), np.full(40, -1.0), np.linspace(-4.0, -6.0, 40)])
    e = TrackEvidence(1, UNIVERSAL_HEIGHT_M, contacts, _normal(0.0), 3.0)
    assert floor_stature_m(e, _normal(0.0), 1.62) == pytest.approx(1.75 * 1.62 / (1.0 + ANKLE_HEIGHT_M))
    # the same contacts under a camera pitched 10 deg: each contact's depth below it is −p · up
    depth = np.median(-(contacts @ _normal(10.0))) + ANKLE_HEIGHT_M
    assert floor_stature_m(e, _normal(10.0), 1.62) == pytest.approx(1.75 * 1.62 / depth)
    assert np.isnan(floor_stature_m(e, -_normal(0.0), 1.62))  # a floor above the contacts


def test_a_tracks_tilt_error_falls_with_its_strides_not_its_frames():
    # one posture (a person standing still: two footfalls) errs by the posture's 6 deg whatever its
    # frames' spread; a walker's 14 footfalls are 7 strides: 6.8 / sqrt(7); 3 deg stays
    assert track_tilt_sd_deg(4.0, 2) == pytest.approx(np.hypot(3.0, 6.0))
    assert track_tilt_sd_deg(4.0, 0) == pytest.approx(np.hypot(3.0, 6.0))
    assert track_tilt_sd_deg(6.8, 14) == pytest.approx(np.hypot(3.0, 6.8 / np.sqrt(7.0)))
    assert track_tilt_sd_deg(12.0, 2) == pytest.approx(np.hypot(3.0, 12.0))
    # three strides whose frames agree within 2 deg: a posture's floor is 6 / 3 deg, over sqrt(3)
    assert track_tilt_sd_deg(2.0, 6) == pytest.approx(np.hypot(3.0, 2.0 / np.sqrt(3.0)))


def test_a_still_persons_leaning_posture_does_not_tilt_the_world_of_a_walker():
    """A person standing still at 5 m (both feet planted all take: twice the walker's contacts) whose
    one posture reads the pitch 8 deg low, beside a walker at 7 m (half a metre: no floor's slope)
    whose strides read it right; nothing given. The tracks' up estimates count by their errors (the
    still one's posture's 6.7 deg, the walker's 4 deg): pitch 1.6 deg and camera height 10 % off.
    Counted by their contacts, they put the pitch 2.7 deg and the height 18 % off."""
    rng = np.random.default_rng(7)
    walker = _person(1, 1.70, 0.5, 7.0, 1.5, 10.0, rng, walk_m=0.5, n=72)
    still = _person(2, 1.75, -1.0, 5.0, 1.5, 10.0, rng, walk_m=0.0, n=144, up_error_deg=-8.0)
    walker = replace(walker, up_sd_deg=track_tilt_sd_deg(6.8, 14))
    still = replace(still, up_sd_deg=track_tilt_sd_deg(4.0, 2))
    world = estimate_world([walker, still])
    assert world.pitch_deg == pytest.approx(10.0, abs=2.0)
    assert world.camera_height_m == pytest.approx(1.5, rel=0.12)


def _with_strays(e: TrackEvidence, share: float, drop_m: float, rng: np.random.Generator) -> TrackEvidence:
    """``e`` with ``share`` of its contacts more (at its end) whose depth drifts: each one further
    along its viewing ray, so that it sinks up to ``drop_m`` below the floor (as an ankle's depth
    drifts while its body leaves the image)."""
    strays = e.contacts_m[rng.choice(len(e.contacts_m), int(share * len(e.contacts_m)))]
    below = -(strays @ e.up)                              # how far below the camera each one is
    stretch = 1.0 + np.linspace(0.3, 1.0, len(strays)) * drop_m / below
    return TrackEvidence(e.track, e.nominal_stature_m, np.concatenate([e.contacts_m, strays * stretch[:, None]]),
                         e.up, e.up_sd_deg, e.given_stature_m)


def test_the_floor_is_the_level_most_contacts_stand_on_not_a_few_strays_below():
    """A tenth of a track's contacts sinking 10-35 cm below the rest (its 5th percentile, which set
    the floor before, among them): its floor-consistent stature and the world stay as without them
    (before: the strays' median was taken for the floor, the stature 9 % off on a real take)."""
    rng = np.random.default_rng(7)
    people = [_person(1, 1.80, -0.8, 4.0, 1.9, 22.0, rng, walk_m=0.4), _person(2, 1.65, 1.0, 7.0, 1.9, 22.0, rng)]
    strayed = [_with_strays(people[0], 0.1, 0.35, rng), people[1]]
    for given in (1.9, None):
        clean, noisy = estimate_world(people, given), estimate_world(strayed, given)
        assert noisy.camera_height_m == pytest.approx(clean.camera_height_m, rel=0.02)
        assert noisy.pitch_deg == pytest.approx(clean.pitch_deg, abs=0.3)
        assert noisy.people[1].stature_m == pytest.approx(clean.people[1].stature_m, rel=0.02)
    assert estimate_world(strayed, 1.9).people[1].stature_m == pytest.approx(1.80, rel=0.04)


def test_the_reported_spreads_are_the_posteriors_by_hand_on_a_tiny_grid():
    """Two tilts and three log heights, the posterior exp(−cost) by hand: the height's SD over the
    column sums, the tilt's over the row sums (at least the grid's step over √12)."""
    log_h = np.log([1.5, 2.0, 2.5])
    tilts = np.array([[0.0, 0.0], [4.0, -2.0]])
    cost = np.array([[0.0, np.log(2.0), np.log(4.0)],       # weights 1, 1/2, 1/4: 1.75 in all
                     [np.log(4.0), 0.0, np.log(4.0)]])       # weights 1/4, 1, 1/4: 1.5 in all
    heights = np.array([1.25, 1.5, 0.5]) / 3.25
    mean = heights @ log_h
    assert height_spread_log(log_h, cost) == pytest.approx(np.sqrt(heights @ (log_h - mean) ** 2), abs=1e-12)
    rows = np.array([1.75, 1.5]) / 3.25                      # the tilts' weights
    sd = np.sqrt(rows[0] * rows[1]) * np.array([4.0, 2.0])   # two points: SD = √(p q) × their distance
    assert tilt_spread_deg(tilts, cost, 0.5) == pytest.approx(tuple(sd), abs=1e-12)
    assert tilt_spread_deg(tilts[:1], cost[:1], 2.0) == pytest.approx((2.0 / np.sqrt(12.0),) * 2)


def test_two_equally_likely_heights_report_the_spread_between_them():
    """A posterior with two modes as likely, 1.2 m and 2.4 m apart by a factor of 2: the reported
    SD of the log height is half their distance, so ±2 SD about either holds the other."""
    log_h = np.linspace(np.log(0.5), np.log(5.0), 901)
    two = np.logaddexp(-0.5 * ((log_h - np.log(1.2)) / 0.05) ** 2, -0.5 * ((log_h - np.log(2.4)) / 0.05) ** 2)
    spread = height_spread_log(log_h, -two[None])
    assert spread == pytest.approx(np.hypot(np.log(2.0) / 2, 0.05), rel=0.01)
    assert 2 * spread > np.log(2.0)
