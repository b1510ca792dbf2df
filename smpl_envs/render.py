"""Rendering: frames from MuJoCo's offscreen renderer, reference markers, mp4 and PNG strips.

Videos are streamed to disk frame by frame through imageio's ffmpeg writer, so recording a long
rollout never holds the episode in memory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import mujoco
import numpy as np

MARKER_RGBA = np.array([0.9, 0.1, 0.1, 0.8], dtype=np.float32)
MARKER_RADIUS = 0.03


class FrameRenderer:
    """RGB frames of a humanoid model from its tracking camera, optionally with marker spheres
    (reference bodies, targets) drawn into the scene."""

    def __init__(self, model: mujoco.MjModel, width: int = 640, height: int = 480, camera: str = "track"):
        self.renderer = mujoco.Renderer(model, height, width)
        self.camera = camera

    def render(self, data: mujoco.MjData, markers=None) -> np.ndarray:
        """markers: an (K, 3) array of positions (red spheres of MARKER_RADIUS), or a list of
        groups (positions (K, 3), rgba, radius)."""
        self.renderer.update_scene(data, camera=self.camera)
        if markers is not None and not isinstance(markers, list):
            markers = [(markers, MARKER_RGBA, MARKER_RADIUS)]
        scene = self.renderer.scene
        for positions, rgba, radius in markers or []:
            rgba = np.asarray(rgba, np.float32)
            for p in np.asarray(positions, float).reshape(-1, 3):
                if scene.ngeom >= scene.maxgeom:
                    break
                mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE,
                                    np.full(3, radius), p, np.eye(3).ravel(), rgba)
                scene.ngeom += 1
        return self.renderer.render().copy()

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: float = 30.0) -> int:
    """Stream frames to an H.264 mp4; returns the number of frames written."""
    import imageio.v2 as imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = 0
    with imageio.get_writer(path, fps=fps, codec="libx264", quality=7, macro_block_size=8) as writer:
        for frame in frames:
            writer.append_data(frame)
            n += 1
    return n


def write_strip(path: str | Path, frames: list[np.ndarray], columns: int | None = None) -> np.ndarray:
    """Tile frames left to right (and in rows of `columns`) into one PNG; returns the image."""
    import imageio.v3 as iio

    columns = columns or len(frames)
    rows = [np.concatenate(frames[i:i + columns], axis=1) for i in range(0, len(frames), columns)]
    if len(rows) > 1 and rows[-1].shape != rows[0].shape:
        pad = np.zeros_like(rows[0])
        pad[:, : rows[-1].shape[1]] = rows[-1]
        rows[-1] = pad
    image = np.concatenate(rows, axis=0)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, image)
    return image


def record(env, policy, path: str | Path, *, steps: int | None = None, episodes: int | None = 1,
           fps: float | None = None, seed: int | None = None, progress: bool = True,
           override_settings: Iterable[str] = (), **make_kwargs) -> dict:
    """Roll `policy` out in a single env and stream its frames to an mp4 at `path`.

    env: an env id (made with `gym.make(env, render_mode="rgb_array", **make_kwargs)` and closed
        afterwards) or a single env already made with render_mode="rgb_array" (left open).
    policy: a callable obs -> action, or "zero" (all-zero actions: the humanoid collapses) or
        "reference" (`env.unwrapped.reference_action()`: PD tracking of the reference).
        A policy that records its training (an `agents` agent) runs in the env it was trained
        in (`smpl_envs.policy_settings`): only on its task; with its policy settings
        (action_mode, residual_scale, substeps ...); with the rest of its training env kwargs
        as its task's protocol sets a video up (imitation: from a clip's first frame), under
        `make_kwargs`; and on its training motions unless `motions=` says otherwise.
    override_settings: the names of policy settings `make_kwargs` (or the existing env) may set
        to other values than the policy was trained with; any other contradiction of them is a
        ValueError naming the setting.
    Runs `episodes` episodes, or stops after `steps` steps in all, whichever comes first (None
    lifts either bound). A frame is rendered after every reset and every step, so the video has
    steps + episodes frames. `seed` seeds the first reset only; later resets continue its stream.

    Returns {"path", "frames", "steps", "episodes" (started, the last one possibly cut short by
    `steps`), "reward" (total), "returns" (per episode)}.
    """
    import gymnasium as gym
    from .progress import pbar

    if steps is None and episodes is None:
        raise ValueError("record needs a bound: pass steps=, episodes= or both")
    if (steps is not None and steps < 1) or (episodes is not None and episodes < 1):
        raise ValueError(f"steps and episodes must be >= 1 (or None), got steps={steps}, episodes={episodes}")
    from . import policy_settings

    trained = policy_settings.training_record(policy)
    if trained is None and override_settings:
        raise ValueError("override_settings is for a policy that records its training settings (an agent); "
                         "this policy records none")
    path = Path(path)
    if path.is_dir():  # refused now, not once the rollout has rendered
        raise ValueError(f"path {path} is a directory; record writes one mp4 file")
    owned = isinstance(env, str)
    if owned:
        if trained is not None:
            make_kwargs = _trained_make_kwargs(env, *trained, make_kwargs, override_settings)
        env = gym.make(env, render_mode="rgb_array", **make_kwargs)
    elif make_kwargs:
        raise TypeError(f"keyword arguments {sorted(make_kwargs)} are for gym.make and need an env id, not an env")
    elif trained is not None:
        policy_settings.check_env(env, *trained, override_settings)
    try:
        # A vector env renders but steps batches; record drives one episode at a time.
        if isinstance(env, gym.vector.VectorEnv) or not isinstance(env, gym.Env):
            raise ValueError(f"record needs a single env from gym.make, got {type(env).__name__}")
        if env.render_mode != "rgb_array":
            raise ValueError(f"record needs an env made with render_mode='rgb_array', got render_mode={env.render_mode!r}")
        act = _resolve_policy(env, policy)
        stats = {"frames": 0, "steps": 0, "returns": []}

        def frames():
            bar = pbar(total=steps, disable=not progress, unit="step", desc=f"recording {path.name}")
            try:
                # Check the step bound before each reset, so a rollout that ends exactly on it
                # does not add a lone reset frame.
                while (episodes is None or len(stats["returns"]) < episodes) and \
                        (steps is None or stats["steps"] < steps):
                    obs, _ = env.reset(seed=seed if not stats["returns"] else None)
                    stats["returns"].append(0.0)
                    yield env.render()
                    done = False
                    while not done and (steps is None or stats["steps"] < steps):
                        obs, reward, terminated, truncated, _ = env.step(act(obs))
                        done = terminated or truncated
                        stats["returns"][-1] += float(reward)
                        stats["steps"] += 1
                        bar.update()
                        yield env.render()
            finally:
                bar.close()

        stats["frames"] = write_video(path, frames(), fps=fps or env.metadata.get("render_fps", 30))
    finally:
        if owned:
            env.close()
    return {"path": str(path), "frames": stats["frames"], "steps": stats["steps"],
            "episodes": len(stats["returns"]), "reward": sum(stats["returns"]), "returns": stats["returns"]}


def generate(decoder, path: str | Path, *, seconds: float = 20.0, seed: int | None = 0, noise_scale: float = 1.0,
             env_id: str = "SMPL/Speed-v0", motions="stand", fps: float | None = None, progress: bool = True,
             **make_kwargs) -> dict:
    """An mp4 at `path` of the humanoid driven by a PULSE prior with no task: z sampled from the
    prior every step (`latent.PriorSampler`: seeded, `noise_scale` x the prior's std; 0 acts
    its mean), decoded by `decoder` (a PULSE checkpoint path or a `latent.LatentDecoder`).

    `seconds` (x 30 steps) of one `env_id` world, whose goal goes unused and unseen (the prior
    and the decoder read only the self observation; markers hidden), from the first frame of
    `motions`; a fall ends the episode and the next starts. Returns `record`'s summary."""
    import gymnasium as gym

    from .latent import PriorSampler, as_latent_decoder
    from .wrappers import LatentAction

    steps = int(round(seconds * 30))
    if steps < 1:
        raise ValueError(f"seconds must be at least 1/30, got {seconds!r}")
    decoder = as_latent_decoder(decoder)
    kwargs = {"motions": motions, "start": "beginning", "show_markers": False, **make_kwargs}
    env = LatentAction(gym.make(env_id, render_mode="rgb_array", max_episode_steps=steps, **kwargs), decoder)
    try:
        return record(env, PriorSampler(decoder, seed, noise_scale), path, steps=steps, episodes=None, fps=fps,
                      seed=seed, progress=progress)
    finally:
        env.close()


def _trained_make_kwargs(env_id: str, trained_id: str | None, trained: dict, make_kwargs: dict,
                         override: Iterable[str]) -> dict:
    """gym.make kwargs for a video of a policy trained on `trained_id` with env kwargs `trained`."""
    from . import policy_settings
    from .backend import runnable_here
    from .evaluation import protocol_for

    policy_settings.check_task(trained_id, env_id)
    carried = {}
    if policy_settings.task_class(env_id) is not None:  # a suite task: its protocol says what carries over
        carried = protocol_for(env_id).record_kwargs(trained)
        if trained.get("motions") is not None:
            carried["motions"] = trained["motions"]
    return policy_settings.with_trained_settings(
        env_id, trained, runnable_here(carried, make_kwargs, "the policy's training"), override)


def _resolve_policy(env, policy):
    if callable(policy):
        return policy
    if policy == "zero":
        space = env.action_space
        return lambda obs: np.zeros(space.shape, space.dtype)
    if policy == "reference":
        if not hasattr(getattr(env.unwrapped, "vec", env.unwrapped), "reference_action"):
            raise ValueError(f"policy='reference' needs an smpl_envs env; {type(env.unwrapped).__name__} has no reference_action()")
        return lambda obs: env.unwrapped.reference_action()
    raise ValueError(f"policy must be a callable obs -> action, 'zero' or 'reference', got {policy!r}")
