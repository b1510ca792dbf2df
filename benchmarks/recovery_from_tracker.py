"""PHC's recovery protocol on a policy trained only to imitate: does a tracker that has learnt the
get-up family (tasks/tracker_getup_ppo.yaml) rise when Recovery-v0 shows it a get-up?

    python benchmarks/recovery_from_tracker.py runs/tracker_getup --trials 200
    python benchmarks/recovery_from_tracker.py tracker --trials 200 --no-guide     # the shipped tracker

`smpl-envs eval` runs a policy only on the task it was trained on; this runs an Imitation-v0
policy on SMPL/Recovery-v0 (Imitation with recovery on: the same observation and action), in its
trained action settings (action_mode, residual_scale, substeps), with the get-up guide
(`getup_guide`, docs/tasks/recovery.md) unless --no-guide. It is the starting point a recovery
primitive fine-tuned from this tracker (tasks/recovery_getup_ppo.yaml) begins at, measured with
the same protocol as that run's evaluations: Succ-5s and Succ-10s from fallen, far (3 m) and
fallen+far starts, deterministic actions, seeded.
"""
from __future__ import annotations

import argparse
import json

import smpl_envs
from smpl_envs.policy_settings import training_record

PHC = {"fallen": 98.8, "far": 99.5, "fallen+far": 98.8}  # PHC's Succ-10s (REFERENCE.md section 3)
ACTION_SETTINGS = ("action_mode", "residual_scale", "substeps")


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", help="an Imitation-v0 policy: .pt file, run directory (its best.pt) or shipped name")
    p.add_argument("--trials", type=int, default=200, help="trials per start kind (PHC: 1000)")
    p.add_argument("--num-envs", type=int, default=50)
    p.add_argument("--no-guide", action="store_true", help="the point goal only, as PHC shows it")
    p.add_argument("--guide", default="corpus:getup", help="the get-up clips shown to a body down")
    p.add_argument("--walk-guide", action="store_true", help="a walk to the goal shown to a standing body far from it")
    p.add_argument("--action-base", default="reference", choices=("reference", "pull", "pose", "target"),
                   help="recovery_action_base while the goal is the recovery form (and not a get-up)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", help="JSON file for the summary")
    args = p.parse_args(argv)

    import torch

    import agents
    from agents.recipes import find_checkpoint

    torch.set_num_threads(args.threads)
    model = agents.load(find_checkpoint(args.checkpoint))
    record = training_record(model)
    if record is None or record[0] != "SMPL/Imitation-v0":
        raise SystemExit(f"{args.checkpoint} must be an SMPL/Imitation-v0 policy, "
                         f"it was trained on {record and record[0]}")
    trained = record[1]
    kwargs = {k: trained[k] for k in ACTION_SETTINGS if k in trained}
    kwargs["recovery_action_base"] = args.action_base
    if not args.no_guide:
        kwargs["getup_guide"] = args.guide
    if args.walk_guide:
        kwargs["walk_guide"] = True
    # A bare callable: the policy's own training record would (rightly) refuse another task id;
    # the settings that give its actions their meaning are passed on above instead.
    result = smpl_envs.evaluate(lambda obs: model.predict(obs, deterministic=True)[0], "SMPL/Recovery-v0",
                                num_envs=args.num_envs, env_kwargs=kwargs, trials=args.trials)
    s = result.summary
    guide = ", ".join([*([] if args.no_guide else [f"get-up guide {args.guide}"]),
                       *(["walk guide"] if args.walk_guide else [])]) or "point goal only"
    print(f"{args.checkpoint} on SMPL/Recovery-v0 ({guide}; {kwargs}), {args.trials} trials per kind")
    print(f"{'start':<12}{'Succ-5s':>9}{'Succ-10s':>10}{'final distance (m)':>20}{'PHC Succ-10s':>14}")
    for kind in PHC:
        print(f"{kind:<12}{100 * s[f'succ_5s_{kind}']:>8.1f}%{100 * s[f'succ_10s_{kind}']:>9.1f}%"
              f"{s[f'final_distance_{kind}']:>20.2f}{PHC[kind]:>13.1f}%")
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"checkpoint": args.checkpoint, "env_kwargs": kwargs, "trials": args.trials, **s}, f, indent=1)
    return s


if __name__ == "__main__":
    main()
