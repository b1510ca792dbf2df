"""What the episode-outcome benchmarks (`strike_outcomes.py`, `reach_outcomes.py`,
`speed_outcomes.py`) share: their command line (a run, checkpoint or shipped name; how many
episodes, worlds and the first seed) and the checkpoint loaded with its own env settings, refused
if it was trained on another task."""

from __future__ import annotations

import argparse


def open_policy_env(doc: str, env_id: str, argv=None):
    """Parse the command line described by `doc`, load the checkpoint and make its env (its own
    kwargs, no autoreset). Returns (args, agent, checkpoint path, env, worlds)."""
    import gymnasium as gym
    import torch

    p = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    p.add_argument("target", help="a run directory, checkpoint or shipped name")
    p.add_argument("--checkpoint", choices=("best", "last"), default="last")
    p.add_argument("--episodes", type=int, default=64)
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--seed", type=int, default=1000, help="the first episode seed (the protocol's stream is another)")
    args = p.parse_args(argv)
    if args.episodes < 1 or args.num_envs < 1:
        p.error("--episodes and --num-envs must be at least 1")
    torch.set_num_threads(1)

    import smpl_envs  # noqa: F401  (registers the ids)
    from agents.checkpoint_commands import load_target

    agent, ckpt, _, _ = load_target(args.target, args.checkpoint, "cpu")
    if agent.env_id != env_id:
        p.error(f"{ckpt} was trained on {agent.env_id}, not {env_id}")
    n = min(args.num_envs, args.episodes)
    env = gym.make_vec(agent.env_id, num_envs=n, autoreset_mode="Disabled", **agent.env_kwargs)
    return args, agent, ckpt, env, n
