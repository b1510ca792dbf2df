"""smpl-envs: physics-based SMPL humanoid control on MuJoCo."""

import os as _os

# MuJoCo picks its OpenGL backend when it is first imported. On a server (no display) choose the
# headless EGL backend unless the user chose one, so rendering just works; import smpl_envs before
# mujoco for this to take effect.
GL_CHOSEN_HERE = "MUJOCO_GL" not in _os.environ and not (_os.environ.get("DISPLAY") or _os.environ.get("WAYLAND_DISPLAY"))
if GL_CHOSEN_HERE:
    _os.environ["MUJOCO_GL"] = "egl"

__version__ = "0.1.0"  # the package version (pyproject.toml reads it here)

# Registering by string (ENV_IDS) keeps `import smpl_envs` light: MuJoCo and the tasks load on
# the first gym.make.
from .env_ids import ENV_IDS  # noqa: E402 (after MUJOCO_GL is set)


class OneWorld:
    """`gym.make`'s entry point of a task: the batch of one of its vector class (`SingleEnv`), so
    a task is one class, written once, batched."""

    def __init__(self, vector_entry_point: str):
        self.vector_entry_point = vector_entry_point

    @property
    def vec_class(self):
        from gymnasium.envs.registration import load_env_creator

        return load_env_creator(self.vector_entry_point)

    @property
    def metadata(self) -> dict:  # gym.make reads the render modes from the entry point
        from .envs.base import SingleEnv

        return SingleEnv.metadata

    def __call__(self, **kwargs):
        from .envs.base import SingleEnv

        return SingleEnv(self.vec_class, **kwargs)

    def __repr__(self) -> str:
        return f"OneWorld({self.vector_entry_point!r})"


def _register() -> None:
    import gymnasium as gym

    for env_id, (vector, steps) in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=OneWorld(vector), vector_entry_point=vector, max_episode_steps=steps)


_register()


def __getattr__(name):
    # `smpl_envs.record(...)` and `smpl_envs.evaluate(...)` without importing MuJoCo at package import.
    if name == "record":
        from .render import record

        return record
    if name == "evaluate":
        from .evaluation import evaluate

        return evaluate
    raise AttributeError(f"module 'smpl_envs' has no attribute {name!r}")
