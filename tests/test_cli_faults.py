"""`smpl-envs train` when things go wrong: nothing lost, nothing silently wrong.

Each test reproduces one fault of the issue of that name: a SIGTERM that ended training without a
checkpoint, logs of a killed run repeated after `--resume`, a truncated last.pt that stopped a
resume with intact checkpoints beside it, bad settings that gave tracebacks after `--overwrite`
had deleted the old run, failed starts that left unusable run directories, a second training
started into (or `--overwrite` of) a live run, and temporary files of interrupted saves that
stayed forever; then outputs that cannot be written, found only after the work, and a disk that
fills up during a save. Budgets are tiny: 2 worlds x 8 steps per iteration.
"""
import csv
import multiprocessing
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import agents
import smpl_envs
from agents import PPO
from agents import checkpoint_commands
from agents import run as run_module
from agents.cli import DISK_FULL, INTERRUPTED, TERMINATED, main
from agents.logger import Logger
from agents.recipes import RUN_SUBDIRS, RunLock, live_run_pid, load_recipe, write_config

STEPS_PER_ITERATION = 16  # env.num_envs x n_steps below
TINY = ["--set", "env.num_envs=2", "--set", "agent.hyperparams.n_steps=8", "--set", "agent.hyperparams.batch_size=16",
        "--set", "agent.hyperparams.actor_hidden=[32,32]", "--set", "agent.hyperparams.critic_hidden=[32,32]",
        "--set", "video.steps=0", "--no-progress", "--quiet", "--threads", "1"]


@pytest.fixture(scope="module")
def base_run(tmp_path_factory):
    """A finished 64-step run with ckpt_32, ckpt_64 and last.pt; tests change copies of it."""
    tmp = tmp_path_factory.mktemp("faults")
    run = tmp / "run"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SMPL_ENVS_CACHE", str(tmp / "cache"))  # as conftest does for each test
        assert main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=64",
                     "--set", "train.checkpoint_every=32", "--run-dir", str(run), *TINY]) == 0
    return run


@pytest.fixture
def run(base_run, tmp_path):
    copy = tmp_path / "run"
    shutil.copytree(base_run, copy)
    return copy


def steps_logged(run: Path) -> list[float]:
    with open(run / "logs" / "progress.csv", newline="") as f:
        return [float(r["time/total_timesteps"]) for r in csv.DictReader(f)]


def assert_increasing(steps: list[float]) -> None:
    assert all(a < b for a, b in zip(steps, steps[1:])), steps


def snapshot(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    return err


class Killed(BaseException):
    """Stands in for a SIGKILL: leaves training without any handler running (no save, no message)."""


def fail_on_update(monkeypatch, n: int, exc):
    """Raise `exc` (an instance or a callable) in PPO's n-th update of this test; returns the
    original update."""
    update, calls = PPO._update, []

    def patched(self, buf):
        calls.append(1)
        if len(calls) == n:
            raise exc() if callable(exc) else exc
        return update(self, buf)

    monkeypatch.setattr(PPO, "_update", patched)
    return update


# ---------------------------------------------------------------------------------------- 1. SIGTERM
@pytest.fixture
def sigterm_guard():
    """A SIGTERM handler of the test's own: should the CLI not replace it, the test fails
    instead of the signal ending pytest."""
    def unhandled(signum, frame):
        raise AssertionError("SIGTERM reached the handler the CLI should have replaced")

    previous = signal.signal(signal.SIGTERM, unhandled)
    yield unhandled
    signal.signal(signal.SIGTERM, previous)


def test_sigterm_saves_a_resumable_checkpoint(tmp_path, monkeypatch, capsys, sigterm_guard):
    def sigterm():
        os.kill(os.getpid(), signal.SIGTERM)  # delivered to this (main) thread at once

    update, calls = PPO._update, []

    def terminated_update(self, buf):
        calls.append(1)
        if len(calls) == 2:
            sigterm()
        return update(self, buf)

    monkeypatch.setattr(PPO, "_update", terminated_update)
    run = tmp_path / "run"
    code = main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=4096", "--run-dir", str(run), *TINY])
    assert code == TERMINATED != INTERRUPTED
    assert signal.getsignal(signal.SIGTERM) is sigterm_guard  # the CLI's handler lives only while training
    assert agents.load(run / "checkpoints" / "last.pt").num_timesteps == 2 * STEPS_PER_ITERATION
    err = capsys.readouterr().err
    assert "SIGTERM" in err and f"smpl-envs train --resume {run}" in err

    monkeypatch.setattr(PPO, "_update", update)
    assert main(["train", "--resume", str(run), "--set", "train.total_timesteps=64", *TINY]) == 0
    assert agents.load(run / "checkpoints" / "last.pt").num_timesteps == 64


def test_sigterm_to_a_training_process(tmp_path, capsys):
    """What `timeout` or a scheduler does: SIGTERM to a real `python -m agents train` mid-run."""
    run = tmp_path / "run"
    env = {**os.environ, "SMPL_ENVS_CACHE": str(tmp_path / "cache")}
    proc = subprocess.Popen([sys.executable, "-m", "agents", "train", "demo_walk_ppo", "--set",
                             "train.total_timesteps=10000000", "--run-dir", str(run), *TINY],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    try:
        csv_path = run / "logs" / "progress.csv"
        deadline = time.monotonic() + 300
        while not (csv_path.is_file() and len(csv_path.read_text().splitlines()) >= 3):
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < deadline, "training logged nothing in 300 s"
            time.sleep(0.2)
        # The live run holds its directory: a second start into it is refused, naming it.
        assert live_run_pid(run) == proc.pid
        with pytest.raises(SystemExit):
            main(["train", "demo_walk_ppo", "--run-dir", str(run), "--overwrite", *TINY])
        assert f"live training (process {proc.pid})" in one_error_line(capsys)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)  # promptly: one iteration plus a save
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == TERMINATED, err
    assert f"smpl-envs train --resume {run}" in err
    steps = agents.load(run / "checkpoints" / "last.pt").num_timesteps
    assert steps >= 2 * STEPS_PER_ITERATION
    # The saved step count may be mid-rollout; resuming trains on to the new budget.
    assert main(["train", "--resume", str(run), "--set", f"train.total_timesteps={steps + 32}", *TINY]) == 0
    assert agents.load(run / "checkpoints" / "last.pt").num_timesteps >= steps + 32


# ---------------------------------------------------------------------------------------- 2. logs after a kill
def test_resume_after_a_kill_logs_each_step_once(tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    # Killed in the 4th update: checkpoints at 32, rows logged up to 48.
    update = fail_on_update(monkeypatch, 4, Killed)
    with pytest.raises(Killed):
        main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=4096", "--set", "train.checkpoint_every=32",
              "--run-dir", str(run), *TINY])
    assert agents.load(run / "checkpoints" / "last.pt").num_timesteps == 32
    assert steps_logged(run) == [16, 32, 48]
    with open(run / "logs" / "progress.csv", "a") as f:
        f.write("64.0,0.5")  # a row the kill cut short, without its newline
    capsys.readouterr()

    monkeypatch.setattr(PPO, "_update", update)
    # TensorBoard reads event files in name order: creation second, then an unpadded counter of
    # this process, so two files made in one second can sort "10" before "9". A real restart
    # is a new process, later; start the resumed run's file in a later second, like one.
    time.sleep(1.05)
    assert main(["train", "--resume", str(run), "--set", "train.total_timesteps=96", *TINY]) == 0
    assert "dropped 2 row(s)" in capsys.readouterr().err
    assert steps_logged(run) == [16, 32, 48, 64, 80, 96]  # one row per step, the final evaluation's merged

    # TensorBoard: the resumed writer purges the killed run's events past the checkpoint.
    event_accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")
    acc = event_accumulator.EventAccumulator(str(run / "logs" / "tb"))
    acc.Reload()
    tb_steps = [e.step for e in acc.Scalars("time/iterations")]
    assert tb_steps == [16, 32, 48, 64, 80, 96]


def test_logger_drops_rows_past_the_resume_step_and_merges_same_step_dumps(tmp_path):
    log = Logger(tmp_path, stdout=False, tensorboard=False)
    for step in (10, 20, 30):
        log.record("a", step)
        log.dump(step)
    log.record("eval/x", 1.0)
    log.dump(30)  # the final evaluation at the last step joins that row
    log.close()
    assert (tmp_path / "progress.csv").read_text().splitlines() == [
        "time/total_timesteps,a,eval/x", "10.0,10.0,", "20.0,20.0,", "30.0,30.0,1.0"]

    log = Logger(tmp_path, stdout=False, tensorboard=False, resume_step=20)
    assert log.dropped_rows == 1
    log.record("a", 25)
    log.dump(30)
    assert (tmp_path / "progress.csv").read_text().splitlines() == [
        "time/total_timesteps,a,eval/x", "10.0,10.0,", "20.0,20.0,", "30.0,25.0,"]
    assert not list(tmp_path.glob(".*.tmp"))


# ---------------------------------------------------------------------------------------- 3. damaged last.pt
def test_resume_falls_back_to_the_newest_readable_checkpoint(run, capsys):
    last = run / "checkpoints" / "last.pt"
    last.write_bytes(last.read_bytes()[: last.stat().st_size // 2])  # truncated mid-write
    assert main(["train", "--resume", str(run), "--set", "train.total_timesteps=96", *TINY]) == 0
    warnings = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("warning: ")]
    assert len(warnings) == 1
    assert str(last) in warnings[0] and "truncated or corrupt" in warnings[0]
    assert str(run / "checkpoints" / "ckpt_000000000064.pt") in warnings[0]
    assert agents.load(last).num_timesteps == 96
    assert_increasing(steps_logged(run))


def test_resume_with_no_readable_checkpoint_is_one_error(run, capsys):
    for ckpt in (run / "checkpoints").glob("*.pt"):
        ckpt.write_bytes(ckpt.read_bytes()[:100])
    with pytest.raises(SystemExit) as exc:
        main(["train", "--resume", str(run), *TINY])
    assert exc.value.code == 2
    err = one_error_line(capsys)
    assert "no readable checkpoint" in err and "last.pt" in err and "ckpt_000000000064.pt" in err


# ---------------------------------------------------------------------------------------- 4. bad settings
BAD_SETTINGS = ["agent.hyperparams.learning_rate=fast", "agent.hyperparams.learning_rate=-1",
                "agent.hyperparams.actor_hidden=512", "env.kwargs.motion=walk", "train.device=cdua",
                "train.seed=-3", "agent.hyperparams.n_steps=[32]"]


@pytest.mark.parametrize("setting", BAD_SETTINGS)
def test_bad_setting_is_one_error_and_overwrite_keeps_the_old_run(setting, run, capsys):
    before = snapshot(run)
    with pytest.raises(SystemExit) as exc:
        main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=64", *TINY, "--set", setting,
              "--run-dir", str(run), "--overwrite"])
    assert exc.value.code == 2
    one_error_line(capsys)
    assert snapshot(run) == before


@pytest.mark.parametrize("argv, device", [(["--backend", "warp"], None), (["--backend", "warp", "--device", "cuda:1"], "cuda:1"),
                                          (["--backend", "cpu", "--device", "cuda"], None)])
def test_backend_flag_sets_where_the_env_runs(monkeypatch, argv, device):
    seen = {}

    def train(recipe, overrides, **kwargs):
        seen["recipe"] = load_recipe(recipe, overrides)

    monkeypatch.setattr(run_module, "train", train)
    main(["train", "demo_walk_ppo", *argv])
    kwargs = seen["recipe"]["env"]["kwargs"]
    assert kwargs["backend"] == argv[1] and kwargs["device"] == device


@pytest.mark.parametrize("asked", [["--set", "env.kwargs.backend=warp"], ["--backend", "warp"]])
def test_warp_backend_without_the_gpu_extra_is_one_error_naming_the_extra(tmp_path, monkeypatch, capsys, asked):
    for module in ("warp", "mujoco_warp"):  # as where the extra is not installed, whether or not it is here
        monkeypatch.setitem(sys.modules, module, None)
    run = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        main(["train", "demo_walk_ppo", *asked, "--run-dir", str(run), *TINY])
    assert exc.value.code == 2
    err = one_error_line(capsys)
    assert "pip install 'smpl-envs[gpu]'" in err and "backend='warp'" in err
    assert not run.exists()


@pytest.mark.parametrize("setting", ["train.device=cdua", "agent.hyperparams.learning_rate=fast"])
def test_bad_setting_on_resume_records_nothing(setting, run, capsys):
    config = (run / "config.yaml").read_text()
    with pytest.raises(SystemExit) as exc:
        main(["train", "--resume", str(run), "--set", setting, *TINY])
    assert exc.value.code == 2
    one_error_line(capsys)
    assert (run / "config.yaml").read_text() == config  # the bad value is not written into the run


@pytest.mark.parametrize("setting", ["env.kwargs.action_mode=residual", "env.kwargs.substeps=2"])
def test_resume_keeps_the_policy_settings_of_its_checkpoint(setting, run, capsys):
    config = (run / "config.yaml").read_text()
    with pytest.raises(SystemExit) as exc:
        main(["train", "--resume", str(run), "--set", setting, *TINY])
    assert exc.value.code == 2
    err = one_error_line(capsys)
    assert f"--set {setting}" in err and "keeps the policy settings" in err
    assert (run / "config.yaml").read_text() == config
    # Stating the value it was trained with (here the default) is no change.
    assert main(["train", "--resume", str(run), "--set", "env.kwargs.action_mode=absolute",
                 "--set", "train.total_timesteps=80", *TINY]) == 0


@pytest.mark.parametrize("argv", [["--num-envs", "-2"], ["--device", "cdua"]])
def test_eval_bad_options_are_one_error(argv, base_run, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["eval", str(base_run), "--no-progress", *argv])
    assert exc.value.code == 2
    assert argv[0] in one_error_line(capsys)


# ---------------------------------------------------------------------------------------- 5. failed starts
def test_failed_start_leaves_no_run_directory(tmp_path, capsys):
    run = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        main(["train", "demo_walk_ppo", "--set", "env.kwargs.motions=wakl", "--run-dir", str(run), *TINY])
    assert exc.value.code == 2 and "wakl" in one_error_line(capsys)
    assert not run.exists()
    assert main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=16", "--run-dir", str(run), *TINY]) == 0


def test_crash_before_anything_was_written_removes_the_new_run_directory(tmp_path, monkeypatch):
    run = tmp_path / "run"
    fail_on_update(monkeypatch, 1, RuntimeError("a bug"))
    with pytest.raises(RuntimeError, match="a bug"):
        main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=64", "--run-dir", str(run), *TINY])
    assert not run.exists()


def test_leftover_of_a_failed_start_is_not_sent_to_resume(tmp_path, capsys):
    """What older versions left: config.yaml and empty subdirectories. --resume cannot help it."""
    run = tmp_path / "run"
    for sub in ("checkpoints", "logs/tb", "videos"):
        (run / sub).mkdir(parents=True)
    (run / "config.yaml").write_text("{}\n")
    argv = ["train", "demo_walk_ppo", "--set", "train.total_timesteps=16", "--run-dir", str(run), *TINY]
    with pytest.raises(SystemExit):
        main(argv)
    err = one_error_line(capsys)
    assert "--overwrite" in err and "--resume" not in err
    assert main(argv + ["--overwrite"]) == 0


# ---------------------------------------------------------------------------------------- 6. a live run
def _hold_run_lock(run, ready) -> None:
    """A live run's hold on its directory, in a child process (until killed)."""
    RunLock(run).acquire()
    ready.set()
    time.sleep(600)


def test_a_live_run_keeps_its_directory_and_a_crash_frees_it(tmp_path, capsys):
    run = tmp_path / "run"
    # What a live run looks like in its first seconds: its config and empty subdirectories.
    for sub in RUN_SUBDIRS:
        (run / sub).mkdir(parents=True)
    write_config(run, load_recipe("demo_walk_ppo"))
    context = multiprocessing.get_context("fork")  # no re-import: the child only holds the lock
    ready = context.Event()
    holder = context.Process(target=_hold_run_lock, args=(run, ready), daemon=True)
    holder.start()
    argv = ["train", "demo_walk_ppo", "--set", "train.total_timesteps=16", "--run-dir", str(run), *TINY]
    try:
        assert ready.wait(60)
        before = snapshot(run)
        for command in (argv, argv + ["--overwrite"], ["train", "--resume", str(run), "--no-progress"]):
            with pytest.raises(SystemExit) as exc:
                main(command)
            assert exc.value.code == 2
            err = one_error_line(capsys)
            assert f"in use by a live training (process {holder.pid})" in err, command
            assert "never trained" not in err
        assert snapshot(run) == before  # nothing deleted, nothing written (the owner's id included)
    finally:
        holder.kill()  # SIGKILL: no handler runs, as in a crash
        holder.join()
    # The kernel dropped the lock with its process: the directory is what it is again.
    assert live_run_pid(run) is None
    with pytest.raises(SystemExit):
        main(argv)
    assert "never trained" in one_error_line(capsys)
    assert main(argv + ["--overwrite"]) == 0
    assert agents.load(run / "checkpoints" / "last.pt").num_timesteps == 16
    assert live_run_pid(run) is None  # released when training ended


# ---------------------------------------------------------------------------------------- 7. temp files
def test_stale_temp_files_are_removed_on_resume(run, capsys):
    ckpts = run / "checkpoints"
    stale = [ckpts / ".last.pt.x1y2z3.tmp", ckpts / ".ckpt_000000000096.pt.a1b2c3.tmp"]
    for path in stale:
        path.write_bytes(b"half a checkpoint")
    assert main(["train", "--resume", str(run), "--set", "train.total_timesteps=80", *TINY]) == 0
    assert not any(p.exists() for p in stale)
    removed = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("removed ")]
    assert len(removed) == 1 and all(p.name in removed[0] for p in stale)


# ---------------------------------------------------------------------------------------- 7. unwritable outputs
@pytest.fixture
def no_work(monkeypatch):
    """Fails the test should the command start its work (build the agent, evaluate, record)
    before refusing its output path."""
    def started(*args, **kwargs):
        raise AssertionError("the work started before the output path was checked")

    monkeypatch.setattr(run_module, "_new_agent", started)
    monkeypatch.setattr(run_module, "record_video", started)  # training's video goes through run's import
    for name in ("evaluate_agent", "record_video"):
        monkeypatch.setattr(checkpoint_commands, name, started)


UNWRITABLE = [
    (["train", "demo_walk_ppo", "--run-dir", "{file}/run"], "--run-dir"),
    (["train", "demo_walk_ppo", "--run-dir", "{file}"], "--run-dir"),
    (["train", "demo_walk_ppo", "--runs-root", "{file}/runs"], "--runs-root"),
    (["eval", "{run}", "--out", "{file}/eval.json"], "--out"),
    (["eval", "{run}", "--out", "{dir}"], "--out"),
    (["record", "{run}", "--out", "{file}/video.mp4"], "--out"),
    (["record", "{run}", "--out", "{dir}"], "--out"),
]


@pytest.mark.parametrize("argv, option", UNWRITABLE, ids=[" ".join(a[:1] + a[-2:]) for a, _ in UNWRITABLE])
def test_unwritable_output_is_one_error_before_the_work(argv, option, base_run, tmp_path, no_work, capsys):
    a_file, a_dir = tmp_path / "a_file", tmp_path / "a_dir"
    a_file.write_text("not a directory")
    a_dir.mkdir()
    before = snapshot(tmp_path)
    argv = [a.format(file=a_file, dir=a_dir, run=base_run) for a in argv]
    with pytest.raises(SystemExit) as exc:
        main(argv + (TINY if argv[0] == "train" else ["--no-progress"]))
    assert exc.value.code == 2
    err = one_error_line(capsys)
    assert option in err and ("is a file" in err or "is a directory" in err), err
    assert snapshot(tmp_path) == before and not any(a_dir.iterdir())


@pytest.mark.parametrize("argv", [["train", "demo_walk_ppo", "--run-dir", "{ro}/run"],
                                  ["eval", "{run}", "--out", "{ro}/eval.json"],
                                  ["record", "{run}", "--out", "{ro}/deeper/video.mp4"]])
def test_read_only_directory_is_one_error_before_the_work(argv, base_run, tmp_path, no_work, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        try:
            (ro / "probe").touch()
        except PermissionError:
            pass
        else:  # a path under a file, which stops root too, is tested above
            pytest.skip("this process writes into read-only directories (root with CAP_DAC_OVERRIDE)")
        with pytest.raises(SystemExit) as exc:
            main([a.format(ro=ro, run=base_run) for a in argv] + (TINY if argv[0] == "train" else ["--no-progress"]))
        assert exc.value.code == 2
        assert f"cannot create files in {ro}" in one_error_line(capsys)
        assert not any(ro.iterdir())
    finally:
        ro.chmod(0o755)


def test_record_refuses_a_directory_before_rendering(tmp_path):
    with pytest.raises(ValueError, match="is a directory"):
        smpl_envs.record("SMPL/Nonexistent-v0", "zero", tmp_path)  # refused before the env is even made


# ---------------------------------------------------------------------------------------- 8. a full disk
def test_full_disk_during_a_checkpoint_stops_the_run_with_what_it_saved(tmp_path, full_disk, capsys):
    run = tmp_path / "run"
    ckpts = run / "checkpoints"
    # Saves at 16 steps (ckpt_16, then last.pt) succeed; the disk is full for ckpt_32.
    free = full_disk(after=2)
    code = main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=64", "--set", "train.checkpoint_every=16",
                 "--run-dir", str(run), *TINY])
    assert code == DISK_FULL
    err = capsys.readouterr().err
    assert err.startswith("error: no space left on device") and err.count("\n") == 1, err  # no traceback
    assert str(ckpts / "ckpt_000000000032.pt") in err and "stopped at 32 timesteps" in err
    assert f"{ckpts / 'last.pt'} (16 timesteps)" in err and f"smpl-envs train --resume {run}" in err
    assert agents.load(ckpts / "last.pt").num_timesteps == 16
    assert sorted(p.name for p in ckpts.iterdir()) == ["ckpt_000000000016.pt", "last.pt"]  # no partial files

    free()  # space freed: the printed command continues the run
    assert main(["train", "--resume", str(run), *TINY]) == 0
    assert agents.load(ckpts / "last.pt").num_timesteps == 64
    assert_increasing(steps_logged(run))


def test_full_disk_on_a_run_s_only_save_is_one_error_without_a_resume_command(tmp_path, full_disk, capsys):
    # The final save of a run without periodic checkpoints: nothing was saved to resume from.
    fresh = tmp_path / "fresh"
    full_disk(after=0)
    assert main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=16", "--run-dir", str(fresh), *TINY]) \
        == DISK_FULL
    err = one_error_line(capsys)
    assert str(fresh / "checkpoints" / "last.pt") in err and "no checkpoint was saved" in err
    assert "--resume" not in err
