"""Adapters from the suite's native batched envs to other libraries' conventions.

`SB3VecEnv` presents a Gymnasium `VectorEnv` (such as `gym.make_vec("SMPL/Imitation-v0",
num_envs=N)`: N worlds stepped together in one process) as a Stable-Baselines3 `VecEnv`, which
SB3 requires and which the native env is not::

    import smpl_envs
    from smpl_envs.wrappers import SB3VecEnv
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    venv = SB3VecEnv("SMPL/Imitation-v0", num_envs=16, max_episode_steps=300)
    venv = VecNormalize(VecMonitor(venv))   # episode statistics for SB3's logs, then normalisation
    model = PPO("MlpPolicy", venv, n_steps=256, batch_size=1024)
    model.learn(1_000_000)

Stable-Baselines3 is an optional dependency: this module imports without it, and only using
`SB3VecEnv` needs it (it is built on first access, so importing this module stays light).

`NumpyVecEnv` is the NumPy view of a torch-native env (`backend="warp"`): actions in as NumPy
(or tensors), observations, rewards, flags and `info` out as NumPy, for code written against
NumPy (the evaluation protocols, other libraries). The data crosses from the device every step,
so training loops that can take tensors should use the env itself::

    env = NumpyVecEnv(gym.make_vec("SMPL/Imitation-v0", num_envs=1024, backend="warp", device="cuda"))

`LatentAction` gives any task PULSE's latent action space: the action becomes a in R^32,
decoded as D(s_p, mu_prior(s_p) + a) into the humanoid's 69 numbers by a PULSE checkpoint's
frozen prior and decoder (`smpl_envs.latent`), so any RL library learns a task in it::

    env = LatentAction(gym.make("SMPL/Speed-v0"), "agents/pretrained/pulse.pt")
    venv = LatentAction(gym.make_vec("SMPL/Speed-v0", num_envs=64), "agents/pretrained/pulse.pt")
"""
from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv

__all__ = ["SB3VecEnv", "NumpyVecEnv", "LatentAction", "LatentActionVec"]


def _numpy(x):
    if isinstance(x, dict):
        return {k: _numpy(v) for k, v in x.items()}
    if isinstance(x, (tuple, list)):
        return type(x)(_numpy(v) for v in x)
    return x.detach().cpu().numpy() if hasattr(x, "detach") else x


class NumpyVecEnv(gym.vector.VectorWrapper):
    """A torch-native vector env seen through NumPy (its arrays copied to the host each call);
    on a NumPy env it changes nothing. Attributes and methods of the env read through."""

    def reset(self, *, seed=None, options=None):
        return _numpy(self.env.reset(seed=seed, options=options))

    def step(self, actions):
        return _numpy(self.env.step(actions))

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.env, name)

class _LatentMap:
    """What the one-world and the vector LatentAction share: the decoder, the checks of the env
    it drives, and the map from latent to env actions on the last observation."""

    # Shared by the one-world and the vector wrapper: the mixin comes first in their MROs.
    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._obs = obs
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(self._decode(action))
        self._obs = obs
        return obs, reward, terminated, truncated, info

    def _setup(self, env, decoder, device) -> None:
        from . import policy_settings
        from .env_ids import ENV_IDS
        from .latent import as_latent_decoder

        env_id = policy_settings.env_id_of(env)
        if env_id is None or env_id.split(":", 1)[-1] not in ENV_IDS:
            raise ValueError("LatentAction drives an smpl_envs task (its observation starts with the self observation "
                             f"the decoder reads); this env is {env_id or type(env.unwrapped).__name__}")
        self.decoder = as_latent_decoder(decoder)
        box = getattr(env, "single_action_space", env.action_space)
        if box.shape != (self.decoder.action_dim,) or not (np.all(box.low == -1) and np.all(box.high == 1)):
            raise ValueError(f"the decoder acts in [-1, 1]^{self.decoder.action_dim}; the env's actions are {box}")
        # The decoder's actions mean what they meant where it was distilled: the same control
        # period, absolute PD targets.
        env_settings = policy_settings.settings_of(env)
        for name, value in (self.decoder.settings or {}).items():
            if name in env_settings and env_settings[name] != value:
                raise ValueError(f"the env runs {name}={env_settings[name]!r}, the decoder was distilled with "
                                 f"{name}={value!r}; make the env with {name}={value!r}")
        if env_settings.get("action_mode", "absolute") != "absolute":
            raise ValueError("the decoder's actions are absolute PD targets; make the env with action_mode='absolute'")
        self.device = device
        self._obs = None

    def _box(self, bound: float) -> gym.spaces.Box:
        if not (np.isfinite(bound) and bound > 0):
            raise ValueError(f"bound must be a positive finite number, got {bound!r}")
        return gym.spaces.Box(-float(bound), float(bound), (self.decoder.latent_dim,), np.float32)

    def _decode(self, action):
        import torch

        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        native = isinstance(self._obs, torch.Tensor)
        obs = self._obs if native else torch.as_tensor(self._obs, dtype=torch.float32)
        device = self.device or obs.device
        if next(self.decoder.buffers()).device != torch.device(device):
            self.decoder.to(device)
        a = torch.as_tensor(action, dtype=torch.float32, device=device)
        with torch.no_grad():
            out = self.decoder(obs.to(device), a)
        return out.to(obs.device) if native else out.cpu().numpy()


class LatentAction(_LatentMap, gym.Wrapper, gym.utils.RecordConstructorArgs):
    """A task whose action is a latent action a in R^32, neither scaled nor clipped (as PULSE's
    tasks act): the env gets D(s_p, mu_prior(s_p) + a), computed on the observation the action
    answers, so a = 0 acts the prior's mean.

    `LatentAction(env, decoder, device=None, bound=5.0)`: env a single task env (`gym.make`) or
    a native vector env (`gym.make_vec`; then the instance is a `LatentActionVec`); decoder a
    PULSE checkpoint path, a `latent.LatentDecoder`, or an object with one as `latent_decoder`
    (an agents.PULSE). The env must share the decoder's recorded settings (substeps) and take
    absolute actions. device: where the decoder runs (default: the observations' device).
    bound: the half width of the action Box, [-bound, bound]^32. Finite because RL libraries
    need it (Stable-Baselines3 refuses unbounded Boxes); the wrapper does not clip to it, and
    5 lies far beyond where PULSE's policies act (a bounds loss keeps their mean within 1)."""

    def __new__(cls, env, *args, **kwargs):
        if cls is LatentAction and isinstance(env, VectorEnv):
            return LatentActionVec(env, *args, **kwargs)
        return super().__new__(cls)

    def __init__(self, env: gym.Env, decoder, device=None, bound: float = 5.0):
        # Recorded in env.spec, so gym.make(env.spec) (and Gymnasium's env checker) makes it again.
        gym.utils.RecordConstructorArgs.__init__(self, decoder=decoder, device=device, bound=bound)
        gym.Wrapper.__init__(self, env)
        self._setup(env, decoder, device)
        self.action_space = self._box(bound)


class LatentActionVec(_LatentMap, gym.vector.VectorWrapper):
    """`LatentAction` of a vector env: N worlds, each acting in the latent space, decoded in one
    batch on the observations the env last returned (NumPy, or tensors of a torch-native env)."""

    def __init__(self, env: VectorEnv, decoder, device=None, bound: float = 5.0):
        gym.vector.VectorWrapper.__init__(self, env)
        self._setup(env, decoder, device)
        self.single_action_space = self._box(bound)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, env.num_envs)


# Keys of a SameStep info dict that describe the finished episode rather than the current one.
_FINAL_KEYS = ("final_obs", "final_info")


class _SB3VecEnvMethods:
    """A Stable-Baselines3 `VecEnv` over a native batched env: N worlds in one process.

    `SB3VecEnv(env_or_id, num_envs=None, **make_kwargs)`: `env_or_id` is an env id, made with
    `gym.make_vec(env_or_id, num_envs=num_envs or 1, autoreset_mode="SameStep", **make_kwargs)`
    (make_kwargs are the task's kwargs, e.g. motions, max_episode_steps, termination_distance),
    or an existing `gymnasium.vector.VectorEnv` made with autoreset_mode="SameStep".

    SB3's conventions: `reset()` returns the observations only (their infos are in
    `reset_infos`); `step` returns float32 observations, float32 rewards, `dones` =
    terminated | truncated and a list of N info dicts. A finished world restarts within the same
    step: the returned observation is the new episode's first, the last one of the finished
    episode is `infos[i]["terminal_observation"]`, `infos[i]` is the info of the finished
    episode's last step (from `info["final_info"]`, plus keys that only wrappers added) and the
    new episode's reset info goes to `reset_infos[i]`.
    `infos[i]["TimeLimit.truncated"]` is truncated and not terminated, for every world and step.
    Per-world info dicts hold row i of each batched info array (keys starting with "_" and the
    final_* keys are left out; a key whose "_key" mask is False for world i is absent).

    The worlds share one env object, hence these departures from a VecEnv of N separate envs:
    `seed(s)` seeds the batched env's one generator with s at the next reset (every world's
    entry of the returned list is s); `set_options` takes one options dict for all worlds (the
    native options such as reset_mask or motion_ids address worlds themselves); `get_attr`
    returns the batched env's attribute once per requested index (an (N, ...) array stays
    whole); `env_method` calls the method once and repeats its result; `set_attr` sets the
    attribute for all worlds and refuses a subset; `env_is_wrapped` is False for every world
    (the worlds are not gymnasium.Env objects). When made with render_mode="rgb_array",
    `get_images()` gives one frame per world and SB3's `render()` tiles them into one image.
    Episode returns and lengths for SB3's logs come from wrapping this in `VecMonitor`.
    """

    def __init__(self, env_or_id: str | VectorEnv, num_envs: int | None = None, **make_kwargs):
        self.vector_env = _make_same_step(env_or_id, num_envs, make_kwargs)
        self._actions: np.ndarray | None = None
        self._closed = False
        venv = self.vector_env
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        if "render_fps" in venv.metadata:  # SB3's VecVideoRecorder reads it
            self.metadata = {**self.metadata, "render_fps": venv.metadata["render_fps"]}

    # ------------------------------------------------------------------ stepping
    def reset(self) -> np.ndarray:
        options = self._shared_options()
        obs, info = self.vector_env.reset(seed=self._seeds[0], options=options)
        self.reset_infos = [_world_info(info, i) for i in range(self.num_envs)]
        # As SB3's own VecEnvs: seeds and options apply to one reset only.
        self._reset_seeds()
        self._reset_options()
        return np.array(obs, dtype=np.float32)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async(actions)")
        actions, self._actions = self._actions, None
        obs, reward, terminated, truncated, info = self.vector_env.step(actions)
        # A copy: the learner keeps these arrays while the env may reuse its buffers.
        obs = np.array(obs, dtype=np.float32)
        terminated, truncated = np.asarray(terminated, bool), np.asarray(truncated, bool)
        dones = terminated | truncated
        infos = [_world_info(info, i) for i in range(self.num_envs)]
        if dones.any():
            final_obs, final_mask = info.get("final_obs"), info.get("_final_obs")
            if final_obs is None or final_mask is None or not np.asarray(final_mask)[dones].all():
                raise RuntimeError("the vector env ended episodes without info['final_obs']; it must "
                                   "be made with autoreset_mode='SameStep'")
            final_info, final_info_mask = info.get("final_info"), info.get("_final_info")
            for i in np.flatnonzero(dones):
                # The info already returned describes the new episode: it is the reset info.
                self.reset_infos[i] = infos[i]
                infos[i] = dict(infos[i])
                if final_info is not None and final_info_mask is not None and final_info_mask[i]:
                    # The last step's values win; keys only wrappers add on top (e.g. Gymnasium's
                    # RecordEpisodeStatistics' "episode") stay.
                    infos[i].update(_world_info(final_info, i))
                infos[i]["terminal_observation"] = np.array(final_obs[i], dtype=np.float32)
        for i in range(self.num_envs):
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        return obs, np.asarray(reward, dtype=np.float32), dones, infos

    def seed(self, seed: int | None = None) -> list[int | None]:
        if seed is None:  # as SB3 does: pick one, so the seed returned can be logged and reused
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [int(seed)] * self.num_envs
        return list(self._seeds)

    def _shared_options(self) -> dict | None:
        options = [dict(o or {}) for o in self._options]
        if not any(options):
            return None
        if any(o != options[0] for o in options[1:]):
            raise ValueError("SB3VecEnv passes one options dict to the batched env's reset; give the same "
                             "options for every world (use its reset_mask / motion_ids options to address "
                             "single worlds)")
        return options[0]

    # ------------------------------------------------------------------ attributes and methods
    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        value = self._env_attr(attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        self._require_all(indices, "set_attr")
        setattr(self._attr_owner(attr_name), attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        result = self._env_attr(method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def _env_attr(self, name: str) -> Any:
        return getattr(self._attr_owner(name), name)

    def _attr_owner(self, name: str) -> Any:
        # Gymnasium's vector wrappers do not forward arbitrary attributes; the task env has them.
        venv = self.vector_env
        if hasattr(venv, name) or not hasattr(venv.unwrapped, name):
            return venv
        return venv.unwrapped

    def _require_all(self, indices, what: str) -> None:
        chosen = sorted({int(i) % self.num_envs for i in self._get_indices(indices)})
        if chosen != list(range(self.num_envs)):
            raise ValueError(f"{what}: the {self.num_envs} worlds share one env object, so an attribute can only "
                             f"be set for all of them (indices=None), not for {chosen}")

    # ------------------------------------------------------------------ rendering and closing
    def get_images(self) -> list[np.ndarray | None]:
        if self.render_mode != "rgb_array":
            return [None] * self.num_envs
        return list(self.vector_env.render())

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.vector_env.close()


def _make_same_step(env_or_id: str | VectorEnv, num_envs: int | None, make_kwargs: dict) -> VectorEnv:
    if isinstance(env_or_id, str):
        mode = make_kwargs.pop("autoreset_mode", AutoresetMode.SAME_STEP)
        if _autoreset_value(mode) != AutoresetMode.SAME_STEP.value:
            raise ValueError(f"SB3VecEnv needs autoreset_mode='SameStep' (SB3 resets within the step), got {mode!r}")
        kwargs: dict[str, Any] = dict(make_kwargs)
        if gym.spec(env_or_id).vector_entry_point is None:
            # Other ids are vectorised by gymnasium's SyncVectorEnv, which takes the mode itself.
            kwargs["vector_kwargs"] = {**kwargs.get("vector_kwargs", {}), "autoreset_mode": AutoresetMode.SAME_STEP}
        else:
            kwargs["autoreset_mode"] = AutoresetMode.SAME_STEP.value
        return gym.make_vec(env_or_id, num_envs=1 if num_envs is None else int(num_envs), **kwargs)
    if not isinstance(env_or_id, VectorEnv):
        raise TypeError(f"SB3VecEnv takes an env id or a gymnasium.vector.VectorEnv, got {type(env_or_id).__name__}; "
                        "for single gymnasium.Env objects use SB3's DummyVecEnv")
    if make_kwargs:
        raise TypeError(f"kwargs {sorted(make_kwargs)} only apply when SB3VecEnv makes the env from an id")
    if num_envs is not None and num_envs != env_or_id.num_envs:
        raise ValueError(f"num_envs={num_envs} but the given env has {env_or_id.num_envs} worlds")
    mode = env_or_id.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
    if _autoreset_value(mode) != AutoresetMode.SAME_STEP.value:
        raise ValueError(f"the vector env's autoreset mode is {_autoreset_value(mode)!r}; SB3VecEnv needs one made "
                         "with autoreset_mode='SameStep'")
    return env_or_id


def _autoreset_value(mode) -> str:
    return mode.value if isinstance(mode, AutoresetMode) else str(mode)


def _world_info(info: dict, i: int) -> dict:
    """World i's info from a batched (Gymnasium vector) info dict."""
    out = {}
    for key, value in info.items():
        if key.startswith("_") or key in _FINAL_KEYS:
            continue
        mask = info.get("_" + key)
        if mask is not None and not mask[i]:
            continue  # Gymnasium's convention: the key does not apply to this world this step
        if isinstance(value, dict):
            out[key] = _world_info(value, i)
        elif isinstance(value, np.ndarray) and value.ndim > 0:
            out[key] = value[i].copy()
        else:  # a value the env did not batch: the same for every world
            out[key] = value
    return out


def _sb3_vec_env_class() -> type:
    try:
        from stable_baselines3.common.vec_env import VecEnv
    except ImportError as e:
        raise ImportError("smpl_envs.wrappers.SB3VecEnv needs Stable-Baselines3: pip install stable-baselines3") from e
    cls = type("SB3VecEnv", (_SB3VecEnvMethods, VecEnv), {"__module__": __name__,
                                                          "__doc__": _SB3VecEnvMethods.__doc__})
    cls.__qualname__ = "SB3VecEnv"
    return cls


def __getattr__(name: str):
    # Built on first use, so that importing this module neither needs nor loads SB3 (and torch).
    if name == "SB3VecEnv":
        cls = _sb3_vec_env_class()
        globals()[name] = cls
        return cls
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
