"""Policies as plug-ins: how checkpoints and recipes name a policy class, and how a policy is
made again from what a checkpoint records.

A checkpoint records its policy as

    policy_class:   a registry name ("ActorCritic") or an importable path ("my_pkg.nets:Composer")
    policy_kwargs:  its constructor's keyword arguments (`Policy.init_kwargs`), plain data; a
                    policy among them (a primitive, a decoder) as a record of its own,
                    {"__policy__": {"class", "kwargs", "obs_dim", "action_low", "action_high", "frozen"}}

beside `spaces` (the env's observation size and action box), so `make_policy` builds the same
module again and the state dict fills it, nested policies' weights included: a checkpoint needs
none of the files its primitives came from. Checkpoints from before policies were plug-ins
(format smpl-envs-agent/1) record no class: they hold the default `ActorCritic`, whose
arguments were PPO hyperparameters then (`FORMER_HYPERPARAMS`).

Loading a checkpoint imports the module its policy class names (the checkpoint itself stays a
weights-only torch file, with no code in it); a class that cannot be imported is a
`PolicyClassError` that says so. Register a class under a short name with `register_policy`.
"""
from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from .checkpoint import load_checkpoint
from .networks import ActorCritic, Policy

POLICIES: dict[str, type[Policy]] = {"ActorCritic": ActorCritic}

# ActorCritic's arguments that were PPO hyperparameters before policies were plug-ins: old
# checkpoints store them with the hyperparameters, and recipes and code may still pass them so.
FORMER_HYPERPARAMS = ("actor_hidden", "critic_hidden", "activation", "log_std_init", "learn_std", "normalize_obs",
                      "obs_clip", "normalize_value")
NESTED = "__policy__"  # the key of a policy's record inside another policy's kwargs


class PolicyClassError(ValueError):
    """A policy class name that names no importable `Policy` subclass."""


def register_policy(cls: type[Policy] | None = None, *, name: str | None = None):
    """Register a policy class under `name` (default: its class name), so recipes and
    checkpoints can call it that. Usable as a decorator, with or without `name=`."""
    def register(klass: type[Policy]) -> type[Policy]:
        if not (isinstance(klass, type) and issubclass(klass, Policy)):
            raise TypeError(f"register_policy takes a Policy subclass, got {klass!r}")
        key = name or klass.__name__
        if POLICIES.get(key, klass) is not klass:
            raise ValueError(f"a policy class {key!r} is registered already ({_path(POLICIES[key])})")
        POLICIES[key] = klass
        return klass

    return register if cls is None else register(cls)


def policy_class(name: str | type[Policy]) -> type[Policy]:
    """The Policy subclass a registry name or an importable path ("module:Class" or
    "module.Class") names; a class is returned as is. PolicyClassError otherwise."""
    if isinstance(name, type):
        if not issubclass(name, Policy):
            raise PolicyClassError(f"{name!r} is not a Policy subclass (agents.networks.Policy)")
        return name
    if not isinstance(name, str) or not name:
        raise PolicyClassError(f"a policy class is a registry name or an import path, got {name!r}")
    if name in POLICIES:
        return POLICIES[name]
    module, sep, attr = name.partition(":") if ":" in name else name.rpartition(".")
    if not sep:
        raise PolicyClassError(f"unknown policy class {name!r}; registered: {', '.join(sorted(POLICIES))}, or give "
                               "an importable path such as 'my_package.policies:MyPolicy'")
    try:
        obj = importlib.import_module(module)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as e:
        raise PolicyClassError(f"policy class {name!r} cannot be imported ({type(e).__name__}: {e}); install or "
                               "import the package that defines it") from None
    if not (isinstance(obj, type) and issubclass(obj, Policy)):
        raise PolicyClassError(f"{name!r} is {obj!r}, not a Policy subclass (agents.networks.Policy)")
    return obj


def class_name(cls: type[Policy]) -> str:
    """What a checkpoint calls `cls`: its registry name, else its import path."""
    for key, klass in POLICIES.items():
        if klass is cls:
            return key
    if "<locals>" in cls.__qualname__:
        raise TypeError(f"policy class {cls.__qualname__} is defined inside a function, so a checkpoint could not "
                        "import it again; define it at module level (or register_policy it)")
    return _path(cls)


def _path(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


# ---------------------------------------------------------------------------------------- records
def policy_record(policy: Policy) -> dict[str, Any]:
    """{"class", "kwargs"}: what a checkpoint records to make `policy` again (module docstring)."""
    return {"class": class_name(type(policy)), "kwargs": _plain(policy.init_kwargs, policy, "")}


def _plain(value: Any, owner: Policy, where: str) -> Any:
    if isinstance(value, Policy):
        # Its weights are saved only as part of the owner's state dict.
        if not any(m is value for m in owner.modules()):
            raise ValueError(f"{type(owner).__name__} argument {where} is a policy that is not one of its submodules, "
                             "so its weights would not be saved; keep it as an attribute (or in an nn.ModuleList)")
        box = value.action_space
        return {NESTED: {"class": class_name(type(value)), "kwargs": _plain(value.init_kwargs, value, ""),
                         "obs_dim": value.obs_dim, "action_low": box.low.tolist(), "action_high": box.high.tolist(),
                         "frozen": value.frozen}}
    if isinstance(value, dict):
        return {str(k): _plain(v, owner, f"{where}[{k!r}]") for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v, owner, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"{type(owner).__name__} argument {where or '?'}={value!r} is neither plain data nor a policy, so a "
                    "checkpoint cannot record it")


def make_policy(cls: str | type[Policy], obs_dim: int, action_space: gym.spaces.Box | int,
                kwargs: dict[str, Any] | None = None) -> Policy:
    """A new `cls(obs_dim, action_space, **kwargs)`, with nested policy records in `kwargs`
    made into (untrained) policies, frozen where they were: a checkpoint's state dict then
    fills in every weight."""
    return policy_class(cls)(obs_dim, action_space, **_restore(dict(kwargs or {})))


def _restore(value: Any) -> Any:
    if isinstance(value, dict):
        if set(value) == {NESTED}:
            r = value[NESTED]
            box = gym.spaces.Box(np.array(r["action_low"], np.float32), np.array(r["action_high"], np.float32))
            policy = make_policy(r["class"], r["obs_dim"], box, r["kwargs"])
            return policy.freeze() if r["frozen"] else policy
        return {k: _restore(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_restore(v) for v in value]
    return value


def split_former_hyperparams(hyperparams: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(hyperparams without the former ActorCritic ones, those ones)."""
    rest = {k: v for k, v in hyperparams.items() if k not in FORMER_HYPERPARAMS}
    return rest, {k: v for k, v in hyperparams.items() if k in FORMER_HYPERPARAMS}


def checkpoint_policy(ckpt: dict[str, Any]) -> Policy:
    """The policy of a loaded checkpoint (`checkpoint.load_checkpoint`), made again without its
    weights (load `ckpt["policy"]` into it). A PolicyClassError names an unimportable class."""
    sp = ckpt["spaces"]
    box = gym.spaces.Box(np.array(sp["action_low"], np.float32), np.array(sp["action_high"], np.float32))
    if "policy_class" in ckpt:
        return make_policy(ckpt["policy_class"], sp["obs_dim"], box, ckpt["policy_kwargs"])
    # Format 1: the default actor-critic, with the sizes the hyperparameters recorded.
    return make_policy(ActorCritic, sp["obs_dim"], box, split_former_hyperparams(ckpt["hyperparams"])[1])


def load_policy(path: str | os.PathLike, device: str = "cpu") -> Policy:
    """The policy of a checkpoint file, weights loaded and frozen: a primitive, a teacher or a
    decoder for another policy or agent."""
    ckpt = load_checkpoint(path, device)
    try:
        policy = checkpoint_policy(ckpt)
    except PolicyClassError as e:
        raise PolicyClassError(f"{path}: {e}") from None
    policy.load_state_dict(ckpt["policy"])
    return policy.to(device).freeze()


__all__ = ["POLICIES", "FORMER_HYPERPARAMS", "PolicyClassError", "register_policy", "policy_class", "class_name",
           "policy_record", "make_policy", "checkpoint_policy", "load_policy", "split_former_hyperparams"]
