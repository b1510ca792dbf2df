"""What makes a body following video input fall, and how accurate a SimPoE policy's refinement is.

    python benchmarks/videopose_diagnosis.py knobs                      # which estimator error fells the tracker
    python benchmarks/videopose_diagnosis.py refinement videopose runs/videopose_aux
    python benchmarks/videopose_diagnosis.py step0                      # the recipe's policy before PPO
    python benchmarks/videopose_diagnosis.py step0 --targets angles --set agent.policy.kwargs.refined_reference=false
    python benchmarks/videopose_diagnosis.py families RUN/evals/*.json  # no fall per motion family
    python benchmarks/videopose_diagnosis.py endings videopose          # why training episodes end
    python benchmarks/videopose_diagnosis.py noise videopose tracker    # one family's no fall by noise scale

`knobs`: the generalist tracker (`--tracker`) follows the noisy input of `--sequences` evenly
spaced corpus:test sequences (the report's, `videopose_report.py`) with every knob of the estimator
model at its default, then with one knob (or group) at zero at a time, and with the true joint
rotations or the true root orientation put back into the estimate. The no-fall share and MPJPE of
each row say which error the physics has to reject: a knob whose removal lifts no-fall most is
what a video policy must learn to see through.

`refinement`: for each checkpoint (a run directory, a .pt file or a shipped name) of a
`KinematicRefinement` policy, the root-mean-square body error (mm, 24 bodies, posed from the
estimate's root) of the estimate and of the policy's refined estimate against the truth, on
`--frames` observations of its own rollouts on corpus:train (the distribution it trains on). The
supervised pretraining sets this error; PPO's loss alone moves it (`refine_aux_coef`).

`step0`: the recipe's policy (`videopose_ppo`: the tracker's weights, the refinement unit) before
any PPO update, evaluated on `--motions` (corpus:test, every sequence, as the runs evaluate): with
the untrained unit (damped Gauss-Newton on the keypoints), and after the supervised pretraining on
each `refine_target`. What the refinement hands the tracker decides how often it falls.

`families`: from evaluation files a run wrote (`RUN/evals/*.json`, one column each), per motion
family of the sequences: the no-fall share and the median time of the falls.

`endings`: a checkpoint acts (sampling, as in training) in its own training env (the env kwargs
of its checkpoint; `--termination-distance` to change that one) for `--steps` steps of
`--num-envs` worlds; the episodes that end are counted by why: a fall, the distance to the
estimate, or the sequence's end. What ends the training episodes is what the policy never learns
to do after.

`noise`: each policy (SimPoE checkpoints, runs or shipped names; "tracker" is the generalist
tracker reading the Imitation-v0 part of the observation) follows the sequences of `--motions`
(default: the 40 test walks) generated at each of `--scales`: the no-fall share and MPJPE per
scale. A policy that walks on clean input and not on noisy input has to learn robustness; one
that no longer walks on clean input has forgotten how.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import smpl_envs
from smpl_envs.motion import load_motions
from smpl_envs.motion.estimator_noise import EstimatorNoise
from smpl_envs.motion.motion import FPS
from smpl_envs.motion.video_input import VideoInput, VideoLib

sys.path.insert(0, str(Path(__file__).resolve().parent))
from videopose_report import TrackerOnVideo, degraded, evenly_spaced  # noqa: E402

KNOB_ROWS = (
    ("every error (the default)", {}),
    ("without per-frame rotation jitter", {"jitter_rotation": 0.0}),
    ("without the slow rotation error", {"rotation_error": 0.0}),
    ("without depth drift", {"depth_drift": 0.0}),
    ("without foot sliding", {"foot_sliding": 0.0}),
    ("without ground penetration", {"ground_penetration": 0.0}),
    ("the slow rotation error alone", {"jitter_rotation": 0.0, "jitter_translation": 0.0, "depth_drift": 0.0,
                                       "foot_sliding": 0.0, "ground_penetration": 0.0}),
)


def _true_joints(v: VideoInput) -> VideoInput:
    q = v.local_quat.copy()
    q[:, 1:] = v.truth.local_quat[:, 1:]
    return dataclasses.replace(v, local_quat=q)


def _true_root_orientation(v: VideoInput) -> VideoInput:
    q = v.local_quat.copy()
    q[:, 0] = v.truth.local_quat[:, 0]
    return dataclasses.replace(v, local_quat=q)


def _true_root_position(v: VideoInput) -> VideoInput:
    return dataclasses.replace(v, root_pos=v.truth.root_pos.copy())


def _true_root_height(v: VideoInput) -> VideoInput:
    root = v.root_pos.copy()
    root[:, 2] = v.truth.root_pos[:, 2]
    return dataclasses.replace(v, root_pos=root)


def knobs(args) -> None:
    from agents.checkpoint_commands import load_target  # the command line's own lookup of runs and names

    lib = load_motions(args.split)
    indices = evenly_spaced(lib.num_motions, args.sequences)
    tracker = TrackerOnVideo(load_target(args.tracker, "best", "cpu")[0])

    rows = [(name, degraded(lib, indices, EstimatorNoise.make(knob))) for name, knob in KNOB_ROWS]
    default = rows[0][1]
    rows += [("every error, true joint rotations", [_true_joints(v) for v in default]),
             ("every error, true root orientation", [_true_root_orientation(v) for v in default]),
             ("every error, true root position", [_true_root_position(v) for v in default]),
             ("every error, true root height", [_true_root_height(v) for v in default]),
             ("every error, true joint rotations and root position",
              [_true_root_position(_true_joints(v)) for v in default])]
    print(f"**The tracker ({args.tracker}) on {len(indices)} {args.split} sequences**\n")
    print("| estimate | no fall | MPJPE | PA-MPJPE |\n|---|---|---|---|")
    for name, videos in rows:
        s = smpl_envs.evaluate(tracker, "SMPL/VideoPose-v0", motions=VideoLib(videos), num_envs=args.num_envs,
                               progress=False).summary
        print(f"| {name} | {100 * s['no_fall']:.1f} % | {s['mpjpe']:.1f} | {s['pa_mpjpe']:.1f} |", flush=True)


@torch.no_grad()
def refinement(args) -> None:
    from agents.checkpoint_commands import load_target
    from agents.simpoe import TRUTH, KinematicRefinement, split_observation

    print("| checkpoint | estimate, rms mm | refined, rms mm |\n|---|---|---|")
    for target in args.checkpoints:
        agent = load_target(target, "last", "cpu")[0]
        pol = agent.policy
        if not isinstance(pol, KinematicRefinement):
            raise SystemExit(f"{target}: a {type(pol).__name__} policy, not SimPoE's KinematicRefinement")
        env = gym.make_vec("SMPL/VideoPose-v0", num_envs=32, **{**agent.env_kwargs, "motions": args.motions})
        obs, info = env.reset(seed=args.seed)
        xs, ys = [], []
        while 32 * len(xs) < args.frames:
            xs.append(torch.as_tensor(np.asarray(obs), dtype=torch.float32))
            ys.append(torch.as_tensor(np.asarray(info[TRUTH]), dtype=torch.float32))
            obs, _, _, _, info = env.step(agent(obs))
        env.close()
        x, y = torch.cat(xs), torch.cat(ys)
        refined = pol.refinement_error(x, y).mean().sqrt() * 1000.0
        est = pol.body_error(x, split_observation(x)["angles"], y).mean().sqrt() * 1000.0
        print(f"| {target} | {est:.1f} | {refined:.1f} |", flush=True)


def step0(args) -> None:
    from agents.recipes import load_recipe
    from agents.run import new_agent

    print(f"**The recipe's policy before PPO, {args.motions}**\n")
    print("| refinement | rms body error (mm) | rms joint-angle error (deg) | no fall | MPJPE | PA-MPJPE |\n"
          "|---|---|---|---|---|---|")
    for name in args.targets:
        target = None if name == "untrained" else name
        recipe = load_recipe("videopose_ppo", overrides=[*args.set,
                                                          f"agent.hyperparams.refine_target={target or 'angles'}"])
        agent = new_agent(recipe, verbose=0, log_dir=None, tensorboard=False, update_threads=args.threads)
        errors = ("-", "-")
        if target is not None:
            out = agent.pretrain_refinement(recipe["agent"]["hyperparams"]["refine_pretrain_samples"])
            errors = (f"{out['before_mm']:.1f} -> {out['after_mm']:.1f}", f"{out['before_deg']:.1f} -> {out['after_deg']:.1f}")
            if "after_root_mm" in out:
                errors = (f"{errors[0]} (root {out['before_root_mm']:.1f} -> {out['after_root_mm']:.1f})", errors[1])
        s = smpl_envs.evaluate(agent, "SMPL/VideoPose-v0", motions=args.motions, num_envs=args.num_envs,
                               progress=False).summary
        name = "untrained (damped Gauss-Newton)" if target is None else f"pretrained on {target}"
        print(f"| {name} | {errors[0]} | {errors[1]} | {100 * s['no_fall']:.1f} % | {s['mpjpe']:.1f} | "
              f"{s['pa_mpjpe']:.1f} |", flush=True)
        agent.close()


def _family(name: str) -> str:
    from smpl_envs.motion.corpus import family_of

    return family_of(name) or name


def families(args) -> None:
    columns = []
    for path in args.evals:
        clips = json.loads(Path(path).read_text())["clips"]
        by: dict[str, list[dict]] = {}
        for c in clips:
            by.setdefault(_family(c["name"]), []).append(c)
        columns.append(by)
    names = sorted(set().union(*columns))
    print("| family | sequences | " + " | ".join(Path(p).stem.lstrip("0") or "0" for p in args.evals) + " |")
    print("|---|---|" + "---|" * len(args.evals))
    for name in names + ["all"]:
        cells, count = [], 0
        for by in columns:
            rows = [c for v in by.values() for c in v] if name == "all" else by.get(name, [])
            count = len(rows)
            falls = [c["fail_frame"] / FPS for c in rows if c["fell"]]
            if not rows:
                cells.append("-")
                continue
            when = f", falls at {np.median(falls):.1f} s" if falls else ""
            cells.append(f"{100 * (1 - len(falls) / len(rows)):.0f} %{when}")
        print(f"| {name} | {count} | " + " | ".join(cells) + " |")


def endings(args) -> None:
    from agents import load
    from agents.recipes import find_checkpoint

    path = find_checkpoint(args.checkpoint)
    model = load(path)
    kwargs = dict(model.env_kwargs)
    if args.termination_distance is not None:
        kwargs["termination_distance"] = None if args.termination_distance <= 0 else args.termination_distance
    env = gym.make_vec("SMPL/VideoPose-v0", num_envs=args.num_envs, **kwargs)
    obs, _ = env.reset(seed=args.seed)
    counts = {"fall": 0, "distance to the estimate": 0, "sequence end": 0}
    steps, lengths = np.zeros(args.num_envs), []
    for _ in range(args.steps):
        obs, _, terminated, truncated, info = env.step(model.predict(obs, deterministic=False)[0])
        steps += 1
        for i in np.flatnonzero(terminated | truncated):
            why = ("sequence end" if truncated[i] and not terminated[i]
                   else "fall" if info["fallen"][i] else "distance to the estimate")
            counts[why] += 1
            lengths.append(steps[i])
            steps[i] = 0
    env.close()
    total = max(sum(counts.values()), 1)
    print(f"{path}: termination_distance={kwargs.get('termination_distance')}, {total} episodes ended, "
          f"mean length {np.mean(lengths) / FPS:.2f} s")
    for why, n in counts.items():
        print(f"  {why}: {n} ({100 * n / total:.0f} %)")


def noise(args) -> None:
    from agents import load
    from agents.recipes import find_checkpoint

    print(f"**{args.motions}: no fall (MPJPE, mm) by noise scale**\n")
    print("| policy | " + " | ".join(f"noise {s:g}" for s in args.scales) + " |")
    print("|---|" + "---|" * len(args.scales))
    for name in args.policies:
        agent = load(find_checkpoint(name))
        policy = TrackerOnVideo(agent) if agent.env_id != "SMPL/VideoPose-v0" else agent
        cells = []
        for scale in args.scales:
            s = smpl_envs.evaluate(policy, "SMPL/VideoPose-v0", motions=args.motions, num_envs=args.num_envs,
                                   progress=False, env_kwargs={"noise_scale": scale}).summary
            cells.append(f"{100 * s['no_fall']:.0f} % ({s['mpjpe']:.0f})")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    k = sub.add_parser("knobs", help="the tracker's falls with each estimator error removed")
    k.add_argument("--tracker", default="tracker")
    k.add_argument("--split", default="corpus:test")
    k.add_argument("--sequences", type=int, default=64)
    k.add_argument("--num-envs", type=int, default=16)
    r = sub.add_parser("refinement", help="a SimPoE policy's refinement error against the truth")
    r.add_argument("checkpoints", nargs="+")
    r.add_argument("--motions", default="corpus:train")
    r.add_argument("--frames", type=int, default=3200)
    r.add_argument("--seed", type=int, default=3)
    z = sub.add_parser("step0", help="the recipe's policy before PPO, by refinement pretraining target")
    z.add_argument("--motions", default="corpus:test")
    z.add_argument("--num-envs", type=int, default=16)
    z.add_argument("--threads", type=int, default=2)
    z.add_argument("--targets", nargs="+", choices=("untrained", "positions", "angles"),
                   default=["untrained", "positions", "angles"], help="the rows: refinement before PPO")
    z.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a recipe override (as train's --set), e.g. agent.policy.kwargs.refined_reference=true")
    f = sub.add_parser("families", help="no fall per motion family, from a run's evaluation files")
    f.add_argument("evals", nargs="+")
    e = sub.add_parser("endings", help="why a checkpoint's training episodes end")
    e.add_argument("checkpoint")
    e.add_argument("--termination-distance", type=float, default=None, help="m; 0: none (default: the checkpoint's)")
    e.add_argument("--num-envs", type=int, default=16)
    e.add_argument("--steps", type=int, default=600)
    e.add_argument("--seed", type=int, default=1)
    n = sub.add_parser("noise", help="policies' no fall on one family by noise scale")
    n.add_argument("policies", nargs="+")
    n.add_argument("--motions", default="corpus:test/walk")
    n.add_argument("--scales", type=float, nargs="+", default=[0.0, 0.5, 1.0])
    n.add_argument("--num-envs", type=int, default=8)
    args = parser.parse_args(argv)
    torch.set_num_threads(getattr(args, "threads", 1) if args.what == "step0" else 1)
    {"knobs": knobs, "refinement": refinement, "step0": step0, "families": families, "endings": endings,
     "noise": noise}[args.what](args)


if __name__ == "__main__":
    main()
