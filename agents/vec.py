"""What the agents need from Gymnasium's vector API: one batched env, whatever the user passed."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv


def make_vec_env(env: str | gym.Env | VectorEnv, n_envs: int = 1, env_kwargs: dict | None = None,
                 seed: int | None = None) -> VectorEnv:
    """A vector env from an id (native `vector_entry_point` when the id has one, else a
    synchronous vector of copies), a single env (a vector of one), or a vector env as is."""
    env_kwargs = dict(env_kwargs or {})
    if isinstance(env, str):
        env = _import_env_module(env)
        spec = gym.spec(env)
        mode = "vector_entry_point" if spec.vector_entry_point is not None else "sync"
        vec = gym.make_vec(env, num_envs=n_envs, vectorization_mode=mode, **env_kwargs)
    elif isinstance(env, VectorEnv):
        vec = env
    elif isinstance(env, gym.Env):
        vec = gym.vector.SyncVectorEnv([lambda: env], autoreset_mode=AutoresetMode.NEXT_STEP)
    else:
        raise TypeError(f"env must be an env id, a gymnasium.Env or a gymnasium.vector.VectorEnv, got {type(env)}")
    if env_kwargs and not isinstance(env, str):
        raise ValueError("env_kwargs only apply when env is given as an id")
    if not isinstance(vec.single_action_space, gym.spaces.Box):
        raise TypeError(f"the agents need a Box action space, this env has {vec.single_action_space}")
    if not isinstance(vec.single_observation_space, gym.spaces.Box) or len(vec.single_observation_space.shape) != 1:
        raise TypeError(f"the agents need a flat Box observation space, this env has {vec.single_observation_space}")
    if autoreset_mode(vec) == AutoresetMode.DISABLED:
        raise ValueError("the env's autoreset mode is Disabled; agents need NextStep or SameStep autoreset")
    return vec


def _import_env_module(env_id: str) -> str:
    """Register the ids of "module:Id" strings and of the suite's own SMPL/ namespace."""
    import importlib

    if ":" in env_id:
        module, env_id = env_id.split(":", 1)
        importlib.import_module(module)
    if env_id.startswith("SMPL/"):
        importlib.import_module("smpl_envs")
    return env_id


def autoreset_mode(vec: VectorEnv) -> AutoresetMode:
    mode = vec.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
    return AutoresetMode(mode.value if isinstance(mode, AutoresetMode) else mode)


def final_observations(obs: np.ndarray, info: dict, done: np.ndarray, mode: AutoresetMode) -> np.ndarray:
    """The observation each world's step really ended in, also for worlds the vector has already
    reset (SameStep puts those in info["final_obs"]; NextStep returns them as `obs`)."""
    if mode != AutoresetMode.SAME_STEP or not done.any():
        return obs
    if not isinstance(obs, np.ndarray):  # a torch-native vector env: one batched array
        import torch

        return torch.where((done & info.get("_final_obs", done))[:, None], info["final_obs"], obs)
    out = obs.copy()
    for i in np.flatnonzero(done & info.get("_final_obs", done)):
        out[i] = info["final_obs"][i]
    return out


def final_info_array(info: dict, key: str, done: np.ndarray, mode: AutoresetMode) -> np.ndarray | None:
    """`info[key]` as it was at the end of each world's step (before a SameStep reset)."""
    if key not in info:
        return None
    if not isinstance(info[key], np.ndarray) and hasattr(info[key], "detach"):  # a torch-native env
        value, final = info[key], info.get("final_info")
        if mode == AutoresetMode.SAME_STEP and done.any() and isinstance(final, dict) and key in final:
            value = final[key].where(done.reshape(-1, *[1] * (value.dim() - 1)), value)
        return value
    value = np.asarray(info[key])
    if mode == AutoresetMode.SAME_STEP and done.any() and "final_info" in info:
        final = info["final_info"]
        value = value.copy()
        ids = np.flatnonzero(done)
        if isinstance(final, dict) and key in final:  # native vector envs: one dict of arrays
            value[ids] = np.asarray(final[key])[ids]
        else:  # a sequence of per-env dicts
            for i in ids:
                value[i] = final[i][key]
    return value


def reward_terms(info: dict, valid: np.ndarray) -> dict[str, float]:
    """Means over valid worlds of every scalar `reward_*` entry the env reports in `info`
    (0-d tensors, left on the device, for a torch-native env)."""
    if not isinstance(valid, np.ndarray):
        out = {}
        for k, v in info.items():
            mask = valid & info.get("_" + k, valid)
            if k.startswith("reward_") and v.shape == valid.shape:
                out[k[len("reward_"):]] = v.double().where(mask, 0.0).sum() / mask.sum().clip(min=1)
        return out
    out = {}
    for k, v in info.items():
        if not k.startswith("reward_"):
            continue
        v = np.asarray(v, dtype=np.float64)
        mask = valid & np.asarray(info.get("_" + k, np.ones_like(valid)), bool)
        if v.shape == valid.shape and mask.any():
            out[k[len("reward_"):]] = float(v[mask].mean())
    return out
