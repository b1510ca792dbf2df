
import errno
import os

import numpy as np
import pytest

import smpl_envs  # noqa: F401  (headless GL before mujoco)
from smpl_envs.humanoid import NUM_BODIES
from smpl_envs.motion import RawMotion
from smpl_envs.rotations import quat_from_euler_xyz, yaw_quat

# The device the MuJoCo Warp tests (test_sim_warp, test_env_warp; skipped without the gpu extra)
# run on: Warp's CPU device by default, so they need no GPU; SMPL_ENVS_WARP_DEVICE=cuda runs the
# same tests on one.
WARP_DEVICE = os.environ.get("SMPL_ENVS_WARP_DEVICE", "cpu")
# MuJoCo Warp on CUDA sums contact and constraint forces with atomics, whose order changes from run
# to run: the same inputs give the same states to float32 rounding, not bit for bit (measured on an
# H200: 1e-6 apart after 5 steps). On Warp's CPU device runs repeat exactly.
WARP_REPEAT_ATOL = 0.0 if WARP_DEVICE == "cpu" else 1e-3


def warp_same(a, b) -> bool:
    """Two tensors (or lists of tensors) of repeated Warp runs are the same run: bit for bit on the
    CPU, within WARP_REPEAT_ATOL on CUDA."""
    import torch

    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(warp_same(x, y) for x, y in zip(a, b))
    return torch.equal(a, b) if WARP_REPEAT_ATOL == 0 else torch.allclose(a, b, rtol=0, atol=WARP_REPEAT_ATOL)


@pytest.fixture(scope="module", autouse=True)
def _restore_torch_threads():
    """The CLI's --threads sets torch's process-wide pool; each module leaves it as it found it."""
    import torch

    n = torch.get_num_threads()
    yield
    torch.set_num_threads(n)


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    """Every test gets its own MotionLib cache, so no test sees another's (or the user's)."""
    monkeypatch.setenv("SMPL_ENVS_CACHE", str(tmp_path / "cache"))


class _FillingDisk:
    """A file on a disk with no space left: a write stores part of its bytes, then fails."""

    def __init__(self, f):
        self._f = f

    def write(self, data) -> int:
        self._f.write(bytes(memoryview(data)[: len(data) // 2]))
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()


@pytest.fixture
def full_disk(monkeypatch):
    """`full_disk(after=n)`: the disk fills up after n more files opened with `os.fdopen` (how
    checkpoint saves open their temporary file); every write to a later one fails with ENOSPC.
    Returns a function that frees the space again."""
    real, opened = os.fdopen, []

    def fill(after: int = 0):
        def fdopen(fd, *args, **kwargs):
            f = real(fd, *args, **kwargs)
            opened.append(fd)
            return f if len(opened) <= after else _FillingDisk(f)

        monkeypatch.setattr(os, "fdopen", fdopen)
        return lambda: monkeypatch.setattr(os, "fdopen", real)

    return fill


def sway_motion(fps: float = 120.0, seconds: float = 3.0, name: str = "sway") -> RawMotion:
    """A smooth test motion at any frame rate: walking forward while turning, every hinge moving
    with its own sine, so frame-rate and rotation bugs cannot hide."""
    t = np.arange(int(round(seconds * fps)) + 1) / fps
    phase = np.arange(NUM_BODIES * 3).reshape(NUM_BODIES, 3)
    angles = 0.3 * np.sin(2 * np.pi * 0.7 * t[:, None, None] + phase)
    quat = quat_from_euler_xyz(angles)
    quat[:, 0] = yaw_quat(0.4 * t)  # pelvis: turning at 0.4 rad/s, otherwise upright
    root = np.stack([1.2 * t, 0.1 * np.sin(t), 0.95 + 0.02 * np.sin(4 * t)], -1)
    return RawMotion(name, fps, root, quat)


@pytest.fixture
def sway():
    return sway_motion()


def check_env_quietly(env) -> None:
    """Gymnasium's env checker on `env.unwrapped`, without its warnings about unbounded boxes."""
    import warnings

    from gymnasium.utils.env_checker import check_env

    env = env.unwrapped
    if str(env.metadata.get("device") or "cpu").startswith("cuda") and env.spec is not None:
        # Repeatable to float32 rounding only (WARP_REPEAT_ATOL): Gymnasium's bit-for-bit step
        # check is for deterministic envs; this one's repeatability is checked within the tolerance.
        import dataclasses

        import torch

        env.spec = dataclasses.replace(env.spec, nondeterministic=True)
        action, runs = env.action_space.sample(), []
        for _ in range(2):
            env.reset(seed=123)
            obs, reward = env.step(action)[:2]
            runs.append([torch.as_tensor(obs), torch.as_tensor(reward)])
        assert warp_same(*runs)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*(infinity|too low|too high).*")
        check_env(env)


def seeded_rollouts(env, seeds=(3, 3, 4), steps: int = 20):
    """One rollout of a vector env per seed (reset with it, then `steps` fixed random actions in
    [-0.3, 0.3]): per seed the list [obs0, obs1, rew1, term1, trunc1, ...] and the last info, for
    checking that equal seeds repeat and different seeds differ."""
    n, act = env.num_envs, env.single_action_space.shape[0]
    runs = []
    for seed in seeds:
        out = [env.reset(seed=seed)[0]]
        rng = np.random.default_rng(0)
        for _ in range(steps):
            obs, rew, term, trunc, info = env.step(rng.uniform(-0.3, 0.3, (n, act)))
            out += [obs, rew, term, trunc]
        runs.append((out, info))
    return runs


def step_backends_alike(warp_env, cpu_env, steps: int = 10, scale: float = 0.3, info_keys=(),
                        tol=lambda k: 1e-3 if k < 3 else 1e-2, seed: int = 0) -> int:
    """Step an env on the warp backend and its CPU twin with the same random actions in
    [-scale, scale] and assert they agree at every step: observations and rewards within
    `tol(step)`, the `info_keys` within 10x that, the same terminations and truncations, the same
    clips and clip times where the task reports them. Returns how many CPU episodes terminated."""
    import torch

    rng, n, ended = np.random.default_rng(seed), cpu_env.num_envs, 0
    width = cpu_env.single_action_space.shape[0]  # 69 PD targets, or more (SimPoE's meta-PD and root wrench)
    for k in range(steps):
        a = rng.uniform(-scale, scale, (n, width)).astype(np.float32)
        ow, rw, tw, uw, iw = warp_env.step(torch.as_tensor(a))
        oc, rc, tc, uc, ic = cpu_env.step(a)
        assert isinstance(ow, torch.Tensor) and ow.shape == oc.shape
        t = tol(k)
        assert np.abs(ow.cpu().numpy() - oc).max() < t, k
        assert np.abs(rw.cpu().numpy() - rc).max() < t, k
        assert tw.tolist() == tc.tolist() and uw.tolist() == uc.tolist(), k
        for key in info_keys:
            assert np.abs(iw[key].cpu().numpy() - ic[key]).max() < 10 * t, (k, key)
        if "motion_id" in ic:
            np.testing.assert_array_equal(iw["motion_id"].cpu().numpy(), ic["motion_id"])
            np.testing.assert_allclose(iw["motion_time"].cpu().numpy(), ic["motion_time"], atol=1e-6)
        ended += int(tc.sum())
    return ended
