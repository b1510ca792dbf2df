"""Training throughput against the env's own stepping rate, measured side by side in one run.

    python benchmarks/bench_train.py [--worlds N] [--iterations 5] [--repeats 3] [--threads 1]
    python benchmarks/bench_train.py --ppo-recipe walk_residual_ppo --update-threads 2   # 64 worlds
    python benchmarks/bench_train.py ... --set agent.hyperparams.n_epochs=2              # any recipe value

Rates at the same number of worlds N (default: the PPO recipe's num_envs), each repeat
measuring all of them in turn (so load on the machine hits them alike), reported as medians of
`--repeats`:

- PPO: the `--ppo-recipe`'s agent (default `imitation_ppo`; its env id, env kwargs and
  hyperparameters) training on N worlds, samples/s over whole iterations (rollout collection +
  update + logging), after one untimed warm-up iteration (first reset, allocations);
- env: a second `gym.make_vec(id, num_envs=N, **recipe env kwargs)` stepped with the very
  actions PPO sent to its env in that repeat, replayed from a log (not timed), N x steps / s.
  The env's cost depends on what the actions do (uniformly random residual actions end episodes
  every few steps, and each end brings a reset-only step without physics: ~25 % more steps/s
  than under a policy's actions), so the training rate is compared with the env's rate under the
  same actions;
- env (random): the same env with uniformly random actions, for reference;
- AMP: PPO's recipe (env, kwargs and every PPO hyperparameter) plus the AMP-only settings of
  `--amp-recipe` (default `imitation_amp`: discriminator, style reward, windows), measured the
  same way, so AMP/PPO is the cost of AMP's extras alone. (`imitation_amp` is `imitation_ppo`
  plus those settings, so the default pair is the two recipes as they are.)

It prints PPO/env (the share of the env's rate training keeps) and AMP/PPO (what AMP's extras
cost), then one markdown table line. Torch runs on `--threads` CPU threads (default 1, as the
recipes recommend on small CPUs, where torch's pool fights the simulation for cores).
"""

from __future__ import annotations

import argparse
import copy
import os
import time

import gymnasium as gym
import mujoco
import numpy as np
import torch

import smpl_envs  # noqa: F401  (registers the ids)
from agents.ppo import PPOConfig
from agents.recipes import load_recipe
from agents.run import new_agent


class ActionLog(gym.vector.VectorWrapper):
    """Keeps a copy of every action batch sent to the env (`actions`, cleared by the caller)."""

    def __init__(self, env):
        super().__init__(env)
        self.actions: list[np.ndarray] = []

    def step(self, actions):
        self.actions.append(np.array(actions, copy=True))
        return self.env.step(actions)


def make_agent(recipe: dict, worlds: int, device: str, update_threads: int | None):
    env = recipe["env"]
    vec = ActionLog(gym.make_vec(env["id"], num_envs=worlds, **env["kwargs"]))
    return new_agent(recipe, env=vec, device=device, verbose=0, log_dir=None, tensorboard=False,
                     update_threads=update_threads)


def train_rate(agent, iterations: int) -> float:
    """Samples/s of `iterations` whole training iterations."""
    per_iteration = agent.config.n_steps * agent.env.num_envs
    start = agent.num_timesteps
    t = time.perf_counter()
    agent.learn(iterations * per_iteration, progress_bar=False, reset_num_timesteps=False)
    return (agent.num_timesteps - start) / (time.perf_counter() - t)


def amp_on(ppo_recipe: dict, amp_recipe: dict) -> dict:
    """PPO's recipe with AMP as the agent: PPO's settings, and AMP's own ones from `amp_recipe`."""
    ppo_names = set(PPOConfig.names())
    recipe = copy.deepcopy(ppo_recipe)
    recipe["agent"]["class"] = amp_recipe["agent"]["class"]
    recipe["agent"]["hyperparams"].update({k: v for k, v in amp_recipe["agent"]["hyperparams"].items()
                                           if k not in ppo_names})
    return recipe


def env_rate(env, actions: np.ndarray) -> float:
    """Steps/s (all worlds counted) of stepping every world with `actions` (steps, N, act_dim)."""
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    return env.num_envs * len(actions) / (time.perf_counter() - t)


def random_actions(env, steps: int, rng: np.random.Generator) -> np.ndarray:
    low, high = env.single_action_space.low, env.single_action_space.high
    return rng.uniform(low, high, (steps, env.num_envs, len(low))).astype(np.float32)


def logged_actions(agent) -> np.ndarray:
    actions = np.stack(agent.env.actions)
    agent.env.actions.clear()
    return actions


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ppo-recipe", default="imitation_ppo")
    p.add_argument("--amp-recipe", default="imitation_amp")
    p.add_argument("--worlds", type=int, default=None, help="worlds N (default: the PPO recipe's num_envs)")
    p.add_argument("--iterations", type=int, default=5, help="timed training iterations per repeat")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--update-threads", type=int, default=None,
                   help="torch CPU threads during the update only (default: as --threads)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a value of the PPO recipe (and so of AMP's), as `smpl-envs train --set`, "
                        "e.g. --set agent.hyperparams.n_epochs=2")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    ppo_recipe, amp_recipe = load_recipe(args.ppo_recipe, overrides=args.set), load_recipe(args.amp_recipe)
    env_id = ppo_recipe["env"]["id"]
    args.worlds = args.worlds or ppo_recipe["env"]["num_envs"]
    if amp_recipe["env"]["id"] != env_id:
        raise SystemExit(f"the recipes train on different envs: {env_id} and {amp_recipe['env']['id']}")

    env = gym.make_vec(env_id, num_envs=args.worlds, **ppo_recipe["env"]["kwargs"])
    env.reset(seed=0)
    ppo = make_agent(ppo_recipe, args.worlds, args.device, args.update_threads)
    amp = make_agent(amp_on(ppo_recipe, amp_recipe), args.worlds, args.device, args.update_threads)
    steps = ppo.config.n_steps * args.iterations  # per world: as many as PPO collects per repeat
    for agent in (ppo, amp):  # warm-up: the first reset and the first iteration's allocations
        agent.learn(agent.config.n_steps * args.worlds, progress_bar=False)
        logged_actions(agent)
    env_rate(env, random_actions(env, min(steps, 8), np.random.default_rng(1)))

    print(f"{os.cpu_count()} CPU cores, torch {torch.__version__} on {args.threads} thread(s) "
          f"({args.update_threads or args.threads} while updating), "
          f"MuJoCo {mujoco.__version__}; {env_id} at {args.worlds} worlds; {args.iterations} iterations "
          f"({ppo.config.n_steps} steps each) per repeat, {args.repeats} repeats (medians)", flush=True)
    rng = np.random.default_rng(0)
    rates = []
    for r in range(args.repeats):
        ppo_rate = train_rate(ppo, args.iterations)
        replayed = env_rate(env, logged_actions(ppo))
        random = env_rate(env, random_actions(env, steps, rng))
        amp_rate = train_rate(amp, args.iterations)
        logged_actions(amp)
        rates.append((replayed, ppo_rate, amp_rate, random))
        print(f"repeat {r + 1}: env {replayed:.0f} steps/s with PPO's actions ({random:.0f} with random ones), "
              f"PPO {ppo_rate:.0f} samples/s, AMP {amp_rate:.0f} samples/s", flush=True)
    rates = np.array(rates)
    env_s, ppo_s, amp_s, random_s = np.median(rates, 0)
    ppo_env, amp_ppo = np.median(rates[:, 1] / rates[:, 0]), np.median(rates[:, 2] / rates[:, 1])
    print(f"PPO/env {ppo_env:.2f}, AMP/PPO {amp_ppo:.2f} (PPO/env with random actions "
          f"{np.median(rates[:, 1] / rates[:, 3]):.2f})")
    print("| id | worlds | torch threads (update) | env steps/s (PPO's actions) | env steps/s (random) "
          "| PPO samples/s | AMP samples/s | PPO/env | AMP/PPO |")
    print("|---|---|---|---|---|---|---|---|---|")
    print(f"| `{env_id}` | {args.worlds} | {args.threads} ({args.update_threads or args.threads}) | {env_s:.0f} "
          f"| {random_s:.0f} | {ppo_s:.0f} | {amp_s:.0f} | {ppo_env:.2f} | {amp_ppo:.2f} |")
    for closeable in (env, ppo, amp):
        closeable.close()


if __name__ == "__main__":
    main()
