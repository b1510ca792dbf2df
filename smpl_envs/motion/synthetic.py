"""The small clip library the project ships: eight procedural clips (stand, walk, run, turn,
jump, kick, gesture, crouch) made by `procedural`'s machinery; kick, crouch and jump are members
of `whole_body`'s parametrised families.

AMASS cannot be redistributed, yet every demo and test needs motion, so these clips are made by
code. Every clip is deterministic (no randomness at all). Run `python -m smpl_envs.motion.synthetic
[out_dir]` to rewrite the shipped clips; tests/test_synthetic_clips.py checks that regenerating
reproduces them.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from .motion import RawMotion
from .plausibility import GRAVITY  # noqa: F401  (re-exported: the shipped clips' tests read it here)
from .procedural import (
    B, BALL_HEIGHT, DEG, RUN, WALK, _arm, _balanced, _Gait, _keys, _locomotion, _minjerk, _raw,
    _relaxed_arms, _rot, _Spec, _standing_legs, _time, _upright_spine,
)
from .whole_body import _squat, jump, kick

CLIP_NAMES: tuple[str, ...] = ("stand", "walk", "run", "turn", "jump", "kick", "gesture", "crouch")
CLIPS_DIR = Path(__file__).resolve().parent / "clips"


def _walk() -> RawMotion:
    return _locomotion("walk", 6.0, WALK, speed=1.3)


def _run() -> RawMotion:
    return _locomotion("run", 4.0, RUN, speed=3.0)


def _turn() -> RawMotion:
    # Straight, then a smooth left turn of 200 degrees on a ~1.2 m radius, then straight again.
    speed, duration = 1.1, 8.0
    total, t0, t1, ramp = 200 * DEG, 1.2, 6.6, 0.6

    def yaw_rate(t):
        on = _minjerk((t - t0) / ramp) * (1 - _minjerk((t - (t1 - ramp)) / ramp))
        return on * total / (t1 - t0 - ramp)

    gait = _Gait(**{**WALK.__dict__, "stride": 1.1, "swing_height": 0.055})
    return _locomotion("turn", duration, gait, speed=speed, yaw_rate=yaw_rate)


# ----------------------------------------------------------------------------- quasi-static clips

def _stand() -> RawMotion:
    t = _time(6.0)
    legs = _standing_legs(t)
    # Postural sway (~1 cm, incommensurate slow sines) and breathing (~0.25 Hz chest pitch).
    sway = 0.5 + 0.05 * np.sin(2 * np.pi * 0.21 * t)  # weight on the left foot
    breath = 1.2 * DEG * np.sin(2 * np.pi * 0.27 * t)
    angles = _upright_spine(t, 4 * DEG, lean=1 * DEG + breath)
    angles[:, B["Neck"], 2] = 4 * DEG * np.sin(2 * np.pi * 0.09 * t + 1.0)  # glance around
    spec = _Spec(t, np.zeros((len(t), 3)), _rot(0 * t, 4 * DEG), legs,
                 _relaxed_arms(t, flex=2 * DEG + 0.6 * breath, elbow=14 * DEG), angles)
    local = _balanced(spec, sway + 0.02 * np.sin(2 * np.pi * 0.53 * t + 0.7),
                      drop=0.003 + 0.002 * (1 + np.sin(2 * np.pi * 0.13 * t)))
    return _raw("stand", spec, local)


def _gesture() -> RawMotion:
    t = _time(8.0)
    legs = _standing_legs(t)
    angles = _upright_spine(t, 4 * DEG, lean=1 * DEG)
    # Right arm: raise out to the side, wave three times, lower. Then both arms up overhead
    # through the sides and down again. Keys: (upper-arm flex, abduction, elbow, twist) degrees.
    rk = [0.0, 0.5, 1.3, 3.7, 4.3, 5.2, 6.2, 7.2, 8.0]
    rest, wave, up = (2, 10, 15, 0), (10, 95, 85, 50), (0, 165, 15, 0)
    r_keys = [rest, rest, wave, wave, rest, rest, up, rest, rest]
    l_keys = [rest, rest, rest, rest, rest, rest, up, rest, rest]
    r, l = (np.deg2rad(_keys(t, rk, k)) for k in (r_keys, l_keys))
    # The wave: the forearm swings towards and away from the head while the arm is raised.
    waving = _minjerk((t - 1.4) / 0.3) * (1 - _minjerk((t - 3.4) / 0.3))
    r[:, 2] += 25 * DEG * waving * np.sin(2 * np.pi * 1.5 * (t - 1.4))
    arms = {"L": _arm(t, "L", *l.T), "R": _arm(t, "R", *r.T)}
    # Look at the waving hand a little, and up when both arms are overhead.
    angles[:, B["Neck"], 2] -= 12 * DEG * _keys(t, rk, [0, 0, 1, 1, 0, 0, 0, 0, 0])
    angles[:, B["Head"], 1] -= 12 * DEG * _keys(t, rk, [0, 0, 0, 0, 0, 0, 1, 0, 0])
    spec = _Spec(t, np.zeros((len(t), 3)), _rot(0 * t, 4 * DEG), legs, arms, angles)
    return _raw("gesture", spec, _balanced(spec, 0.5, drop=0.004))


# ----------------------------------------------------------------------------- members of whole_body's families

def _crouch() -> RawMotion:
    # Squat depth: 0.21 m of pelvis drop below the legs' reach in the squat posture (knees ~85 deg).
    return _shipped(_squat(bend=0.21, descent=1.3, hold=0.6, ascent=1.4, width=0.12, name="crouch"))


def _kick() -> RawMotion:
    return _shipped(kick("R", height=0.5 + BALL_HEIGHT["R"], reach=0.70, tempo=1.0, name="kick"))


def _jump() -> RawMotion:
    """Countermovement jump 0.3 m forward with 0.4 s of flight."""
    return _shipped(jump(flight=0.4, distance=0.30, direction=0.0, count=1, name="jump"))


def _shipped(raw: RawMotion) -> RawMotion:
    return replace(raw, source="smpl_envs.motion.synthetic")


_GENERATORS = {
    "stand": _stand, "walk": _walk, "run": _run, "turn": _turn, "jump": _jump, "kick": _kick,
    "gesture": _gesture, "crouch": _crouch,
}


def generate(name: str) -> RawMotion:
    """The synthetic clip `name` (one of CLIP_NAMES) at 30 fps, pelvis position and local
    rotations in the humanoid's body frames, feet on the floor z = 0."""
    if name not in _GENERATORS:
        raise KeyError(f"unknown synthetic clip {name!r}; choose from {CLIP_NAMES}")
    return _GENERATORS[name]()


def generate_all(out_dir: str | Path = CLIPS_DIR) -> list[Path]:
    """Write every clip as `<out_dir>/<name>.npz` (RawMotion.save); returns the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in CLIP_NAMES:
        path = out_dir / f"{name}.npz"
        generate(name).save(path)
        paths.append(path)
    return paths


if __name__ == "__main__":
    for p in generate_all(sys.argv[1] if len(sys.argv) > 1 else CLIPS_DIR):
        print(p)
