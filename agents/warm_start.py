"""Warm starts: a new run's policy begins with another checkpoint's weights (`smpl-envs train
RECIPE --init CHECKPOINT`, `agent.init` in a recipe). PHC never learns a primitive from scratch:
each hard-clip primitive starts from the one before, and the recovery primitive from a trained
imitator.

What is copied, and why:

* Every tensor of the source policy's state dict: the actor, its action std, the critic, and the
  normalisers with their statistics. A warm-started run therefore acts at step 0 exactly as the
  source checkpoint does.
* The observation normaliser's statistics come with their sample count, so the new run's
  observations move them only as much as one more rollout would have moved the source's (after
  millions of samples, hardly at all): the copied actor keeps seeing its inputs scaled as it
  learnt them. Resetting them would rescale every input of the actor on the first rollout of a
  new task (a body on the floor is far outside a tracker's statistics) and undo what was copied.
* The critic and the return normaliser are copied too. For a successor on the same reward (PHC's
  hard-clip primitives) its values are right from the start; for a task with another reward
  (recovery) they are wrong for the new states either way, and a copied critic at least values
  the states the source knew, so the first updates do not push the copied actor around on noise.
  `exclude` leaves parts as the new policy made them, e.g. `exclude: [critic., value_norm]` for
  a fresh critic, or `[log_std]` to explore with the recipe's own action std.
* Not copied: the optimiser's moments, the step count, the episode statistics and the RNG state.
  The run is a new run (its learning-rate schedule starts over).

A policy of another class is mapped only by a policy that says how (an `init_from(source_class,
state, exclude)` method returning the copied and kept names): SimPoE's `KinematicRefinement` takes
the tracker's `ActorCritic`, whose observation is the first part of its own.

Refused, with the parameter named: another policy class (unless mapped as above), a tensor the
new policy lacks or has that the source lacks (an architecture change), a tensor of another shape
(other layer sizes or another observation size), and env settings that give the copied actions
another meaning (`smpl_envs.policy_settings`: action_mode, residual_scale, substeps ...; compared
where both tasks have the setting, so a tracker may start a recovery run).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Iterable

import torch

from .checkpoint import load_checkpoint
from .policies import PolicyClassError, class_name, policy_class


def init_spec(value: Any) -> tuple[str, list[str]] | None:
    """(checkpoint, exclude) from `agent.init`: None, a checkpoint (a shipped name, a .pt file or
    a run directory), or {checkpoint: ..., exclude: [state-dict key prefixes]}."""
    if value is None:
        return None
    if isinstance(value, (str, os.PathLike)):
        return str(value), []
    if isinstance(value, dict) and "checkpoint" in value and set(value) <= {"checkpoint", "exclude"}:
        exclude = value.get("exclude") or []
        if isinstance(exclude, str):
            exclude = [exclude]
        if not isinstance(value["checkpoint"], (str, os.PathLike)) or not all(isinstance(e, str) for e in exclude):
            raise ValueError(f"agent.init: checkpoint must be a path or name and exclude a list of parameter-name "
                             f"prefixes, got {value!r}")
        return str(value["checkpoint"]), list(exclude)
    raise ValueError(f"agent.init must be a checkpoint (a shipped name, a .pt file or a run directory) or "
                     f"{{checkpoint: ..., exclude: [...]}}, got {value!r}")


def init_policy(agent, path: str | os.PathLike, exclude: Iterable[str] = ()) -> dict[str, Any]:
    """Copy the policy weights and normalisers of checkpoint `path` into `agent`'s policy (module
    docstring), except the state-dict entries whose names start with a prefix in `exclude`.
    Returns {"checkpoint", "copied": [names], "kept": [names left as made]}. A ValueError names
    what does not fit."""
    path = Path(path)
    ckpt = load_checkpoint(path, agent.device)
    policy = agent.policy
    try:
        source_class = policy_class(ckpt.get("policy_class", "ActorCritic"))
    except PolicyClassError as e:
        raise ValueError(f"--init {path}: {e}") from None
    adopt = getattr(policy, "init_from", None)
    if source_class is not type(policy) and adopt is None:
        raise ValueError(f"--init {path}: it holds a {class_name(source_class)} policy, this run makes a "
                         f"{class_name(type(policy))}; a warm start copies a policy of the same class")
    _check_settings(path, ckpt.get("env") or {}, agent.env_id, agent.env_kwargs)
    exclude = tuple(exclude)
    if source_class is not type(policy):  # the policy maps another class's weights onto its own
        try:
            copied, kept = adopt(source_class, ckpt["policy"], exclude)
        except ValueError as e:
            raise ValueError(f"--init {path}: {e}") from None
        return {"checkpoint": str(path), "copied": copied, "kept": kept}
    skip = lambda name: any(name.startswith(p) for p in exclude)  # noqa: E731
    source, target = ckpt["policy"], policy.state_dict()
    missing = [k for k in target if k not in source and not skip(k)]
    extra = [k for k in source if k not in target and not skip(k)]
    if missing or extra:
        what = "; ".join(x for x in (f"this run's policy has {_names(missing)}, the checkpoint does not" if missing
                                     else "", f"the checkpoint has {_names(extra)}, this run's policy does not"
                                     if extra else "") if x)
        raise ValueError(f"--init {path}: the networks differ: {what}")
    for name, value in target.items():
        if not skip(name) and tuple(source[name].shape) != tuple(value.shape):
            raise ValueError(f"--init {path}: parameter {name} is {_shape(source[name])} in the checkpoint, "
                             f"{_shape(value)} in this run's policy (other layer sizes or another observation "
                             "size); make the policy as the checkpoint's, or exclude it")
    copied = [k for k in target if not skip(k)]
    merged = {k: (source[k].to(target[k].dtype) if k in copied else target[k]) for k in target}
    with torch.no_grad():
        policy.load_state_dict(merged)
    return {"checkpoint": str(path), "copied": copied, "kept": [k for k in target if skip(k)]}


def _check_settings(path: Path, source_env: dict, env_id: str | None, env_kwargs: dict) -> None:
    """Refuse a policy setting of the new run's env that contradicts the checkpoint's training."""
    from smpl_envs import policy_settings

    src_id = source_env.get("id")
    src_cls, dst_cls = policy_settings.task_class(src_id), policy_settings.task_class(env_id)
    if src_cls is None or dst_cls is None:
        return
    src = policy_settings.trained_settings(src_id, dict(source_env.get("kwargs") or {}))
    dst = policy_settings.trained_settings(env_id, dict(env_kwargs or {}))
    free = getattr(dst_cls, "goal_settings", ())  # which clips the goal shows: a fine-tune may change them
    for name in (n for n in dst if n in src and n not in free):
        if src[name] != dst[name]:
            raise ValueError(f"--init {path}: it was trained with {name}={src[name]!r}, this run's env has "
                             f"{name}={dst[name]!r}; the copied weights would mean other actions (set "
                             f"env.kwargs.{name}={src[name]!r})")


def _names(names: list[str], limit: int = 4) -> str:
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def _shape(t: torch.Tensor) -> str:
    return "(" + ", ".join(str(s) for s in t.shape) + ")"


__all__ = ["init_policy", "init_spec"]
