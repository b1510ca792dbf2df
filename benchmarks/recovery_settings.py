"""A recovery primitive under other goal settings, with no training: what a change of the guides
would give before a run is spent on it, and where the trials that fail go wrong.

    # PHC's protocol with the settings swapped (any of Recovery-v0's `goal_settings`)
    python benchmarks/recovery_settings.py training/recovery_brisk --set walk_guide=brisk_exact --set guide_restart=0.4
    # one setting over several values, fallen starts only
    python benchmarks/recovery_settings.py training/recovery_brisk --kinds fallen --trials 192 \\
        --set walk_guide=brisk_exact --sweep guide_restart=0.3,0.4,0.5,0.6
    # per-trial timelines of 32 fallen trials: when the body is first up, how many get-ups it was
    # shown, when it is back, where it ends
    python benchmarks/recovery_settings.py training/recovery_brisk --trace 32 --kinds fallen

The settings a policy trained with stay, except the goal settings given here (which clips the
goal shows; a fine-tune may change them too, `agents.warm_start`): `smpl_envs.evaluate` with
`override_settings`, the protocol's seeds, deterministic actions. A trace runs the protocol's
first wave of the first kind given, stepping the env itself and reading the guides' state.
"""
from __future__ import annotations

import argparse

import numpy as np
import yaml

import agents
import smpl_envs
from agents.recipes import find_checkpoint
from smpl_envs.envs.recovery import RecoveryProtocol, RecoveryVecEnv, _distance, lying_at_start
from smpl_envs.evaluation import policy_actions
from smpl_envs.metrics import recovered_within, recovery_frame

ENV_ID = "SMPL/Recovery-v0"
UP_HEIGHT = 0.7  # m of pelvis height from which a body counts as up (standing: ~0.9)


def parse_settings(pairs: list[str], many: bool = False) -> dict:
    """{key: value} of KEY=VALUE pairs (with `many`, {key: [values]} of KEY=V1,V2,...), goal settings only."""
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise SystemExit(f"--set/--sweep takes key=value, got {pair!r}")
        if key not in RecoveryVecEnv.goal_settings:
            raise SystemExit(f"{key!r} is not a goal setting; these may change: {list(RecoveryVecEnv.goal_settings)}")
        out[key] = [yaml.safe_load(v) for v in value.split(",")] if many else yaml.safe_load(value)
    return out


def evaluate(agent, settings: dict, kinds: list[str], trials: int, num_envs: int):
    return smpl_envs.evaluate(agent, ENV_ID, num_envs=num_envs, env_kwargs=settings, override_settings=set(settings),
                              trials=trials, kinds=kinds, progress=False)


def trace(agent, settings: dict, kind: str, n: int, seed: int = 0) -> list[dict]:
    """One wave of `n` trials from `kind` starts (the protocol's first, seed `seed`), per trial:
    how it lay, when it was first up, how many get-ups it was shown, when it was back (None:
    not within 10 s), its final distance and pelvis distance from the goal."""
    from smpl_envs import policy_settings
    from smpl_envs.backend import runnable_here

    protocol = RecoveryProtocol()
    options = protocol.check_options({"trials": n, "seed": seed})
    trained_id, trained = policy_settings.training_record(agent)
    kwargs = policy_settings.with_trained_settings(ENV_ID, trained, {**runnable_here(protocol.eval_kwargs(trained)),
                                                                     **settings}, set(settings))
    env = protocol.make_env(ENV_ID, None, n, kwargs, False, options)
    u = env.unwrapped
    try:
        obs, info = env.reset(seed=seed, options={"recovery_start": kind, "start": "beginning"})
        lying = lying_at_start(u.sim.bodies.rot[:, 0], u.sim.bodies.pos[:, 0])
        steps = u.max_episode_steps
        height, root = np.zeros((n, steps)), np.zeros((n, steps))
        dist = np.zeros((n, steps + 1))  # frame 0: the start, as the protocol counts
        dist[:, 0] = _distance(info)
        getups = np.zeros(n, int)
        guide = u.recovery.guide
        for t in range(steps):
            age = None if guide is None else np.array(guide.age)
            obs, _, _, _, info = env.step(policy_actions(agent, np.array(obs, copy=True)))
            height[:, t], dist[:, t + 1], root[:, t] = info["body_pos"][:, 0, 2], _distance(info), info["root_distance"]
            if guide is not None:  # a get-up (re)started this step: its age went back to 0
                getups += np.asarray(guide.active) & (np.array(guide.age) < age)
    finally:
        env.close()
    frames = recovery_frame(dist, protocol.options["threshold"])
    rows = []
    for w in range(n):
        up = np.flatnonzero(height[w] > UP_HEIGHT)
        back = frames[w] if recovered_within(frames[w], 10.0) else None
        rows.append({"lying": lying[w], "first_up_s": (up[0] + 1) / 30 if len(up) else None,
                     "getups": int(getups[w]) + (kind != "far"), "back_s": None if back is None else back / 30,
                     "final_m": float(dist[w, -1]), "final_pelvis_m": float(root[w, -1])})
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", help="a Recovery-v0 policy: .pt file, run directory (its best.pt) or shipped name")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a goal setting to swap in")
    p.add_argument("--sweep", metavar="KEY=V1,V2,...", help="evaluate once per value of one goal setting")
    p.add_argument("--kinds", nargs="+", default=list(RecoveryProtocol.kinds), choices=RecoveryProtocol.kinds)
    p.add_argument("--trials", type=int, default=200, help="trials per start kind (PHC: 1000)")
    p.add_argument("--num-envs", type=int, default=64)
    p.add_argument("--trace", type=int, metavar="N", help="per-trial timelines of N trials of the first kind instead")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)

    import torch

    torch.set_num_threads(args.threads)
    agent = agents.load(find_checkpoint(args.checkpoint))
    settings = parse_settings(args.set)
    if args.trace:
        rows = trace(agent, settings, args.kinds[0], args.trace)
        print(f"{'trial':>5} {'lying':>6} {'first up s':>10} {'get-ups':>8} {'back s':>7} {'final m':>8} {'pelvis m':>9}")
        for k, r in enumerate(rows):
            fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
            print(f"{k:>5} {r['lying']:>6} {fmt(r['first_up_s']):>10} {r['getups']:>8} {fmt(r['back_s']):>7} "
                  f"{r['final_m']:>8.2f} {r['final_pelvis_m']:>9.2f}")
        print(f"back within 10 s: {sum(r['back_s'] is not None for r in rows)} of {len(rows)}")
        return
    if args.sweep:
        (key, values), = parse_settings([args.sweep], many=True).items()
        runs = [({**settings, key: v}, f"{key}={v}") for v in values]
    else:
        runs = [(settings, ", ".join(f"{k}={v}" for k, v in settings.items()) or "as trained")]
    for swapped, label in runs:
        result = evaluate(agent, swapped, args.kinds, args.trials, args.num_envs)
        s = result.summary
        rates = "   ".join(f"{k} {100 * s[f'succ_5s_{k}']:.1f} / {100 * s[f'succ_10s_{k}']:.1f} %" for k in args.kinds)
        print(f"{label}: Succ-5s / 10s  {rates}")


if __name__ == "__main__":
    main()
