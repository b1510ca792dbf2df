"""Play a reference clip on the simulated SMPL humanoid; write mp4 videos and PNG strips.

Two ways of playing it:
- kinematic: the clip's qpos written straight into MuJoCo (what the reference *is*);
- physics:   the humanoid starts in the clip's first state and its PD controllers get the clip's
             hinge angles as targets, with no policy to keep balance. Red markers show where the
             reference bodies are; the gap is what a learned controller has to close.

    python examples/play_clip.py walk --out out/
"""

from __future__ import annotations

import argparse
from pathlib import Path

import smpl_envs  # noqa: F401  (selects a headless GL backend before mujoco loads)
import mujoco
import numpy as np

from smpl_envs.humanoid import build_humanoid
from smpl_envs.motion import available_clips, load_motion
from smpl_envs.progress import pbar
from smpl_envs.render import FrameRenderer, write_strip, write_video



def kinematic_frames(model, motion, renderer):
    data = mujoco.MjData(model)
    for t in range(motion.num_frames):
        data.qpos[:] = motion.qpos[t]
        mujoco.mj_forward(model, data)
        yield renderer.render(data), 0.0


def physics_frames(model, motion, renderer):
    """Open-loop PD tracking; also yields the mean body distance to the reference (m)."""
    substeps = round(1.0 / (motion.fps * model.opt.timestep))  # 4 at 1/120 s (docs/humanoid.md, "Timing")
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = motion.qpos[0], motion.qvel[0]
    mujoco.mj_forward(model, data)
    for t in range(motion.num_frames):
        if t > 0:
            data.ctrl[:] = np.clip(motion.dof_pos[t], *model.actuator_ctrlrange.T)
            mujoco.mj_step(model, data, nstep=substeps)
        error = np.linalg.norm(data.xpos[1:] - motion.body_pos[t], axis=-1).mean()
        yield renderer.render(data, markers=motion.body_pos[t]), error


def play(clip: str, out: Path, mode: str, width: int, height: int, strip_frames: int) -> dict:
    motion = load_motion(clip)
    model = build_humanoid()
    frames_fn = kinematic_frames if mode == "kinematic" else physics_frames
    keep = set(np.linspace(0, motion.num_frames - 1, strip_frames).round().astype(int))
    strip, errors = [], []

    def frames():
        with FrameRenderer(model, width, height) as renderer:
            bar = pbar(frames_fn(model, motion, renderer), total=motion.num_frames,
                       desc=f"{motion.name} ({mode})", unit="frame")
            for t, (frame, err) in enumerate(bar):
                errors.append(err)
                if t in keep:
                    strip.append(frame[:, width // 6: width - width // 6])  # trim empty sides
                yield frame

    video = out / f"{motion.name}_{mode}.mp4"
    write_video(video, frames(), fps=motion.fps)
    png = out / f"{motion.name}_{mode}_strip.png"
    write_strip(png, strip)
    errors = np.array(errors)
    lost = np.flatnonzero(errors > 0.5)
    return dict(video=video, strip=png, mean_error_m=float(errors.mean()),
                lost_at_s=None if len(lost) == 0 else float(lost[0] / motion.fps))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("clip", nargs="?", default="walk",
                        help=f"a shipped clip ({', '.join(available_clips())}) or a motion file")
    parser.add_argument("--out", type=Path, default=Path("out"))
    parser.add_argument("--mode", choices=["kinematic", "physics", "both"], default="both")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--strip-frames", type=int, default=6)
    args = parser.parse_args()
    modes = ["kinematic", "physics"] if args.mode == "both" else [args.mode]
    for mode in modes:
        r = play(args.clip, args.out, mode, args.width, args.height, args.strip_frames)
        note = "" if mode == "kinematic" else (
            f"; mean body error {100 * r['mean_error_m']:.1f} cm, "
            + ("kept up to the end" if r["lost_at_s"] is None else f"fell behind (> 0.5 m) at {r['lost_at_s']:.1f} s"))
        print(f"{mode:9s} -> {r['video']}  {r['strip']}{note}")


if __name__ == "__main__":
    main()
