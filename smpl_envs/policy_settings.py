"""A trained policy runs in the env it was trained in: its task, and the settings that give its
actions and observations their meaning.

A policy in the wrong env acts without any error and is silently wrong: the shipped residual
`walk` policy driven with absolute actions fails the clip at 265 mm instead of tracking it at
27 mm, and a Speed policy runs on Reach (both observe 361 numbers). Agents record the env id and
kwargs they trained with (`agents.PPO.save`, as `policy.env_id` and `policy.env_kwargs`);
`smpl_envs.evaluate`, `smpl_envs.record` and `agents.PPO.load` / `AMP.load` (through
`set_env`) hand them to the functions here.

An env kwarg is one of three kinds:

* A policy setting: in `policy_kwargs` of the task's vector class (the core: substeps, the
  control period; the reference-tracking tasks add action_mode and residual_scale, what an
  action does; Recovery its switch_distance and clamp_distance, when and how the observation
  takes the recovery form). These come from the policy's record. A caller's value that
  contradicts it (or, where the record lacks the kwarg, the env's default, which the policy was
  then trained with) is refused, naming the setting, unless the caller names it in
  `override_settings`: running a policy off its settings is then a choice, not an accident.
* A task setting: anything else the training run passed (reward weights, target ranges, the
  box, the terrain, Imitation's `recovery`). It carries over where the task's evaluation
  protocol says so (`EvalProtocol.eval_kwargs`, `record_kwargs`), and a caller changes it
  freely: how a policy does against farther boxes is a fair question.
* A choice of the run: motions (default: the training ones), num_envs, seeds, rendering,
  backend and device.

The task is compared by env id: a policy is refused on any other task, whatever the sizes.
"""
from __future__ import annotations

import inspect
from typing import Any, Iterable

from .env_ids import ENV_IDS


def training_record(policy) -> tuple[str | None, dict] | None:
    """(env id, env kwargs) of the training a policy records (an `agents` agent, or a bound
    method of one such as `model.predict`), or None for a policy that records none."""
    owner = getattr(policy, "__self__", policy)
    kwargs = getattr(owner, "env_kwargs", None)
    if not hasattr(owner, "env_id") or not isinstance(kwargs, dict):
        return None
    return owner.env_id, kwargs


def task_class(env_id: str | None) -> type | None:
    """The vector class of a registered smpl_envs task id (None for any other id)."""
    entry = ENV_IDS.get(_bare(env_id))
    if entry is None:
        return None
    from gymnasium.envs.registration import load_env_creator

    return load_env_creator(entry[0])


def env_id_of(env) -> str | None:
    """The id of an existing env: its spec's, or for a suite env made without `gym.make` the id
    its class is registered under."""
    spec = getattr(env, "spec", None)
    if spec is not None:
        return spec.id
    cls = type(_task_env(env))
    name = f"{cls.__module__}:{cls.__qualname__}"
    return next((i for i, (entry, _) in ENV_IDS.items() if entry == name), None)


def settings_of(env) -> dict[str, Any]:
    """The policy settings an existing env runs with ({} for an env that is no suite task)."""
    u = _task_env(env)
    return {name: getattr(u, name) for name in getattr(type(u), "policy_kwargs", ())}


def check_task(trained_id: str | None, env_id: str | None) -> None:
    """Refuse to run a policy trained on `trained_id` on another task (None: nothing recorded)."""
    if trained_id is not None and _bare(env_id) != _bare(trained_id):
        raise ValueError(f"the policy was trained on {trained_id}, not {env_id}: its observations and actions "
                         "mean something else there, even where their sizes match")


def with_trained_settings(env_id: str, trained: dict, kwargs: dict, override: Iterable[str] = ()) -> dict:
    """`kwargs` for making `env_id` for a policy trained with env kwargs `trained`: its policy
    settings filled in from `trained`; a value in `kwargs` that contradicts one is a ValueError
    naming it, unless the setting is named in `override`."""
    override = _override(override, getattr(task_class(env_id), "policy_kwargs", ()), env_id)
    for name, (given, value) in contradictions(env_id, trained, kwargs).items():
        if name not in override:
            raise ValueError(f"{name}={given!r} contradicts the policy's {name}={value!r}, which it was "
                             f"trained with; pass override_settings={{{name!r}}} to run it so anyway")
    return {**trained_settings(env_id, trained), **kwargs}


def trained_settings(env_id: str, trained: dict) -> dict[str, Any]:
    """The policy settings of `env_id` that env kwargs `trained` make (defaults where absent)."""
    cls = task_class(env_id)
    return {name: trained.get(name, _default(cls, name)) for name in getattr(cls, "policy_kwargs", ())}


def contradictions(env_id: str, trained: dict, kwargs: dict) -> dict[str, tuple[Any, Any]]:
    """{name: (value in `kwargs`, trained value)} of the policy settings of `env_id` that `kwargs`
    set otherwise than env kwargs `trained` did."""
    return {name: (kwargs[name], value) for name, value in trained_settings(env_id, trained).items()
            if name in kwargs and kwargs[name] != value}


def check_env(env, trained_id: str | None, trained: dict, override: Iterable[str] = ()) -> None:
    """Refuse an existing env for a policy trained on `trained_id` with env kwargs `trained`:
    another task, or a policy setting other than the trained one (unless named in `override`)."""
    if trained_id is None:
        return
    env_id = env_id_of(env)
    if env_id is None:
        raise ValueError(f"the policy was trained on {trained_id}; this env has no registered id to tell its task "
                         "(make it with gym.make or gym.make_vec)")
    check_task(trained_id, env_id)
    override = _override(override, getattr(task_class(env_id), "policy_kwargs", ()), env_id)
    for name, (value, expected) in contradictions(env_id, trained, settings_of(env)).items():
        if name not in override:
            raise ValueError(f"the env runs {name}={value!r}, the policy was trained with {name}={expected!r}; "
                             f"make the env with {name}={expected!r}, or pass override_settings={{{name!r}}} "
                             "to run it so anyway")


def _override(override: Iterable[str], names: tuple[str, ...], env_id: str) -> set[str]:
    override = {override} if isinstance(override, str) else set(override)
    unknown = sorted(override - set(names))
    if unknown:
        raise ValueError(f"override_settings {unknown}: not a policy setting of {env_id} "
                         f"(those are: {', '.join(names) or 'none'})")
    return override


def _default(cls: type, name: str) -> Any:
    """The default of kwarg `name` of `cls` (the first class up the MRO whose constructor names it)."""
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        param = inspect.signature(init).parameters.get(name) if init is not None else None
        if param is not None and param.default is not inspect.Parameter.empty:
            return param.default
    raise TypeError(f"{cls.__name__} lists {name!r} in policy_kwargs but no constructor has it with a default")


def _task_env(env):
    """The suite's vector env under wrappers and under the one-world view (or `env` itself)."""
    u = getattr(env, "unwrapped", env)
    return getattr(u, "vec", u)


def _bare(env_id: str | None) -> str | None:
    # "module:Id" registers the module's ids on use; the id is the part after the colon.
    return env_id.split(":", 1)[-1] if isinstance(env_id, str) else env_id


__all__ = ["training_record", "task_class", "env_id_of", "settings_of", "check_task", "with_trained_settings",
           "trained_settings", "contradictions", "check_env"]
