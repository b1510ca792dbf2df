"""Data-parallel training (agents.distributed) on CPU with Gloo and 2 processes: the collectives,
identical agents on every rank, normaliser statistics as one process seeing every rank's data,
a dead or stalled rank ending the job with a clear error, and the command line under torchrun
(a 2-process run resumed in 1 and in 2 processes; SIGTERM leaves a loadable last.pt)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

import agents
from agents import distributed
from agents.cli import main, without_nproc
from agents.normalizer import RunningNorm
from agents.rollout import minibatch_count, minibatches
from dist_jobs import amp_job, base_agents_job, dying_job, ppo_job, primitives_job, run_job

ROOT = Path(__file__).resolve().parents[1]


def assert_same_state(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k


def reference_norm(batches_per_call, shape) -> RunningNorm:
    """The statistics of one process that was handed, at each call, every rank's batch together."""
    norm = RunningNorm(shape)
    for parts in batches_per_call:
        norm.update(torch.cat(parts))
    return norm


# ---------------------------------------------------------------------------------------- one process
def test_one_process_is_a_no_op_job():
    dp = distributed.current()
    assert not dp.enabled and dp.main and dp.world_size == 1
    assert dp.seed(7) == 7 and dp.seed(7, stride=16) == 7 and dp.seed(None) is None
    x = torch.randn(3, 2)
    assert dp.gather_rows(x) is x and dp.sum(5) == 5 and dp.mean(2.5) == 2.5 and dp.all_true(False) is False
    n, mean, var = 3, torch.zeros(2), torch.ones(2)
    assert dp.reduce_moments(n, mean, var) == (n, mean, var)
    # The minibatch count is one process's own rule.
    for n in (0, 1, 63, 100, 1000):
        assert dp.minibatch_count(n, 64) == minibatch_count(n, 64) == len(list(minibatches({"x": torch.zeros(n)}, 64)))
    with pytest.raises(ValueError, match="grad_sync"):
        agents.PPO("Pendulum-v1", grad_sync="nccl", verbose=0)


def test_nproc_runs_torchrun_with_the_rest_of_the_command_line(monkeypatch):
    command = distributed.torchrun_command(2, ["train", "demo_walk_ppo", "--quiet"])
    assert command[:3] == [sys.executable, "-m", "torch.distributed.run"]
    assert "--nproc-per-node=2" in command and command[-5:] == ["-m", "agents", "train", "demo_walk_ppo", "--quiet"]
    for argv in (["train", "x", "--nproc", "2", "--quiet"], ["train", "x", "--nproc=2", "--quiet"],
                 ["train", "--npro", "2", "x", "--quiet"]):
        assert without_nproc(argv) == [a for a in ["train", "x", "--quiet"] if a in argv], argv
    assert without_nproc(["train", "x", "--no-progress"]) == ["train", "x", "--no-progress"]
    monkeypatch.setenv("WORLD_SIZE", "2")  # already one of torchrun's processes
    with pytest.raises(SystemExit) as exc:
        main(["train", "demo_walk_ppo", "--nproc", "2"])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:  # PMCP's pipeline is one process's
        main(["pmcp", "pmcp_corpus"])
    assert exc.value.code == 2
    with pytest.raises(ValueError, match="--nproc"):
        distributed.torchrun_command(0, [])


# ---------------------------------------------------------------------------------------- 2 processes
@pytest.fixture(scope="module")
def primitives(tmp_path_factory):
    return run_job(primitives_job, tmp_path_factory.mktemp("primitives"))


@pytest.mark.parametrize("mode", distributed.GRAD_SYNCS)
def test_gradients_are_the_mean_of_the_ranks_gradients(primitives, mode):
    r0, r1 = primitives[0][mode], primitives[1][mode]
    for g0, g1, a, b in zip(r0["synced"], r1["synced"], *r0["alone"]):
        assert torch.equal(g0, g1)  # every rank steps on the very same numbers
        torch.testing.assert_close(g0, (a + b) / 2, rtol=1e-6, atol=1e-7)
        assert not torch.allclose(a, b)  # the ranks' batches differ: the average is not either one


def test_normaliser_statistics_are_those_of_one_process_seeing_both_ranks(primitives):
    ranks = [primitives[r] for r in (0, 1)]
    assert_same_state(ranks[0]["norm"], ranks[1]["norm"])
    assert len(ranks[1]["batches"][1]) == 0  # a rank with an empty batch still takes part
    ref = reference_norm(zip(ranks[0]["batches"], ranks[1]["batches"]), 4)
    for k, v in ref.state_dict().items():
        torch.testing.assert_close(ranks[0]["norm"][k], v, rtol=1e-12, atol=1e-12)


def test_collectives_agree_across_ranks(primitives):
    for r in (0, 1):
        res = primitives[r]
        assert res["world_size"] == 2 and res["rank"] == r
        assert res["counts"] == [2, 0]  # the smaller count (2 of 100, 5 of 300); none if a rank has none
        torch.testing.assert_close(res["rows"], torch.tensor([[0.0, 1.0], [10.0, 11.0], [12.0, 13.0]],
                                                             dtype=torch.float64))
        assert res["all_true"] == [True, False] and res["sum"] == 3 and res["mean"] == 0.5
    assert primitives[0]["seed"] == [7, 7, None] and primitives[1]["seed"] == [8, 11, None]


@pytest.mark.parametrize("grad_sync", distributed.GRAD_SYNCS)
def test_ppo_ranks_hold_identical_agents_after_several_updates(tmp_path, grad_sync):
    ranks = run_job(ppo_job, tmp_path, grad_sync=grad_sync)
    r0, r1 = ranks[0], ranks[1]
    assert not torch.equal(r0["first_obs"], r1["first_obs"])  # each rank steps its own worlds
    # Each rank seeds its own network (seed + rank); learn starts every rank from rank 0's.
    assert not torch.equal(r0["initial"]["actor.0.weight"], r1["initial"]["actor.0.weight"])
    assert_same_state(r0["final"], r1["final"])
    assert not torch.equal(r0["final"]["actor.0.weight"], r0["initial"]["actor.0.weight"])
    assert r0["iteration"] == r1["iteration"] == 5
    assert r0["num_timesteps"] == r1["num_timesteps"] == 5 * 2 * 4 * 50  # every rank's steps counted
    # Every rank's episodes, the same statistics on both (Pendulum: 200 steps an episode).
    assert r0["episodes"] == r1["episodes"] and len(r0["episodes"]) == 2 * 4
    # The statistics are those of one process handed both ranks' observations and returns.
    for key, prefix, shape in (("obs", "obs_norm", 3), ("returns", "value_norm", ())):
        calls = list(zip(r0["seen"][key], r1["seen"][key]))
        assert len(calls) == (6 if key == "obs" else 5)  # the reset, then one per rollout
        ref = reference_norm(calls, shape)
        for k, v in ref.state_dict().items():  # up to float32 rounding of each batch's moments
            torch.testing.assert_close(r0["final"][f"{prefix}.{k}"], v, rtol=2e-6, atol=1e-6)


def test_amp_discriminator_is_identical_across_ranks(tmp_path):
    ranks = run_job(amp_job, tmp_path, wait_s=180)
    assert not torch.equal(ranks[0]["demo"], ranks[1]["demo"])  # each rank samples its own demo windows
    assert_same_state(ranks[0]["policy"], ranks[1]["policy"])
    assert_same_state(ranks[0]["disc"], ranks[1]["disc"])  # its weights and its input statistics
    assert float(ranks[0]["disc"]["norm.count"]) > 1


def test_pulse_and_the_composer_are_identical_across_ranks(tmp_path):
    ranks = run_job(base_agents_job, tmp_path, wait_s=180)
    assert_same_state(ranks[0]["pulse"], ranks[1]["pulse"])
    assert_same_state(ranks[0]["composer"], ranks[1]["composer"])
    # The composer network moved; its frozen primitives did not.
    assert not torch.equal(ranks[0]["composer"]["weight_net.0.weight"], ranks[0]["composer_initial"]["weight_net.0.weight"])
    frozen = [k for k in ranks[0]["composer"] if k.startswith("primitives.")]
    assert frozen and all(torch.equal(ranks[0]["composer"][k], ranks[0]["composer_initial"][k]) for k in frozen)


@pytest.mark.parametrize("how", ["exit", "stall"])
def test_a_rank_that_dies_ends_the_job_with_a_clear_error(tmp_path, how):
    start = time.monotonic()
    result = run_job(dying_job, tmp_path, timeout_s=3, wait_for=(0,), how=how)[0]
    assert result["iteration"] == 2 and result["error"] is not None, result
    assert "rank 0 of 2" in result["error"] and "died or stalled" in result["error"]
    assert "3 s" in result["error"]  # names the timeout it waited
    assert result["seconds"] < 30 and time.monotonic() - start < 90


# ---------------------------------------------------------------------------------------- the command line
TINY = ["--set", "env.num_envs=4", "--set", "agent.hyperparams.n_steps=16", "--set", "agent.hyperparams.batch_size=64",
        "--set", "agent.hyperparams.actor_hidden=[32,32]", "--set", "agent.hyperparams.critic_hidden=[32,32]",
        "--set", "video.steps=0", "--no-progress", "--quiet", "--threads", "1"]


def cli(*args: str, nproc: int | None = None, timeout: float = 240) -> subprocess.CompletedProcess:
    """`python -m agents ARGS`, or under torchrun with `nproc` processes, from the worktree's code."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    command = [sys.executable, "-m", "agents", *args] if nproc is None else distributed.torchrun_command(nproc, args)
    return subprocess.run(command, capture_output=True, text=True, env=env, timeout=timeout)


@pytest.fixture(scope="module")
def two_process_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("dist") / "run"
    done = cli("train", "demo_walk_ppo", "--nproc", "2", "--set", "train.total_timesteps=512",
               "--set", "train.checkpoint_every=256", "--run-dir", str(run), *TINY)
    assert done.returncode == 0, done.stderr[-3000:]
    return run, done.stdout


def test_two_process_run_writes_one_run(two_process_run):
    run, stdout = two_process_run
    assert "data-parallel: 2 processes" in stdout and "env.num_envs=4 worlds" in stdout and "per process" in stdout
    assert stdout.count("run directory:") == 2  # rank 0's lines alone
    assert agents.load(run / "checkpoints" / "last.pt").num_timesteps == 512  # 2 x 4 worlds x 16 steps x 4
    assert sorted(p.name for p in (run / "checkpoints").glob("ckpt_*.pt")) == [
        "ckpt_000000000256.pt", "ckpt_000000000512.pt"]
    rows = (run / "logs" / "progress.csv").read_text().splitlines()
    assert len(rows) == 1 + 4  # a header and one row per iteration: one writer
    assert (run / "eval.json").is_file()


@pytest.mark.parametrize("nproc", [None, 2])
def test_two_process_checkpoint_resumes_in_one_and_in_two_processes(two_process_run, tmp_path, nproc):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(two_process_run[0], run)
    done = cli("train", "--resume", str(run), "--set", "train.total_timesteps=1024", *TINY, nproc=nproc)
    assert done.returncode == 0, done.stderr[-3000:]
    agent = agents.load(run / "checkpoints" / "last.pt")
    assert agent.num_timesteps == 1024
    # 4 more iterations in 2 processes (128 steps each), 8 in one (64 steps each).
    assert agent.iteration == 4 + (4 if nproc == 2 else 8)


def test_sigterm_to_torchrun_leaves_a_loadable_last_checkpoint(tmp_path):
    run = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    command = distributed.torchrun_command(2, ["train", "demo_walk_ppo", "--set", "train.total_timesteps=100000000",
                                               "--run-dir", str(run), *TINY])
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 120
        while not (run / "logs" / "progress.csv").is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert (run / "logs" / "progress.csv").is_file(), "training never started"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert "terminated (SIGTERM)" in err and f"--resume {run}" in err
    agent = agents.load(run / "checkpoints" / "last.pt")
    assert agent.num_timesteps > 0
