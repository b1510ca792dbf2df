"""The video task's evaluation (`SMPL/VideoPose-v0`'s `evaluation`), and the same metrics of the
kinematic input itself.

    result = smpl_envs.evaluate(policy, "SMPL/VideoPose-v0", motions="corpus:test")
    result = smpl_envs.evaluate(policy, "SMPL/VideoPose-v0", env_kwargs={"video": "out/smpl.npz"})
    rows = input_rows(video_library("corpus:test"))   # the noisy input's own row, no physics

`VideoProtocol`: every sequence once from its first frame (the humanoid starts in the estimate's
first pose, lifted out of the floor where it sinks), until its last frame or a fall; the env's
distance termination off, batched over worlds as `evaluation.ClipProtocol` (the result does not
depend on the number of worlds). Per sequence `video_metrics.sequence_metrics`: no fall, MPJPE,
PA-MPJPE, E_g-mpjpe, Accel against the ground truth where it is known, foot sliding, ground
penetration, 2D reprojection error, and PHC's success against the input followed (option
`threshold`, 0.5 m). Summary: `video_metrics.summarize`, plus `score` (the no-fall share, ties
broken by the lower MPJPE, or the lower reprojection error without ground truth), which ranks
checkpoints.
"""

from __future__ import annotations

import numpy as np

from . import video_metrics
from .evaluation import ClipProtocol, EvalResult, _clip_queue
from .features import rotmat_from_quat
from .video_features import foot_points, reprojection_residual, weighted_mean
from .motion.video_input import VideoLib

# Kwargs of the video task that shape its input: the evaluation builds the input itself.
_INPUT_KWARGS = ("video", "noise", "noise_scale", "noise_seed")


class VideoResult(EvalResult):
    def table(self) -> str:
        return video_metrics.format_table(self.rows, self.summary)


class VideoProtocol(ClipProtocol):
    """Every video sequence once (module docstring). Option: threshold (m, PHC's success)."""

    key = "score"
    train_only_kwargs = ("start", "max_episode_steps", "termination_distance", "beginning_share",
                         "failure_sampling", "motion_weights", "noise_scale_range")

    def eval_kwargs(self, train_kwargs: dict) -> dict:
        return {k: v for k, v in super().eval_kwargs(train_kwargs).items() if k != "video"}

    def record_kwargs(self, train_kwargs: dict) -> dict:
        return {**super().record_kwargs(train_kwargs), "start": "beginning"}

    def make_env(self, env_id, motions, num_envs, env_kwargs, progress, options):
        import gymnasium as gym

        from .video_sources import video_library

        clash = sorted(set(env_kwargs) & {"motions", "termination_distance", *self.forced_kwargs})
        if clash:
            raise ValueError(f"env_kwargs must not set {clash}: evaluate() chooses them")
        kwargs = {k: v for k, v in env_kwargs.items() if k not in _INPUT_KWARGS}
        source = {k: env_kwargs[k] for k in _INPUT_KWARGS if k in env_kwargs}
        if "video" in source:
            # An agent trained on generated input brings its training motions along: the
            # estimator output given here replaces them.
            lib = video_library(video=source["video"])
        else:
            lib = video_library(motions, noise=source.get("noise"), noise_scale=source.get("noise_scale", 1.0),
                                noise_seed=source.get("noise_seed", 0), progress=progress)
        return gym.make_vec(env_id, num_envs=min(num_envs, lib.num_motions), video=lib, termination_distance=None,
                            autoreset_mode="Disabled", **kwargs)

    def run(self, policy, env, options, progress):
        u = getattr(env, "unwrapped", env)
        lib: VideoLib = u.video
        truth = lib.has_truth
        keys = ("body_pos", "est_body_pos", "foot_points", "reprojection_error", "keypoint_weight") + \
            (("truth_body_pos",) if truth else ())

        def finish(c, frames, broke):
            cols = [np.stack(col) for col in zip(*frames)]
            # A diverged world's last frame may be non-finite: measure the frames before it.
            if broke and not all(np.isfinite(x[-1]).all() for x in cols):
                cols = [x[:-1] for x in cols]
            sim, est, foot, err, w = cols[:5]
            row = video_metrics.sequence_metrics(sim, est, foot, err, w, cols[5] if truth else None, fell=broke,
                                                 threshold=options["threshold"])
            return {"name": lib.names[c], "motion_id": int(c), **row}

        rows = _clip_queue(policy, env, lib.num_motions, lambda info: keys,
                           lambda arrays, lengths: np.zeros(len(lengths), bool), finish, progress)
        return VideoResult(rows, with_score(video_metrics.summarize(rows)), "clips")


def with_score(summary: dict) -> dict:
    """`summary` with `score`: the no-fall share minus 1e-6 x the MPJPE (mm), or the reprojection
    error (px) without ground truth: between equal shares the lower error wins."""
    error = summary.get("mpjpe")
    if error is None or not np.isfinite(error):
        error = summary.get("reprojection")
    penalty = 1e-6 * error if error is not None and np.isfinite(error) else 0.0
    return {**summary, "score": float(summary["no_fall"]) - penalty}


def input_rows(lib: VideoLib, threshold: float = 0.5) -> list[dict]:
    """The rows of the kinematic input itself (no physics, so no fall): its errors against the
    ground truth, its foot sliding and ground penetration, its reprojection error."""
    rows = []
    est = lib.estimate
    for i in range(lib.num_motions):
        s = slice(int(est.starts[i]), int(est.starts[i] + est.lengths[i]))
        pos = np.asarray(est.body_pos[s], float)
        rot = rotmat_from_quat(np.asarray(est.body_quat[s], float))
        cam = lib.cameras[i]
        r = reprojection_residual(pos, lib.keypoints[s].astype(float), cam.rotation[None].repeat(len(pos), 0),
                                  cam.position[None].repeat(len(pos), 0))
        conf = lib.confidence[s].astype(float)
        err = weighted_mean(np.linalg.norm(r * cam.focal, axis=-1), conf)
        truth = np.asarray(lib.truth.body_pos[s], float) if lib.has_truth else None
        row = video_metrics.sequence_metrics(pos, pos, foot_points(pos, rot), err, conf.sum(-1), truth,
                                             threshold=threshold)
        rows.append({"name": lib.names[i], "motion_id": i, **row, "physics": False})
    return rows


def input_result(lib: VideoLib) -> VideoResult:
    """`input_rows` with their summary, as an evaluation result (no-fall share undefined: the
    kinematic input has no physics to fall with)."""
    rows = input_rows(lib)
    return VideoResult(rows, {**video_metrics.summarize(rows), "no_fall": float("nan")}, "clips")


__all__ = ["VideoProtocol", "VideoResult", "input_rows", "input_result", "with_score"]
