"""A run trained on MuJoCo Warp on a GPU evaluates, records and reloads on a machine without that
device: the backend and device say where the physics ran, not how the policy acts, so there the
run falls back to the CPU backend with a warning that names the missing device. Where the device is
asked for directly, the error names it (no crash inside torch)."""
import pytest

import agents
import smpl_envs
import smpl_envs.backend
from agents import PPO


@pytest.fixture
def gpu_trained(tmp_path, monkeypatch):
    """A checkpoint whose record says it trained on backend='warp', device='cuda:7', on a machine
    where that device is missing (whatever this machine has)."""
    monkeypatch.setattr(smpl_envs.backend, "warp_device_problem", lambda device: f"no {device} here")
    model = PPO("SMPL/Imitation-v0", n_envs=1, env_kwargs={"motions": "stand"}, n_steps=8, batch_size=8,
                policy_kwargs={"actor_hidden": [32], "critic_hidden": [32]}, verbose=0, device="cpu")
    cpu_path = model.save(tmp_path / "cpu.pt", optimizer=False)
    model.env_kwargs = {**model.env_kwargs, "backend": "warp", "device": "cuda:7"}
    gpu_path = model.save(tmp_path / "gpu.pt", optimizer=False)
    model.close()
    return cpu_path, gpu_path


def test_a_gpu_run_evaluates_on_the_cpu_backend_with_a_warning(gpu_trained):
    cpu_path, gpu_path = gpu_trained
    with pytest.warns(UserWarning, match=r"device='cuda:7'.*no cuda:7 here.*CPU backend"):
        moved = smpl_envs.evaluate(agents.load(gpu_path), "SMPL/Imitation-v0", num_envs=1, progress=False)
    same = smpl_envs.evaluate(agents.load(cpu_path), "SMPL/Imitation-v0", num_envs=1, progress=False)
    assert moved.summary == same.summary  # the CPU backend's episode, exactly


def test_a_gpu_run_reloads_with_its_env_on_the_cpu_backend(gpu_trained):
    _, gpu_path = gpu_trained
    with pytest.warns(UserWarning, match="cuda:7"):
        agent = agents.load(gpu_path, env="auto", n_envs=1, verbose=0)
    assert agent.env.metadata["backend"] == "cpu"
    agent.close()


def test_a_backend_the_caller_gives_is_used_as_given(monkeypatch):
    import warnings

    monkeypatch.setattr(smpl_envs.backend, "warp_device_problem", lambda device: f"no {device} here")
    recorded = {"backend": "warp", "device": "cuda", "action_mode": "residual"}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert smpl_envs.backend.runnable_here(recorded, {"device": "cuda:1"}) == {**recorded, "device": "cuda:1"}
    with pytest.warns(UserWarning, match="CPU backend"):
        assert smpl_envs.backend.runnable_here(recorded, {"action_mode": "absolute"}) == {"action_mode": "absolute"}


def test_a_run_on_a_device_this_machine_has_keeps_it(monkeypatch):
    monkeypatch.setattr(smpl_envs.backend, "warp_device_problem", lambda device: None)
    kwargs = {"backend": "warp", "device": "cuda", "action_mode": "residual"}
    assert smpl_envs.backend.runnable_here(kwargs) == kwargs
    assert smpl_envs.backend.runnable_here({"action_mode": "residual"}) == {"action_mode": "residual"}


def test_a_missing_warp_device_is_named(monkeypatch):
    problem = smpl_envs.backend.warp_device_problem("cuda")
    try:
        import torch

        has_cuda = torch.cuda.is_available()
    except ImportError:
        has_cuda = False
    if has_cuda:
        pytest.importorskip("mujoco_warp")
        assert problem is None
    else:
        assert problem is not None and ("smpl-envs[gpu]" in problem or "no CUDA device" in problem)
        with pytest.raises((ValueError, ImportError), match="smpl-envs\\[gpu\\]|no CUDA device"):
            smpl_envs.backend.make_backend("warp", "cuda")

