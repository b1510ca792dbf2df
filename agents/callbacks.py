"""Hooks into `learn`: periodic checkpoints, periodic evaluation, or any function of the agent."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable


class Callback:
    """Override any of the three hooks. `on_iteration` runs after every rollout + update;
    returning False stops training."""

    def on_training_start(self, agent) -> None:
        pass

    def on_iteration(self, agent) -> bool | None:
        return True

    def on_training_end(self, agent) -> None:
        pass


class FunctionCallback(Callback):
    def __init__(self, fn: Callable):
        self.fn = fn

    def on_iteration(self, agent):
        return self.fn(agent)


class CallbackList(Callback):
    def __init__(self, callbacks):
        self.callbacks = [as_callback(c) for c in callbacks]

    def on_training_start(self, agent):
        for c in self.callbacks:
            c.on_training_start(agent)

    def on_iteration(self, agent):
        return all([c.on_iteration(agent) is not False for c in self.callbacks])

    def on_training_end(self, agent):
        for c in self.callbacks:
            c.on_training_end(agent)


def as_callback(cb) -> Callback:
    if cb is None:
        return Callback()
    if isinstance(cb, Callback):
        return cb
    if isinstance(cb, (list, tuple)):
        return CallbackList(cb)
    if callable(cb):
        return FunctionCallback(cb)
    raise TypeError(f"callback must be a Callback, a callable or a list of them, got {type(cb)}")


class _Every(Callback):
    """Fires whenever the agent's step count crosses a multiple of `every` timesteps."""

    def __init__(self, every: int):
        if every <= 0:
            raise ValueError(f"every must be a positive number of timesteps, got {every}")
        self.every = int(every)
        self._next = None

    def on_training_start(self, agent):
        self._next = (agent.num_timesteps // self.every + 1) * self.every

    def on_iteration(self, agent):
        if agent.num_timesteps >= self._next:
            self._next = (agent.num_timesteps // self.every + 1) * self.every
            return self.fire(agent)
        return True

    def fire(self, agent) -> bool | None:
        """Do the periodic work now (also callable outside `learn`, e.g. for a final evaluation)."""
        raise NotImplementedError


class CheckpointCallback(_Every):
    """Saves `<dir>/ckpt_<steps>.pt` every `every` timesteps and `<dir>/last.pt` at every save and
    at the end; keeps the newest `keep` numbered checkpoints."""

    def __init__(self, every: int, directory: str | os.PathLike, keep: int | None = 5):
        super().__init__(every)
        self.dir, self.keep = Path(directory), keep

    def fire(self, agent):
        self.dir.mkdir(parents=True, exist_ok=True)
        agent.save(self.dir / f"ckpt_{agent.num_timesteps:012d}.pt")
        agent.save(self.dir / "last.pt")
        if self.keep:
            for old in sorted(self.dir.glob("ckpt_*.pt"))[:-self.keep]:
                old.unlink()
        return True

    def on_training_end(self, agent):
        self.dir.mkdir(parents=True, exist_ok=True)
        agent.save(self.dir / "last.pt")


class EvalCallback(_Every):
    """Every `every` timesteps runs `evaluate_fn(agent) -> {metric: value}`, logs the metrics under
    eval/ and saves `<directory>/best.pt` when `key` improves (higher is better unless
    `minimize`). `best`: the value to beat, e.g. the best of a run being resumed."""

    def __init__(self, every: int, evaluate_fn: Callable, directory: str | os.PathLike | None = None,
                 key: str | None = None, minimize: bool = False, best: float | None = None):
        super().__init__(every)
        self.evaluate_fn, self.key, self.minimize = evaluate_fn, key, minimize
        self.dir = Path(directory) if directory is not None else None
        self.best = best
        self.history: list[tuple[int, dict]] = []

    def fire(self, agent):
        metrics = self.evaluate_fn(agent)
        self.history.append((agent.num_timesteps, metrics))
        for k, v in metrics.items():
            agent.logger.record(f"eval/{k}", v)
        if self.key is not None and self.dir is not None and self.key in metrics:
            v = metrics[self.key]
            better = self.best is None or (v < self.best if self.minimize else v > self.best)
            if better:
                self.best = v
                agent.save(self.dir / "best.pt")
        return True
