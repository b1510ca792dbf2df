"""From a video pose estimator's output to physically corrected motion: the path a user with a
video takes, end to end.

    python examples/video_to_motion.py --out out/                       # on generated input (no files needed)
    python examples/video_to_motion.py --smpl my_video/smpl.npz --out out/
    python examples/video_to_motion.py --smpl my_video/smpl.pkl --keypoints my_video/openpose_json/ \\
        --camera my_video/camera.json --policy runs/videopose --out out/

1. The input. With `--smpl` (and optionally `--keypoints`, `--camera`): your estimator's files,
   read by `smpl_envs.motion.estimator_files.load_estimator_output` (per-frame SMPL parameters
   in the camera frame: global_orient, body_pose, transl; COCO-17 or OpenPose BODY-25 keypoints
   with confidences; intrinsics; its docstring has every accepted field). Without: the shipped
   `--clip` degraded by the estimator model and written out as such files first (an .npz of SMPL
   parameters and intrinsics, a directory of OpenPose JSON), then read back the same way, so the
   generated run exercises exactly the loaders your files go through.
2. The physics. `SMPL/VideoPose-v0` on that input (`video=`), every frame from the first, driven
   by `--policy`: a SimPoE run or checkpoint (`tasks/videopose_ppo.yaml`), or by default the
   shipped generalist tracker following the estimate (PHC's way of using video; VideoPose-v0's
   first 934 observation columns are what it was trained on). The sequence stops early if the
   humanoid falls.
3. Out, under --out: `<name>_physics.npz`, the simulated motion as arrays any tool reads (fps,
   body_names, body_pos (T, 24, 3) m, body_quat (T, 24, 4) wxyz, qpos (T, 76) MuJoCo, z-up world),
   plus `<name>_physics_amass.npz` in AMASS's layout (poses, trans, mocap_framerate) for SMPL
   tools; `<name>_physics.mp4`, the simulated body with the input's bodies as red markers beside
   it (and the truth's in green, for generated input); and the metrics (`video_metrics`: without
   ground truth, the physics metrics and the 2D reprojection error).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

import smpl_envs  # noqa: F401  (registers the SMPL/ ids; headless GL)
from smpl_envs.motion import load_motion
from smpl_envs.motion.estimator_files import export_estimator_output, load_estimator_output, write_openpose
from smpl_envs.motion.estimator_noise import degrade
from smpl_envs.motion.export import to_amass
from smpl_envs.motion.motion import RawMotion
from smpl_envs.render import write_video
from smpl_envs.rotations import quat_from_matrix, quat_inv, quat_mul
from smpl_envs.humanoid.skeleton import BODY_NAMES, PARENTS
from smpl_envs.video_eval import input_result
from smpl_envs.motion.video_input import VideoLib
from smpl_envs.video_metrics import format_table, sequence_metrics

ID = "SMPL/VideoPose-v0"
TRACKER_OBS = 934


def make_input(args) -> VideoLib:
    if args.smpl is not None:
        video = load_estimator_output(args.smpl, keypoints=args.keypoints, camera=args.camera)
        print(f"{args.smpl}: {video.num_frames} frames at {video.fps:g} fps, camera {video.camera.width}x"
              f"{video.camera.height}, {(video.confidence > 0).mean():.0%} of the body keypoints detected")
        return VideoLib([video])
    truth = load_motion(args.clip)
    generated = degrade(truth, seed=args.seed)
    # Written as an estimator would, then read back as your files would be.
    smpl = export_estimator_output(generated, args.out / f"{args.clip}_estimate.npz")
    keypoints = write_openpose(generated, args.out / f"{args.clip}_openpose")
    video = load_estimator_output(smpl, keypoints=keypoints, name=args.clip)
    print(f"generated input of '{args.clip}': {smpl} (SMPL parameters, intrinsics) and {keypoints}/ (OpenPose)")
    # The truth stays known for the metrics (what real input never has).
    video.truth = generated.truth
    return VideoLib([video])


def make_policy(target: str | None):
    from agents.checkpoint_commands import load_target

    agent = load_target(target or "tracker", "best", "cpu")[0]
    if agent.env_id == "SMPL/Imitation-v0":  # the tracker: its observation is the first 934 columns
        return (lambda obs: agent.predict(np.asarray(obs)[:, :TRACKER_OBS])[0]), {}, "tracker"
    settings = {k: agent.env_kwargs[k] for k in ("substeps", "residual_scale", "meta_pd", "meta_pd_range",
                                                  "residual_force", "residual_force_scale",
                                                  "residual_torque_scale") if k in agent.env_kwargs}
    return agent, settings, str(target)


def local_from_world(body_rot: np.ndarray) -> np.ndarray:
    """(T, 24, 4) local rotations from world rotation matrices (T, 24, 3, 3)."""
    q = quat_from_matrix(body_rot)
    local = q.copy()
    local[:, 1:] = quat_mul(quat_inv(q[:, PARENTS[1:]]), q[:, 1:])
    return local


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--smpl", type=Path, help="your estimator's SMPL parameter file (.npz, .pkl, .json)")
    p.add_argument("--keypoints", type=Path, help="2D keypoints: a file, or a directory of OpenPose JSON")
    p.add_argument("--camera", type=Path, help="camera intrinsics (.json / .npz), if not in the SMPL file")
    p.add_argument("--clip", default="walk", help="without --smpl: the shipped clip to generate input from")
    p.add_argument("--seed", type=int, default=0, help="without --smpl: the estimator model's seed")
    p.add_argument("--policy", help="a SimPoE run or checkpoint (default: the shipped tracker)")
    p.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"))
    p.add_argument("--no-video", action="store_true")
    p.add_argument("--out", type=Path, default=Path("out"))
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    lib = make_input(args)
    policy, settings, label = make_policy(args.policy)
    name = lib.names[0]
    env = gym.make_vec(ID, num_envs=1, video=lib, termination_distance=None, autoreset_mode="Disabled",
                       render_mode=None if args.no_video else "rgb_array", render_size=tuple(args.size),
                       ghost_offset=(0.0, 1.0, 0.0), **settings)
    obs, info = env.reset(seed=0, options={"motion_ids": [0], "start": "beginning"})
    frames, log = [], {k: [] for k in ("body_pos", "est_body_pos", "foot_points", "reprojection_error",
                                       "keypoint_weight", "truth_body_pos")}
    rots, qpos = [], []
    fell = False
    while True:
        for k in log:
            if k in info:
                log[k].append(np.asarray(info[k][0], float))
        rots.append(env.sim.bodies.rot[0].copy())
        qpos.append(env.sim.qpos[0, env.humanoid.qpos].copy())
        if not args.no_video:
            frames.append(env.render_frame(0))
        if len(qpos) == lib.lengths[0]:
            break
        obs, _, terminated, truncated, info = env.step(policy(obs))
        if terminated[0]:
            fell = True
            break
    env.close()

    body_pos, body_rot = np.stack(log["body_pos"]), np.stack(rots)
    body_quat = quat_from_matrix(body_rot)
    out = args.out / f"{name}_physics.npz"
    np.savez(out, fps=30.0, body_names=np.array(BODY_NAMES), body_pos=body_pos, body_quat=body_quat,
             qpos=np.stack(qpos), fell=fell)
    to_amass(RawMotion(f"{name}_physics", 30.0, body_pos[:, 0], local_from_world(body_rot)),
             args.out / f"{name}_physics_amass.npz", layout="smpl")
    print(f"\n{out}: {len(body_pos)} frames of simulated motion ({label}){', ended by a fall' if fell else ''}")
    if frames:
        write_video(args.out / f"{name}_physics.mp4", frames, fps=30)
        print(f"{args.out / f'{name}_physics.mp4'}: the simulated body, the input's bodies in red beside it")

    truth = np.stack(log["truth_body_pos"]) if log["truth_body_pos"] else None
    row = sequence_metrics(body_pos, np.stack(log["est_body_pos"]), np.stack(log["foot_points"]),
                           np.array(log["reprojection_error"]), np.array(log["keypoint_weight"]), truth, fell=fell)
    print(f"\nthe physically corrected motion ({label}):\n" + format_table([{"name": name, **row}]))
    print("\nthe kinematic input itself:\n" + input_result(lib).table())


if __name__ == "__main__":
    main()
