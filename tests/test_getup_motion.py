"""The get-up generator (smpl_envs.motion.getup): from lying on the front or the back to standing,
physically plausible by the corpus' own checks, and strict about its parameters."""

from __future__ import annotations

import numpy as np
import pytest

from smpl_envs.humanoid.kinematics import forward_kinematics
from smpl_envs.humanoid.skeleton import BODY_NAMES, MEAN_SKELETON
from smpl_envs.motion import getup as gu
from smpl_envs.motion.getup import getup, phases
from smpl_envs.motion.plausibility import check_motion
from smpl_envs.rotations import quat_apply

HEAD = BODY_NAMES.index("Head")
KNEES = [BODY_NAMES.index(f"{s}_Knee") for s in "LR"]
SHOULDERS = [BODY_NAMES.index(f"{s}_Shoulder") for s in "LR"]


@pytest.mark.parametrize("start,side,roll", [("front", "L", "L"), ("front", "R", "L"), ("back", "L", "R"),
                                             ("back", "R", "L")])
def test_a_getup_goes_from_the_floor_to_standing_and_is_plausible(start, side, roll):
    raw = getup(start, side, roll)
    report = check_motion(raw)
    assert report.ok, report.violations
    pos, quat = forward_kinematics(raw.root_pos, raw.local_quat, MEAN_SKELETON.offsets)
    up = quat_apply(quat[:, 0], np.array([0.0, 0.0, 1.0]))  # the pelvis' up axis
    assert pos[0, HEAD, 2] < 0.25 and abs(up[0, 2]) < 0.3  # lying: head low, body horizontal
    face = quat_apply(quat[0, 0], np.array([1.0, 0.0, 0.0]))  # the pelvis' forward axis
    assert (face[2] < -0.7) if start == "front" else (face[2] > 0.7)  # face down / face up
    assert pos[-1, HEAD, 2] > 1.4 and up[-1, 2] > 0.99  # standing upright at the end
    still = np.linalg.norm(np.diff(raw.root_pos[-10:], axis=0), axis=-1) * raw.fps
    assert still.max() < 0.02  # and still, so the clip chains


@pytest.mark.parametrize("start", ["front", "back"])
def test_the_phases_tile_the_clip_in_order(start):
    spans = phases(start, tempo=1.1)
    names = list(spans)
    assert names == [p for p in gu._PHASES if p in spans] and ("roll" in spans) == (start == "back")
    assert all(a < b for a, b in spans.values())
    assert all(spans[p][1] == spans[q][0] for p, q in zip(names, names[1:]))
    assert names[0] == "lie" and spans["lie"][0] == 0
    raw = getup(start, tempo=1.1)
    assert raw.num_frames == round(spans[names[-1]][1] * raw.fps) + 1


def test_pushing_onto_hands_and_knees_the_knees_slide_half_way(monkeypatch):
    def travel(slide):  # how far the knees and the shoulders move over the push (xy)
        monkeypatch.setattr(gu, "_KNEE_SLIDE", slide)
        raw = getup("front")
        pos, _ = forward_kinematics(raw.root_pos, raw.local_quat, MEAN_SKELETON.offsets)
        a, b = (round(t * raw.fps) for t in phases("front")["push"])
        return [pos[b, i, :2].mean(0) - pos[a, i, :2].mean(0) for i in (KNEES, SHOULDERS)]

    knees0, shoulders0 = travel(0.0)
    knees, shoulders = travel(gu._KNEE_SLIDE)
    # pinned on the legs' contacts, the knees roll a few cm on the floor and the upper body moves the whole way
    assert np.linalg.norm(knees0) < 0.08 and np.linalg.norm(shoulders0) > 0.3
    np.testing.assert_allclose(shoulders, (1 - gu._KNEE_SLIDE) * shoulders0, atol=0.01)
    np.testing.assert_allclose(knees - knees0, -gu._KNEE_SLIDE * shoulders0, atol=0.01)


@pytest.mark.parametrize("roll", ["L", "R"])
def test_rolling_from_the_back_the_top_foot_pushes_from_a_floor_point_while_the_pelvis_turns(roll):
    raw = getup("back", roll=roll, tempo=2.0, lie=0.3)
    pos, quat = forward_kinematics(raw.root_pos, raw.local_quat, MEAN_SKELETON.offsets)
    a, b = phases("back", roll=roll, tempo=2.0, lie=0.3)["roll"]
    share = lambda u: round((a + u * (b - a)) * raw.fps)  # noqa: E731
    pushing = slice(share(gu._ROLL["plant"][1]), share(gu._ROLL["push"]) + 1)
    top = BODY_NAMES.index(f"{'R' if roll == 'R' else 'L'}_Ankle")
    ankle = pos[pushing, top]
    # the top leg is the one on the roll's side: its ankle stays on the floor, within a few cm of
    # its point (the body's pinning averages over all its contacts) ...
    assert np.ptp(ankle[:, :2], axis=0).max() < 0.05 and ankle[:, 2].max() < 0.12
    # ... while the pelvis turns from face up towards face down (its forward axis' height)
    facing = quat_apply(quat[pushing, 0], np.array([1.0, 0.0, 0.0]))[:, 2]
    assert facing[0] > 0.9 and facing[-1] < facing[0] - 0.5
    # and the roll ends face down, the arm underneath brought down from overhead for the push
    end = quat_apply(quat[share(1.0), 0], np.array([1.0, 0.0, 0.0]))[2]
    assert end < -0.9


def test_a_getup_is_a_function_of_its_parameters():
    a, b = getup("back", tempo=0.9), getup("back", tempo=0.9)
    assert np.array_equal(a.root_pos, b.root_pos) and np.array_equal(a.local_quat, b.local_quat)
    slow, fast = getup("front", tempo=0.8), getup("front", tempo=1.2)
    assert slow.num_frames > fast.num_frames


@pytest.mark.parametrize("kwargs,match", [({"start": "side"}, "start"), ({"side": "X"}, "side"),
                                          ({"tempo": 4.0}, "tempo"), ({"hand_width": "wide"}, "hand_width"),
                                          ({"lie": float("nan")}, "lie")])
def test_bad_parameters_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        getup(**kwargs)


def test_facing_height_reads_face_up_and_face_down_from_body_positions():
    bench = _getup_follow()
    for start, sign in (("back", 1), ("front", -1)):
        raw = getup(start, lie=0.5)
        pos, _ = forward_kinematics(raw.root_pos, raw.local_quat, MEAN_SKELETON.offsets)
        assert sign * bench.facing_height(pos[0]) > 0.9  # lying still at the start
        assert abs(bench.facing_height(pos[-1])) < 0.3  # standing at the end: facing level


def _getup_follow():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).parents[1] / "benchmarks" / "getup_follow.py"
    spec = importlib.util.spec_from_file_location("getup_follow", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_follow_benchmark_names_the_phase_a_clip_is_lost_in():
    bench = _getup_follow()
    params = {"start": "front", "side": "L", "roll": "R", "tempo": 1.0, "hand_width": 0.2, "hand_ahead": 0.0,
              "lie": 0.5, "kneel": 0.4, "held_out": None}
    spans = bench.phase_frames(params)
    a, b = spans["foot_1"]
    lost = (a + b) // 2

    class Lib:  # the two attributes the report reads
        names, lengths = ["g"], np.array([spans["still"][1] + 1])

    dist = np.full((1, int(Lib.lengths[0])), 0.1)
    dist[0, lost:] = 0.7
    (row,) = bench.report(Lib, {"g": params}, dist, threshold=0.5)
    assert row["followed"] == lost and row["lost_in"] == "foot_1"
    assert row["distance"]["kneel"] == pytest.approx(0.1) and row["distance"]["lift"] is None
    dist[0, lost:] = 0.1
    (row,) = bench.report(Lib, {"g": params}, dist, threshold=0.5)
    assert row["followed"] == row["frames"] and row["lost_in"] == "-"
    # from the back, the first face-down frame of the simulated body is reported
    back = {**params, "start": "back"}
    facing = np.ones((1, int(Lib.lengths[0])))
    (row,) = bench.report(Lib, {"g": back}, dist, 0.5, facing)
    assert row["turned"] is None
    facing[0, 40:] = -0.9
    (row,) = bench.report(Lib, {"g": back}, dist, 0.5, facing)
    assert row["turned"] == 40
    assert "turned" not in bench.report(Lib, {"g": params}, dist, 0.5, facing)[0]  # from the front: no roll
    with pytest.raises(SystemExit, match="get-up clips only"):
        bench.main(["--motions", "corpus:test/walk"])
    with pytest.raises(SystemExit, match="tempo-scale 9.*outside"):  # beyond getup.TEMPO_LIMITS
        bench.main(["--tempo-scale", "9"])


def test_getup_makes_faster_tempos_than_the_corpus_draws():
    from smpl_envs.motion.getup import RANGES, TEMPO_LIMITS

    assert TEMPO_LIMITS[1] > RANGES["getup"]["tempo"][1]
    slow, fast = phases("front", tempo=1.0), phases("front", tempo=2.0)
    # the moving phases take half as long; lying and kneeling are held for their own seconds
    assert fast["crouch"][1] - fast["crouch"][0] == pytest.approx((slow["crouch"][1] - slow["crouch"][0]) / 2)
    assert fast["lie"] == slow["lie"]
