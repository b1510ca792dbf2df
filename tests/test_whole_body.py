"""The parametrised whole-body families: across each parameter range (corners and middle, both
sides) every clip is physically plausible (check_motion), starts and ends standing still, and its
parameters do what they say; bad parameters raise ValueError naming the parameter."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from smpl_envs.humanoid.kinematics import forward_kinematics
from smpl_envs.humanoid.skeleton import BODY_NAMES, HINGE_NAMES, MEAN_SKELETON
from smpl_envs.motion import whole_body as wb
from smpl_envs.motion.kinematics import hinge_angles
from smpl_envs.motion.motion import FPS
from smpl_envs.motion.plausibility import GRAVITY, check_motion

PI = np.pi


def toe(raw, side):
    pos, _ = forward_kinematics(raw.root_pos, raw.local_quat, MEAN_SKELETON.offsets)
    return pos[:, BODY_NAMES.index(f"{side}_Toe")]


def assert_clip_basics(raw, allow_flight):
    report = check_motion(raw, allow_flight=allow_flight)
    assert report.ok, str(report)
    assert raw.fps == FPS and raw.source == "smpl_envs.motion.whole_body"
    assert 2.0 <= (raw.num_frames - 1) / raw.fps <= 10.0
    # Standing still at both ends (so clips chain): no joint or pelvis motion over 0.3 s.
    for ends in (slice(0, 10), slice(-10, None)):
        assert np.ptp(raw.root_pos[ends], axis=0).max() < 1e-4
        assert np.ptp(raw.local_quat[ends], axis=0).max() < 1e-4
    return report


# ----------------------------------------------------------------------------- kick

@lru_cache(maxsize=None)
def kick(side, height, where, tempo=1.0):
    lo, hi = wb.kick_reach_range(height, side, tempo)
    reach = {"short": lo, "mid": 0.5 * (lo + hi), "long": hi}[where]
    return reach, wb.kick(side, height, reach, tempo)


KICKS = [(side, h, where, 1.0) for side in "LR" for h in (0.2, 0.55, 0.9) for where in ("short", "mid", "long")]
KICKS += [(side, 0.55, "mid", tempo) for side in "LR" for tempo in (0.7, 1.4)]


@pytest.mark.parametrize("side, height, where, tempo", KICKS)
def test_kick(side, height, where, tempo):
    reach, raw = kick(side, height, where, tempo)
    assert_clip_basics(raw, allow_flight=False)
    foot = toe(raw, side)
    i = int(round(1.7 / tempo * FPS))  # full extension
    assert foot[i, 2] == pytest.approx(height, abs=0.03)
    assert foot[i, 0] - foot[0, 0] == pytest.approx(reach, abs=0.03)
    assert np.abs(foot[:, 2]).max() == pytest.approx(height, abs=0.03)  # the highest point
    standing = toe(raw, "L" if side == "R" else "R")
    assert np.ptp(standing, axis=0).max() < 1e-6  # the other foot stays put


def test_kick_reach_range_bounds_the_knee():
    for side, height in (("R", 0.2), ("L", 0.9)):
        for where, knee in (("short", 80), ("long", 10)):
            _, raw = kick(side, height, where)
            knee_y = HINGE_NAMES.index(f"{side}_Knee_y")
            flex = np.degrees(hinge_angles(raw.local_quat)[int(1.7 * FPS), knee_y])
            assert flex == pytest.approx(knee, abs=3)


def test_kicks_mirror():
    _, right = kick("R", 0.55, "mid")
    _, left = kick("L", 0.55, "mid")
    # The pelvis sways to the standing side: opposite ways for the two legs, as far.
    assert right.root_pos[60, 1] > 0.05 and left.root_pos[60, 1] < -0.05
    assert right.root_pos[60, 1] == pytest.approx(-left.root_pos[60, 1], abs=0.01)


# ----------------------------------------------------------------------------- squat

SQUATS = [(d, 1.0, 0.5, w, None) for d in (0.05, 0.15, 0.25) for w in (0.08, 0.14)]
SQUATS += [(0.15, desc, hold, 0.12, asc) for desc, hold, asc in ((0.5, 0.0, 2.0), (2.0, 2.0, 0.5))]


@pytest.mark.parametrize("depth, descent, hold, width, ascent", SQUATS)
def test_squat(depth, descent, hold, width, ascent):
    raw = wb.squat(depth, descent, hold, width, ascent)
    assert_clip_basics(raw, allow_flight=False)
    z = raw.root_pos[:, 2]
    assert z[0] - z.min() == pytest.approx(depth, abs=0.002)
    # At the bottom from the end of the descent to the end of the hold.
    lead = 0.6
    bottom = np.flatnonzero(z < z.min() + 1e-4) / FPS
    assert bottom.min() == pytest.approx(lead + descent, abs=0.1)
    assert bottom.max() == pytest.approx(lead + descent + hold, abs=0.1)
    ascent = descent if ascent is None else ascent
    assert (raw.num_frames - 1) / FPS == pytest.approx(lead + descent + hold + ascent + 1.1, abs=1e-9)
    for side in "LR":
        assert np.ptp(toe(raw, side), axis=0).max() < 1e-6  # feet planted
        assert abs(toe(raw, side)[0, 1]) == pytest.approx(width, abs=1e-6)


# ----------------------------------------------------------------------------- lunge

LUNGES = [(side, length, depth) for side in "LR" for length in (0.5, 0.7, 0.9) for depth in (0.12, 0.3)]


@pytest.mark.parametrize("side, length, depth", LUNGES)
def test_lunge(side, length, depth):
    raw = wb.lunge(side, length, depth)
    assert_clip_basics(raw, allow_flight=False)
    back_side = "R" if side == "L" else "L"
    front, back = toe(raw, side), toe(raw, back_side)
    hold = int(3.0 * FPS)
    assert front[hold, 0] - front[0, 0] == pytest.approx(length, abs=0.005)
    assert np.abs(front[-1] - front[0]).max() < 1e-6  # stepped back where it was
    assert np.ptp(back, axis=0).max() < 1e-6  # the back foot's ball stays put
    assert front[:, 2].max() - front[0, 2] > 0.03  # a swing, not a slide
    z = raw.root_pos[:, 2]
    assert z[0] - z[hold] == pytest.approx(depth, abs=0.002)
    # The back heel is up at the bottom: the back ankle rises above its standing height.
    pos, _ = forward_kinematics(raw.root_pos, raw.local_quat, MEAN_SKELETON.offsets)
    ankle = pos[:, BODY_NAMES.index(f"{back_side}_Ankle"), 2]
    assert ankle[hold] - ankle[0] > 0.05


def test_lunge_depth_min_grows_with_length():
    lows = [wb.lunge_depth_min(length) for length in (0.5, 0.7, 0.9)]
    assert lows == sorted(lows) and lows[-1] < wb.RANGES["lunge"]["depth"][0]


# ----------------------------------------------------------------------------- jump and hop

JUMPS = [(f, d, a, c) for f in (0.25, 0.5) for d in (0.0, 0.8) for a in (0.0, PI / 2, PI, -2.5) for c in (1, 3)
         if not (d == 0.0 and a != 0.0)]
JUMPS += [(0.4, 0.4, 1.0, 2)]


@pytest.mark.parametrize("flight, distance, direction, count", JUMPS)
def test_jump(flight, distance, direction, count):
    raw = wb.jump(flight, distance, direction, count)
    report = assert_clip_basics(raw, allow_flight=True)
    assert len(report.flight_phases) == count
    travelled = raw.root_pos[-1, :2] - raw.root_pos[0, :2]
    u = np.array([np.cos(direction), np.sin(direction)])
    np.testing.assert_allclose(travelled, count * distance * u, atol=0.01)
    z = raw.root_pos[:, 2]
    for k in range(count):
        take_off = int(round((0.5 + 0.9 + 2.6 * k) * FPS))
        apex = z[take_off: take_off + int(flight * FPS) + 1].max() - z[take_off]
        assert apex == pytest.approx(GRAVITY * flight ** 2 / 8, abs=0.003)
    # The body keeps facing +x.
    w, x, y, zq = raw.local_quat[:, 0].T
    assert np.abs(np.arctan2(2 * (w * zq + x * y), 1 - 2 * (y * y + zq * zq))).max() < 1e-6


HOPS = [("L", 1, 0.15, 0.0, 0.0), ("R", 1, 0.3, 0.4, 0.0), ("L", 4, 0.3, 0.0, 0.0), ("R", 4, 0.15, 0.4, PI / 2),
        ("L", 3, 0.22, 0.2, PI), ("R", 2, 0.3, 0.4, -2.5), ("L", 4, 0.15, 0.4, 2.0),
        ("L", 3, 0.1834, 0.2231, -3.065)]  # take-offs between frames: the foot once dipped 1 cm


@pytest.mark.parametrize("side, count, flight, distance, direction", HOPS)
def test_hop(side, count, flight, distance, direction):
    raw = wb.hop(side, count, flight, distance, direction)
    report = assert_clip_basics(raw, allow_flight=True)
    assert len(report.flight_phases) == count
    u = np.array([np.cos(direction), np.sin(direction)])
    np.testing.assert_allclose(raw.root_pos[-1, :2] - raw.root_pos[0, :2], count * distance * u, atol=0.01)
    hopping, free = toe(raw, side), toe(raw, "R" if side == "L" else "L")
    np.testing.assert_allclose(hopping[-1, :2] - hopping[0, :2], count * distance * u, atol=1e-6)
    # The free foot is off the floor all through the hops.
    hops = slice(int(1.6 * FPS), int((2.1 + count * (flight + 0.3)) * FPS))
    assert free[hops, 2].min() - free[0, 2] > 0.05


# ----------------------------------------------------------------------------- validation

BAD = [
    (wb.kick, {"height": 0.1}, "height"), (wb.kick, {"height": np.nan}, "height"),
    (wb.kick, {"reach": 1.5}, "reach"), (wb.kick, {"reach": np.nan}, "reach"),
    (wb.kick, {"tempo": 3.0}, "tempo"), (wb.kick, {"side": "X"}, "side"),
    (wb.squat, {"depth": 0.5}, "depth"), (wb.squat, {"depth": np.nan}, "depth"),
    (wb.squat, {"descent": 0.1}, "descent"), (wb.squat, {"hold": -1.0}, "hold"),
    (wb.squat, {"width": np.inf}, "width"), (wb.squat, {"ascent": 5.0}, "ascent"),
    (wb.lunge, {"length": 1.2}, "length"), (wb.lunge, {"depth": 0.01}, "depth"),
    (wb.lunge, {"depth": np.nan}, "depth"), (wb.lunge, {"side": None}, "side"),
    (wb.jump, {"flight": 1.0}, "flight"), (wb.jump, {"distance": -0.1}, "distance"),
    (wb.jump, {"direction": 4.0}, "direction"), (wb.jump, {"count": 0}, "count"),
    (wb.jump, {"count": 1.5}, "count"), (wb.jump, {"flight": np.nan}, "flight"),
    (wb.hop, {"count": 5}, "count"), (wb.hop, {"flight": 0.1}, "flight"),
    (wb.hop, {"distance": 0.5}, "distance"), (wb.hop, {"direction": np.nan}, "direction"),
    (wb.hop, {"side": "left"}, "side"), (wb.squat, {"depth": "deep"}, "depth"),
]


@pytest.mark.parametrize("family, kwargs, name", BAD, ids=[f"{f.__name__}-{n}-{i}" for i, (f, _, n) in enumerate(BAD)])
def test_bad_parameters_raise_naming_the_parameter(family, kwargs, name):
    with pytest.raises(ValueError, match=name):
        family(**kwargs)


def test_ranges_are_stated_for_every_numeric_parameter():
    assert set(wb.RANGES) == {"kick", "squat", "lunge", "jump", "hop"}
    for family, ranges in wb.RANGES.items():
        for lo, hi in ranges.values():
            assert lo < hi, family


def test_deterministic():
    a, b = wb.hop("R", 2, 0.2, 0.3, 0.5), wb.hop("R", 2, 0.2, 0.3, 0.5)
    assert np.array_equal(a.root_pos, b.root_pos) and np.array_equal(a.local_quat, b.local_quat)


def random_members(seed: int = 7, per_family: int = 4):
    """A few members drawn uniformly from each family's ranges (the grid above has corners and
    middles; a corpus samples the interior)."""
    rng = np.random.default_rng(seed)
    draw = lambda family, name: float(rng.uniform(*wb.RANGES[family][name]))  # noqa: E731
    members = []
    for _ in range(per_family):
        side = str(rng.choice(["L", "R"]))
        height, tempo = draw("kick", "height"), draw("kick", "tempo")
        reach = float(rng.uniform(*wb.kick_reach_range(height, side, tempo)))
        members.append((wb.kick, dict(side=side, height=height, reach=reach, tempo=tempo), False))
        members.append((wb.squat, {k: draw("squat", k) for k in wb.RANGES["squat"]}, False))
        members.append((wb.lunge, dict(side=side, length=draw("lunge", "length"), depth=draw("lunge", "depth")), False))
        for family in (wb.jump, wb.hop):
            ranges = wb.RANGES[family.__name__]
            kwargs = {k: draw(family.__name__, k) for k in ranges if k != "count"}
            kwargs["count"] = int(rng.integers(ranges["count"][0], ranges["count"][1] + 1))
            members.append((family, kwargs, True))
    return members


RANDOM = random_members()


@pytest.mark.parametrize("family, kwargs, allow_flight", RANDOM,
                         ids=[f"{family.__name__}-{i}" for i, (family, _, _) in enumerate(RANDOM)])
def test_random_members_are_plausible(family, kwargs, allow_flight):
    raw = family(**kwargs)
    report = assert_clip_basics(raw, allow_flight)
    if allow_flight:
        assert len(report.flight_phases) == kwargs["count"]
