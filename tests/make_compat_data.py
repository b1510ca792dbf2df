"""Writes tests/data/compat/: checkpoints in the format before policies were plug-ins, and the
actions the code of that time gave on fixed observations.

Run once with the code whose checkpoints must keep loading (it was generated at commit 154a8bb,
before checkpoints recorded their policy class); `test_policy_plugins.py` loads the files with
today's code and requires the very same actions, and resumes training from them.

- ppo_v1.pt: a tiny PPO on SMPL/Imitation-v0 (walk, residual actions), two iterations, with its
  optimiser; amp_v1.pt: the same for AMP; pendulum_v1.pt: a PPO on Pendulum-v1, whose action
  box is [-2, 2] (the old agent rescaled the policy's [-1, 1] onto it).
- actions_v1.npz: per checkpoint (those above and the shipped walk.pt and clips.pt),
  `<name>/obs` and the deterministic `<name>/actions` of `predict`.
"""
from pathlib import Path

import gymnasium as gym
import numpy as np

import smpl_envs  # noqa: F401
import agents
from agents import AMP, PPO
from agents.recipes import find_checkpoint

OUT = Path(__file__).parent / "data" / "compat"
TINY = dict(actor_hidden=[16], critic_hidden=[16], verbose=0, device="cpu", seed=0)
IMITATION = dict(env_kwargs={"motions": "walk", "action_mode": "residual", "residual_scale": 0.25},
                 n_envs=2, n_steps=8, batch_size=16, n_epochs=1)


def imitation_observations() -> np.ndarray:
    """Twelve observations of SMPL/Imitation-v0: real ones (two steps of four worlds on walk
    and run) and four far outside anything seen, which the normaliser clips."""
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=4, motions=["walk", "run"])
    first, _ = env.reset(seed=0)
    second = env.step(np.full((4, 69), 0.1, np.float32))[0]
    env.close()
    wild = np.random.default_rng(0).normal(0.0, 30.0, (4, first.shape[1]))
    return np.concatenate([first, second, wild]).astype(np.float32)


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    models = {
        "ppo_v1": PPO("SMPL/Imitation-v0", **IMITATION, **TINY),
        "amp_v1": AMP("SMPL/Imitation-v0", **IMITATION, disc_hidden=[16], replay_size=64, **TINY),
        "pendulum_v1": PPO("Pendulum-v1", n_envs=2, n_steps=16, batch_size=32, log_std_init=0.5, **TINY),
    }
    arrays = {}
    imitation_obs = imitation_observations()
    for name, model in models.items():
        model.learn(2 * model.env.num_envs * model.n_steps, progress_bar=False)
        model.save(OUT / f"{name}.pt")
        obs = (np.random.default_rng(1).normal(0.0, 3.0, (12, 3)).astype(np.float32) if name == "pendulum_v1"
               else imitation_obs)
        arrays[f"{name}/obs"], arrays[f"{name}/actions"] = obs, model.predict(obs)[0]
        model.close()
    for name in ("walk", "clips"):
        arrays[f"{name}/obs"] = imitation_obs
        arrays[f"{name}/actions"] = agents.load(find_checkpoint(name), device="cpu").predict(imitation_obs)[0]
    np.savez_compressed(OUT / "actions_v1.npz", **arrays)
    for p in sorted(OUT.iterdir()):
        print(p, p.stat().st_size)
