"""Settings of an agent, written once: a dataclass whose fields are the hyperparameters.

Each agent declares its settings as a dataclass of `AgentConfig` (`PPOConfig` in ppo.py,
`AMPConfig(PPOConfig)` in amp.py): one line per field with its type and default, and a doc
comment under it. The agent's constructor takes the same names as keyword arguments
(`PPO(env, n_steps=32, ...)`) and builds its config with `from_kwargs`, which names any
argument the dataclass lacks. Checkpoints store `to_dict()`, a plain dict.

Values are converted to their field's type on construction (YAML writes `10` where a float is
meant, a recipe gives lists where a tuple is the default), so two runs with the same settings
store the same dict whatever spelling the settings came in.
"""
from __future__ import annotations

import dataclasses
import functools
import types
import typing
from typing import Any


@dataclasses.dataclass
class AgentConfig:
    """Base of the agents' settings dataclasses: type conversion, keyword checking, plain dicts."""

    def __post_init__(self) -> None:
        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            setattr(self, f.name, _convert(f.name, getattr(self, f.name), hints[f.name]))

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The field names, in declaration order (base class fields first)."""
        return _field_names(cls)

    @classmethod
    def from_kwargs(cls, owner: str, kwargs: dict[str, Any]):
        """A config from keyword arguments; a TypeError names those that are no field."""
        unknown = sorted(set(kwargs) - set(cls.names()))
        if unknown:
            raise TypeError(f"{owner}() got unexpected keyword argument(s) {unknown}; "
                            f"its hyperparameters are {', '.join(cls.names())}")
        return cls(**kwargs)

    def to_dict(self) -> dict[str, Any]:
        """The settings as a plain dict (lists, numbers, strings, None): what checkpoints store."""
        return dataclasses.asdict(self)


@functools.cache
def _field_names(cls: type) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


def _convert(name: str, value: Any, hint: Any) -> Any:
    """`value` as the field type `hint` says: int, float, bool, str, list[...] or `X | None`."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _convert(name, value, inner)
    kind = "a list" if origin is list else getattr(hint, "__name__", str(hint))
    if value is None:
        raise TypeError(f"{name} must be {kind}, got None")
    if origin is list:
        if not isinstance(value, (list, tuple)):
            raise TypeError(f"{name} must be a list such as [512, 256], got {value!r}")
        return [_convert(name, v, args[0]) for v in value]
    if hint in (int, float, bool):
        # Only lossless spellings: 10 for a float, 1e6 for an int, never "fast", 3.7 or [32].
        if isinstance(value, bool) and hint is not bool or not isinstance(value, (int, float, bool)):
            raise TypeError(f"{name} must be {kind}, got {value!r}")
        converted = hint(value)
        if converted != value:
            raise TypeError(f"{name} must be {kind}, got {value!r}")
        return converted
    if hint is str and not isinstance(value, str):
        raise TypeError(f"{name} must be a string, got {value!r}")
    return value
