"""smpl-envs: physics-based SMPL humanoid control on MuJoCo."""

import os as _os

# MuJoCo picks its OpenGL backend when it is first imported. On a server (no display) choose the
# headless EGL backend unless the user chose one, so rendering just works; import smpl_envs before
# mujoco for this to take effect.
if "MUJOCO_GL" not in _os.environ and not (_os.environ.get("DISPLAY") or _os.environ.get("WAYLAND_DISPLAY")):
    _os.environ["MUJOCO_GL"] = "egl"

__version__ = "0.1.0"


# Task ids -> (single-world class, batched class) in smpl_envs.envs. Registering by string keeps
# `import smpl_envs` light: MuJoCo and the tasks load on the first gym.make.
ENV_IDS = {
    "SMPL/Imitation-v0": ("ImitationEnv", "ImitationVecEnv"),
    "SMPL/KeypointImitation-v0": ("KeypointImitationEnv", "KeypointImitationVecEnv"),
}


def _register() -> None:
    import gymnasium as gym

    for env_id, (single, vector) in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=f"smpl_envs.envs:{single}",
                         vector_entry_point=f"smpl_envs.envs:{vector}")


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
