"""Data-parallel jobs the tests run on CPU with Gloo: `run_job(job, world_size=2)` starts the
processes (spawned, as torchrun would: RANK, WORLD_SIZE, MASTER_ADDR ... in their environment),
each calls `job(rank, out, **kwargs)` after joining the process group, and the results come
back as what each rank saved to `out/<rank>.pt`.

Every job here is a top-level function, so the spawned processes can import it."""
from __future__ import annotations

import multiprocessing
import os
import socket
import time
import traceback
from pathlib import Path

import torch

TINY_POLICY = dict(actor_hidden=(16,), critic_hidden=(16,))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _entry(job, rank: int, world_size: int, port: int, out: str, timeout_s: float, kwargs: dict) -> None:
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world_size),
                      LOCAL_RANK=str(rank), LOCAL_WORLD_SIZE=str(world_size))
    torch.set_num_threads(1)
    from agents import distributed

    try:
        distributed.init(timeout_s)
        result = job(rank, Path(out), **kwargs)
        torch.save(result, Path(out) / f"{rank}.pt")
    except BaseException:
        (Path(out) / f"{rank}.err").write_text(traceback.format_exc())
        raise
    finally:
        distributed.shutdown()


def run_job(job, out: Path, world_size: int = 2, timeout_s: float = 30.0, wait_s: float = 120.0,
            wait_for: tuple[int, ...] | None = None, **kwargs) -> dict[int, object]:
    """{rank: what job(rank, out, **kwargs) returned} of a `world_size`-process job whose
    collectives time out after `timeout_s`. Waits up to `wait_s` for the ranks in `wait_for`
    (default: all), then ends the others; a rank that failed is an AssertionError with its
    traceback."""
    out.mkdir(parents=True, exist_ok=True)
    ctx, port = multiprocessing.get_context("spawn"), free_port()
    procs = [ctx.Process(target=_entry, args=(job, r, world_size, port, str(out), timeout_s, kwargs))
             for r in range(world_size)]
    for p in procs:
        p.start()
    deadline = time.monotonic() + wait_s
    try:
        for r in wait_for if wait_for is not None else range(world_size):
            procs[r].join(max(deadline - time.monotonic(), 0.1))
            assert not procs[r].is_alive(), f"rank {r} still running after {wait_s} s (a hang)"
    finally:
        for p in procs:
            if p.is_alive():
                p.kill()
            p.join()
    results = {}
    for r in wait_for if wait_for is not None else range(world_size):
        err = out / f"{r}.err"
        assert not err.exists(), f"rank {r} failed:\n{err.read_text()}"
        results[r] = torch.load(out / f"{r}.pt", weights_only=False)
    return results


# ---------------------------------------------------------------------------------------- jobs
def primitives_job(rank: int, out: Path) -> dict:
    """The collectives the agents use, each on data that differs between the ranks."""
    from agents import distributed
    from agents.normalizer import RunningNorm

    dp = distributed.current()
    result = {"rank": dp.rank, "world_size": dp.world_size}
    # Gradients: every rank's own batch through the same network; each mode's average, and what
    # each rank's batch gives alone (so the test can average them itself).
    for mode in distributed.GRAD_SYNCS:
        torch.manual_seed(0)
        net = torch.nn.Sequential(torch.nn.Linear(3, 8), torch.nn.Tanh(), torch.nn.Linear(8, 2))
        xs = [torch.randn(5 + 3 * r, 3, generator=torch.Generator().manual_seed(r)) for r in range(dp.world_size)]
        alone = []
        for x in xs:
            net.zero_grad()
            net(x).square().mean().backward()
            alone.append([p.grad.clone() for p in net.parameters()])
        sync = dp.gradient_sync(net, net.parameters(), mode)
        net.zero_grad(set_to_none=True)
        sync.backward(sync.loss(lambda: net(xs[dp.rank]).square().mean()))
        result[mode] = {"synced": [p.grad.clone() for p in net.parameters()], "alone": alone}
    # Normaliser statistics: batches of different sizes per rank (an empty one on rank 1).
    norm = RunningNorm(4)
    norm.reduce_moments = dp.reduce_moments
    batches = []
    for step in range(3):
        n = 0 if (rank == 1 and step == 1) else 7 + 5 * rank + step
        # float64, so the test sees the combination's own rounding (float32 moments round at 1e-7)
        x = torch.randn(n, 4, generator=torch.Generator().manual_seed(100 * rank + step), dtype=torch.float64)
        x = x * (1 + rank) + rank
        batches.append(x)
        norm.update(x)
    result["norm"] = {k: v.clone() for k, v in norm.state_dict().items()}
    result["batches"] = batches
    result["counts"] = [dp.minibatch_count(100 if rank == 0 else 300, 64),
                        dp.minibatch_count(0 if rank == 1 else 300, 64)]
    result["rows"] = dp.gather_rows(torch.arange(2 * (rank + 1), dtype=torch.float64).reshape(-1, 2) + 10 * rank)
    result["all_true"] = [dp.all_true(True), dp.all_true(rank == 0)]
    result["sum"], result["mean"] = dp.sum(rank + 1), dp.mean(float(rank))
    result["seed"] = [dp.seed(7), dp.seed(7, stride=4), dp.seed(None)]
    return result


def _recording(policy) -> dict[str, list]:
    """Keeps every batch handed to the policy's observation and return statistics."""
    seen = {"obs": [], "returns": []}
    obs_update, value_update = policy.update_obs_stats, policy.update_value_stats

    def update_obs_stats(x):
        seen["obs"].append(x.detach().clone())
        obs_update(x)

    def update_value_stats(x):
        seen["returns"].append(x.detach().clone())
        value_update(x)

    policy.update_obs_stats, policy.update_value_stats = update_obs_stats, update_value_stats
    return seen


def ppo_job(rank: int, out: Path, grad_sync: str = "allreduce", iterations: int = 5) -> dict:
    """PPO on Pendulum (4 worlds a rank, 50-step rollouts): the policy after several updates."""
    from agents import PPO

    model = PPO("Pendulum-v1", n_envs=4, n_steps=50, batch_size=64, n_epochs=2, seed=5, verbose=0,
                policy_kwargs=TINY_POLICY, grad_sync=grad_sync)
    initial = {k: v.clone() for k, v in model.policy.state_dict().items()}
    seen = _recording(model.policy)
    first_obs = []
    model.learn(iterations * 4 * 50 * model.data_parallel.world_size, progress_bar=False,
                callback=lambda agent: first_obs.append(agent.rollout_buffer.obs[0].clone()) or True)
    return {"initial": initial, "final": {k: v.clone() for k, v in model.policy.state_dict().items()},
            "seen": seen, "first_obs": first_obs[0], "episodes": list(model.episodes),
            "num_timesteps": model.num_timesteps, "iteration": model.iteration}


def amp_job(rank: int, out: Path, iterations: int = 3) -> dict:
    """AMP on the walk clip (2 worlds a rank): policy and discriminator after several updates."""
    from agents import AMP

    model = AMP("SMPL/Imitation-v0", n_envs=2, env_kwargs=dict(motions="walk"), n_steps=16, batch_size=16,
                n_epochs=1, disc_hidden=(16,), replay_size=64, seed=0, verbose=0, policy_kwargs=TINY_POLICY)
    demo = model._sample_demo(4)  # this rank's demo stream
    model.learn(iterations * 2 * 16 * model.data_parallel.world_size, progress_bar=False)
    return {"policy": {k: v.clone() for k, v in model.policy.state_dict().items()},
            "disc": {k: v.clone() for k, v in model.disc.state_dict().items()}, "demo": demo}


def dying_job(rank: int, out: Path, how: str = "stall") -> dict:
    """Rank 1 stops taking part after the second iteration ("exit": its process ends; "stall":
    it sleeps); rank 0 reports what ending the job took."""
    from agents import PPO, distributed

    model = PPO("Pendulum-v1", n_envs=2, n_steps=16, batch_size=32, n_epochs=1, seed=0, verbose=0,
                policy_kwargs=TINY_POLICY)

    def stop_taking_part(agent):
        if rank == 1 and agent.iteration == 2:
            if how == "exit":
                os._exit(3)
            time.sleep(600)
        return True

    start = time.monotonic()
    try:
        model.learn(10_000, callback=stop_taking_part, progress_bar=False)
    except distributed.PeerError as e:
        return {"error": str(e), "seconds": time.monotonic() - start, "iteration": model.iteration}
    return {"error": None, "seconds": time.monotonic() - start, "iteration": model.iteration}


def base_agents_job(rank: int, out: Path) -> dict:
    """The other agents on the shared base: PULSE distilling the shipped clips policy, and PPO
    training a PMCP composer over two frozen primitives (the shipped walk policy and a tiny one)."""
    from agents import PPO, PULSE, load_policy
    from agents.recipes import find_checkpoint

    small = dict(n_steps=16, batch_size=32, n_epochs=1, seed=0, verbose=0, device="cpu")
    pulse = PULSE("SMPL/Imitation-v0", teacher="clips", n_envs=2, env_kwargs={"motions": "walk"},
                  policy_kwargs={"encoder_hidden": [32], "prior_hidden": [32], "decoder_hidden": [32]}, **small)
    pulse.learn(2 * 2 * 16 * 2, progress_bar=False)
    primitives = [load_policy(find_checkpoint("walk")), load_policy(Path(__file__).parent / "data" / "compat" / "ppo_v1.pt")]
    composer = PPO("SMPL/Imitation-v0", n_envs=2, policy="Composer",
                   env_kwargs={"motions": "walk", "action_mode": "residual", "residual_scale": 0.25},
                   policy_kwargs={"primitives": primitives, "actor_hidden": [16], "critic_hidden": [16]}, **small)
    initial = {k: v.clone() for k, v in composer.policy.state_dict().items()}
    composer.learn(2 * 2 * 16 * 2, progress_bar=False)
    return {"pulse": {k: v.clone() for k, v in pulse.policy.state_dict().items()},
            "composer_initial": initial, "composer": {k: v.clone() for k, v in composer.policy.state_dict().items()}}
