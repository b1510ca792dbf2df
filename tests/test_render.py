import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import mujoco
import numpy as np
import pytest

from smpl_envs.humanoid import build_humanoid
from smpl_envs.render import FrameRenderer, write_strip, write_video

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def scene():
    model = build_humanoid()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


def test_frame_shows_the_humanoid(scene):
    model, data = scene
    with FrameRenderer(model, 320, 240) as r:
        frame = r.render(data)
        assert frame.shape == (240, 320, 3) and frame.std() > 10  # not blank
        humanoid = model.geom_bodyid > 0
        saved = model.geom_rgba.copy()
        model.geom_rgba[humanoid, 3] = 0.0  # hide the humanoid, keep floor and sky
        model.geom_matid[humanoid] = -1
        try:
            empty = r.render(data)
        finally:
            model.geom_rgba[:] = saved
    changed = np.abs(frame.astype(int) - empty.astype(int)).sum(-1) > 30
    assert changed.mean() > 0.02, "the humanoid covers almost no pixels"
    rows, cols = np.nonzero(changed)
    assert 0.25 < cols.mean() / 320 < 0.75  # the tracking camera keeps it in the middle


def test_markers_are_drawn_in_red(scene):
    model, data = scene
    with FrameRenderer(model, 320, 240) as r:
        plain = r.render(data)
        marked = r.render(data, markers=data.xpos[1:] + [0.0, 0.0, 0.0])
    diff = marked.astype(int) - plain.astype(int)
    redder = (diff[..., 0] > 20) | (diff[..., 1] < -20)
    assert redder.sum() > 50


def test_video_and_strip_are_written(tmp_path, scene):
    model, data = scene
    with FrameRenderer(model, 160, 120) as r:
        frames = [r.render(data) for _ in range(12)]
    assert write_video(tmp_path / "v.mp4", iter(frames), fps=30) == 12
    assert len(iio.imread(tmp_path / "v.mp4")) == 12
    strip = write_strip(tmp_path / "s.png", frames[:4], columns=2)
    assert strip.shape == (240, 320, 3)
    assert iio.imread(tmp_path / "s.png").shape == (240, 320, 3)


def test_demo_script_runs(tmp_path):
    out = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "play_clip.py"), "stand", "--out", str(tmp_path),
         "--width", "160", "--height", "120", "--strip-frames", "3"],
        capture_output=True, text=True, timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    for name in ("stand_kinematic.mp4", "stand_kinematic_strip.png", "stand_physics.mp4",
                 "stand_physics_strip.png"):
        assert (tmp_path / name).stat().st_size > 1000
    assert "mean body error" in out.stdout


def test_readme_demo_runs(tmp_path):
    """examples/imitation_rollout.py (docs/getting-started.md): policy-free rollouts of SMPL/Imitation-v0
    with videos and metrics."""
    out = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "imitation_rollout.py"), "jump", "gesture",
         "--out", str(tmp_path), "--size", "160", "120"],
        capture_output=True, text=True, timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    for name in ("imitation_jump_zero.mp4", "imitation_jump_reference.mp4"):
        assert (tmp_path / name).stat().st_size > 1000
    for name in ("zero", "reference"):
        summary = json.loads((tmp_path / f"metrics_{name}.json").read_text())["summary"]
        assert summary["clips"] == 2
    assert "E_g-mpjpe" in out.stdout and "ALL" in out.stdout
