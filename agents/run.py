"""Runs of the recipes: train one into its run directory, resume it. The `smpl-envs` command
(`agents.cli`) parses its arguments and calls these; what a finished run's checkpoint gives (its
evaluation, a video) is `agents.checkpoint_commands`.

    from agents import run
    run.train("demo_walk_ppo", overrides=["train.total_timesteps=40000"], run_dir=Path("runs/demo"))
    run.train(resume=Path("runs/demo"), overrides=["train.total_timesteps=80000"])
    agent = run.new_agent(load_recipe("imitation_ppo"))   # the agent a recipe describes

A run directory holds config.yaml (the resolved recipe), checkpoints/ (ckpt_<steps>.pt, last.pt,
best.pt), logs/ (progress.csv, tb/ for TensorBoard), videos/, and after training eval.json,
eval.txt and curves.png. Mistakes in what the user asked for are `RecipeError`s (the command
line prints them as one `error: ...` line, exit status 2); a full disk stops training with what
it had saved and one error line (status DISK_FULL); anything else is a bug and keeps its
traceback. Settings and output paths are checked (the env and the agent built) before the run
directory is created (or `overwrite` deletes the old one), before an evaluation or a video.

The recipe's policy (`agent.policy`: a class and its keyword arguments) may take other runs'
or shipped checkpoints as arguments, written `{checkpoint: NAME_OR_PATH}` (a shipped policy's
name, a .pt file or a run directory's best checkpoint): a new run gets each as its frozen
policy (`policies.load_policy`). A resumed run, an evaluation or a video makes the policy from
its own checkpoint, which holds every weight, so those files are no longer needed then.

One training per run directory: a live run holds RUN/.lock (`recipes.RunLock`: an flock, with its
process id), so a second start into it, an overwrite of it or a resume of it is refused, naming
that process. The kernel drops the lock when the process ends, however it ends.

Stopping and resuming: Ctrl-C or SIGTERM (schedulers, `timeout`) saves checkpoints/last.pt and
prints the resume command (exit status 130 / 143). A resume starts from last.pt or, when that
does not read back intact, from the newest intact ckpt_*.pt (saying so); its logs continue from
that checkpoint's step, replacing whatever a killed run logged after it; temporary files of
interrupted saves are removed.

Data-parallel runs (`agents.distributed`): under torchrun (WORLD_SIZE > 1) `train` joins the
job's process group and every process trains its copy of the agent on its own worlds. Rank 0
is the run: it checks the settings and the run directory, holds the lock, writes config.yaml,
logs, checkpoints, evaluations and videos; the other ranks build the same agent (a resume: from
the checkpoint rank 0 chose, on a filesystem they share) and write nothing. env.num_envs and
the batch sizes are per process; train.total_timesteps, checkpoint_every and eval.every count the
steps of all processes. A signal stops every rank at the end of the iteration it arrived in
(at once while rank 0 evaluates or saves, as nothing collective runs then), and rank 0 saves
last.pt; a process that dies or stalls ends the others with a `PeerError` after the collective
timeout (rank 0 saves last.pt, exit status PEER_LOST).
"""
from __future__ import annotations

import dataclasses
import shutil
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any, Iterable

from smpl_envs.backend import MissingExtraError

from . import distributed
from .callbacks import Callback
from .checkpoint import NO_SPACE, DiskFullError, clean_stale_temp_files, load_checkpoint, newest_readable_checkpoint
from .distributed import DEFAULT_TIMEOUT_S, DataParallel, PeerError
from .plot import EmptyLogError, plot_run, read_progress
from .checkpoint_commands import Evaluator, record_video, write_eval
from .recipes import (LOCK_NAME, RecipeError, RunLock, apply_overrides, check_device, check_run_dir_free,
                      check_writable, find_checkpoint, in_use_message, is_unused_run_dir, live_run_pid, load_recipe,
                      make_run_dir, read_config)
from .warm_start import init_policy, init_spec

# Settings a checkpoint fixes: its weights only fit these.
FIXED_ON_RESUME = ("env.id", "agent.class", "agent.policy") + tuple(
    f"agent.hyperparams.{k}" for k in ("disc_hidden", "disc_activation", "amp_num_frames"))
INTERRUPTED = 130  # the shell's status for a SIGINT
TERMINATED = 143   # and for a SIGTERM
DISK_FULL = 74     # sysexits.h's EX_IOERR: a write failed, here for want of space
PEER_LOST = 69     # sysexits.h's EX_UNAVAILABLE: another process of a data-parallel job died or stalled


def print_error(message: str) -> None:
    """A user's mistake or a full disk, as the one line the command prints for it."""
    print(f"error: {' '.join(message.split())}", file=sys.stderr)


def no_space_message(e: OSError) -> str:
    # A checkpoint's DiskFullError says which file and what is left; other writes name their file.
    if isinstance(e, DiskFullError):
        return str(e)
    return f"no space left on device{f' writing {e.filename}' if e.filename else ''}"


# ---------------------------------------------------------------------------------------- agents
def new_agent(recipe: dict, env=None, **options):
    """A new agent as the resolved `recipe` describes it: its class, policy (checkpoint
    references loaded, frozen; agent.init's weights copied in) and hyperparameters, on `env`
    (default: the recipe's env id with env.num_envs worlds and env.kwargs), seeded with
    train.seed on train.device. `options`:
    any other constructor argument (verbose, log_dir, tensorboard, update_threads, device ...)."""
    from . import AGENTS

    spec, train = recipe["agent"], recipe["train"]
    if env is None:
        env, where = recipe["env"]["id"], {"n_envs": recipe["env"]["num_envs"], "env_kwargs": recipe["env"]["kwargs"]}
    else:
        where = {}
    options = {"seed": train["seed"], "device": train["device"], **options}
    agent = AGENTS[spec["class"]](env, **where, policy=spec["policy"]["class"],
                                  policy_kwargs=with_checkpoints_loaded(spec["policy"]["kwargs"]),
                                  **spec["hyperparams"], **options)
    init = init_spec(spec.get("init"))
    if init is not None:  # agent.init / --init: another checkpoint's weights (agents.warm_start)
        try:
            try:
                source = find_checkpoint(init[0])
            except RecipeError as e:
                raise RecipeError(f"agent.init: {e}") from None
            init_policy(agent, source, init[1])
        except BaseException:
            agent.close()
            raise
    return agent


def with_checkpoints_loaded(value: Any) -> Any:
    """`value` (policy kwargs) with each `{checkpoint: NAME_OR_PATH}` replaced by that
    checkpoint's policy, loaded and frozen."""
    from .policies import load_policy

    if isinstance(value, dict):
        if set(value) == {"checkpoint"}:
            return load_policy(find_checkpoint(value["checkpoint"]))
        return {k: with_checkpoints_loaded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [with_checkpoints_loaded(v) for v in value]
    return value


# ---------------------------------------------------------------------------------------- train
@dataclasses.dataclass
class TrainOptions:
    """What `train` was asked for (its keyword arguments)."""

    recipe: str | Path | None = None
    overrides: list[str] = dataclasses.field(default_factory=list)
    profile: str | None = None
    run_dir: Path | None = None
    runs_root: Path = Path("runs")
    overwrite: bool = False
    resume: Path | None = None
    device: str | None = None
    quiet: bool = False
    update_threads: int | None = None
    progress: bool = True
    grad_sync: str = "allreduce"
    dist_timeout: float = DEFAULT_TIMEOUT_S


def train(recipe: str | Path | None = None, *, overrides: Iterable[str] = (), profile: str | None = None,
          run_dir: Path | None = None, runs_root: Path = Path("runs"), overwrite: bool = False,
          resume: Path | None = None, device: str | None = None, quiet: bool = False,
          update_threads: int | None = None, progress: bool = True, grad_sync: str = "allreduce",
          dist_timeout: float = DEFAULT_TIMEOUT_S) -> int:
    """Train `recipe` (a name or a YAML path; `profile`, then the `KEY=VALUE` overrides) into a
    new run directory (`run_dir`, default RUNS_ROOT/<recipe>-<time>; `overwrite` deletes an old
    one first), or continue the run directory `resume` (its config.yaml, with `overrides`) up to
    train.total_timesteps. `device` overrides train.device; `quiet`: no per-iteration table;
    `update_threads`: torch CPU threads while updating. Under torchrun, one process of a
    data-parallel job (module docstring): `grad_sync` says how it averages gradients
    ("allreduce" or "ddp"), `dist_timeout` how many seconds a collective waits for the others.
    Returns the exit status: 0, INTERRUPTED, TERMINATED, DISK_FULL or PEER_LOST."""
    opts = TrainOptions(recipe, list(overrides), profile, None if run_dir is None else Path(run_dir), Path(runs_root),
                        overwrite, None if resume is None else Path(resume), device, quiet, update_threads, progress,
                        grad_sync, dist_timeout)
    if grad_sync not in distributed.GRAD_SYNCS:
        raise RecipeError(f"--grad-sync must be one of {', '.join(distributed.GRAD_SYNCS)}, got {grad_sync!r}")
    if not (isinstance(dist_timeout, (int, float)) and dist_timeout > 0):
        raise RecipeError(f"--dist-timeout must be a positive number of seconds, got {dist_timeout!r}")
    joined = distributed.launched() and not distributed.initialized()
    dp = distributed.init(opts.dist_timeout) if distributed.launched() else distributed.current()
    try:
        return _train_main(opts, dp) if dp.main else _train_follower(opts, dp)
    finally:
        if joined:
            distributed.shutdown()


def _train_main(opts, dp: DataParallel) -> int:
    # Everything that can fail on a bad setting (the recipe, the env, the agent, the device) is
    # built before the run directory is created or an old one deleted, so a mistake costs nothing.
    prepare = _prepare_resume if opts.resume is not None else _prepare_new
    recipe, run, agent, evaluator, lock = prepare(opts, dp)
    try:
        return _train(opts, recipe, run, agent, evaluator)
    except BaseException:
        # A new run that dies before writing anything would leave a directory that can neither
        # be resumed nor reused; it holds nothing worth keeping.
        if opts.resume is None and is_unused_run_dir(run):
            shutil.rmtree(run, ignore_errors=True)
        raise
    finally:
        agent.close()
        lock.release()


def _new_recipe(opts) -> dict:
    if opts.recipe is None:
        raise RecipeError("train needs a RECIPE (or --resume RUN_DIR)")
    overrides = opts.overrides + ([f"train.device={opts.device}"] if opts.device else [])
    return load_recipe(opts.recipe, overrides, opts.profile)


def _prepare_new(opts, dp: DataParallel) -> tuple[dict, Path, Any, Evaluator, RunLock]:
    recipe = _new_recipe(opts)
    root, name = (opts.run_dir.parent, opts.run_dir.name) if opts.run_dir else (opts.runs_root, None)
    # Refuse before the slow part, not after it.
    if opts.run_dir is None:
        check_writable(opts.runs_root, "--runs-root", directory=True)
    else:
        check_writable(opts.run_dir, "--run-dir", directory=True)
        if not opts.overwrite:
            check_run_dir_free(opts.run_dir)
        else:
            _check_overwrite(opts.run_dir)
            if opts.run_dir.is_dir():  # deleted and made again, in its parent
                check_writable(opts.run_dir.parent, "--run-dir", directory=True)
    _check_train_settings(recipe)
    agent = _constructed(lambda: _new_agent(opts, recipe, dp), recipe)
    lock = None
    try:
        evaluator = _constructed(lambda: Evaluator(recipe, progress=opts.progress), recipe)
        if opts.run_dir is not None:
            # Held before anything is deleted or written: a run started meanwhile is refused.
            lock = RunLock(opts.run_dir).acquire()
            if opts.overwrite:
                _clear_run_dir(opts.run_dir)
        run = make_run_dir(recipe, root, name)
        lock = lock or RunLock(run).acquire()
        _clean_temp_files(run / "checkpoints")
        _attach_logger(agent, run)
    except BaseException:
        agent.close()
        if lock is not None:
            lock.release()
        raise
    return recipe, run, agent, evaluator, lock


def _prepare_resume(opts, dp: DataParallel) -> tuple[dict, Path, Any, Evaluator, RunLock]:
    recipe, run, overrides = _resume_recipe(opts)
    check_writable(run, "--resume", directory=True)
    _check_train_settings(recipe)
    # Before the temporary files are cleaned: a live run's would be its saves in progress.
    lock = RunLock(run).acquire()
    try:
        _clean_temp_files(run / "checkpoints")
        checkpoint = _resume_checkpoint(run)
        dp.broadcast_object(str(checkpoint))  # every rank of a job resumes from this one
        agent = _constructed(lambda: _resume_agent(opts, recipe, checkpoint, overrides, dp), recipe)
    except BaseException:
        lock.release()
        raise
    try:
        evaluator = _constructed(lambda: Evaluator(recipe, progress=opts.progress), recipe)
        # Only now that the overrides proved usable are they recorded in config.yaml.
        make_run_dir(recipe, run.parent, run.name, resume=True)
        _attach_logger(agent, run, resume_step=agent.num_timesteps)
    except BaseException:
        agent.close()
        lock.release()
        raise
    return recipe, run, agent, evaluator, lock


def _check_overwrite(run: Path) -> None:
    pid = live_run_pid(run)
    if pid is not None:
        raise RecipeError(f"--overwrite would delete a live run: {in_use_message(run, pid)}")


def _clear_run_dir(run: Path) -> None:
    """--overwrite: delete everything in `run` but the lock file, which this process holds."""
    for entry in run.iterdir():
        if entry.name == LOCK_NAME:
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def _train(opts, recipe: dict, run: Path, agent, evaluator: Evaluator) -> int:
    try:
        return _train_until_done(opts, recipe, run, agent, evaluator)
    except OSError as e:
        if e.errno not in NO_SPACE:
            raise
        # The run stops here with what it had saved: each save replaces its file only once written.
        print_error(f"{no_space_message(e)}; training stopped at {agent.num_timesteps:,} timesteps; {_what_was_saved(run)}")
        return DISK_FULL


def _what_was_saved(run: Path) -> str:
    path, _ = newest_readable_checkpoint(run / "checkpoints")
    if path is None:
        return "no checkpoint was saved"
    steps = load_checkpoint(path)["num_timesteps"]
    return f"the run keeps {path} ({steps:,} timesteps): free some space, then continue with: " \
           f"smpl-envs train --resume {run}"


def _train_until_done(opts, recipe: dict, run: Path, agent, evaluator: Evaluator) -> int:
    dp = agent.data_parallel
    print(f"run directory: {run}", flush=True)
    if dp.enabled:
        print(describe_data_parallel(agent), flush=True)
    evaluator.history_dir = run / "evals"
    callbacks, eval_cb = _callbacks(recipe, run, evaluator, resuming=opts.resume is not None, agent=agent)
    remaining = recipe["train"]["total_timesteps"] - agent.num_timesteps
    with _SigtermAsInterrupt(deferred=dp.enabled) as signals:
        try:
            if remaining > 0:
                agent.learn(remaining, callback=signals.callbacks(callbacks), progress_bar=opts.progress,
                            reset_num_timesteps=opts.resume is None, log_interval=recipe["train"]["log_interval"])
            else:
                print(f"nothing to train: the run is at {agent.num_timesteps:,} of "
                      f"{recipe['train']['total_timesteps']:,} timesteps")
            if signals.received is not None:  # a data-parallel job stopped together on a signal
                raise Terminated() if signals.received == signal.SIGTERM else KeyboardInterrupt()
            agent.save(run / "checkpoints" / "last.pt")
        except KeyboardInterrupt as stop:
            signals.disarm()  # a SIGTERM now must not cut short the save below
            path = agent.save(run / "checkpoints" / "last.pt")
            terminated = isinstance(stop, Terminated)
            print(f"\n{'terminated (SIGTERM)' if terminated else 'interrupted'} at {agent.num_timesteps:,} "
                  f"timesteps; saved {path}\ncontinue with: {resume_command(run, dp)}", file=sys.stderr)
            return TERMINATED if terminated else INTERRUPTED
        except PeerError as e:
            signals.disarm()
            path = agent.save(run / "checkpoints" / "last.pt")
            if signals.received is not None:  # the others stopped on the same signal and left first
                print(f"\nterminated at {agent.num_timesteps:,} timesteps; saved {path}\ncontinue with: "
                      f"{resume_command(run, dp)}", file=sys.stderr)
                return TERMINATED if signals.received == signal.SIGTERM else INTERRUPTED
            print_error(f"{e}; saved {path} at {agent.num_timesteps:,} timesteps; continue with: "
                        f"{resume_command(run, dp)}")
            return PEER_LOST
    _finish_run(agent, recipe, run, evaluator, eval_cb, progress=opts.progress)
    print(f"run directory: {run}")
    return 0


def resume_command(run: Path, dp: DataParallel) -> str:
    """The command that continues `run` (a data-parallel one in as many processes; any number works)."""
    return f"smpl-envs train --resume {run}" + (f" --nproc {dp.world_size}" if dp.enabled else "")


def describe_data_parallel(agent) -> str:
    """The printed line that says how a data-parallel job divides the recipe's numbers."""
    dp, n_envs = agent.data_parallel, agent.env.num_envs
    batch = getattr(agent.config, "batch_size", None)
    per_step = f", minibatches of agent.hyperparams.batch_size={batch}" if batch else ""
    job_step = f", {dp.world_size * batch} transitions per gradient step" if batch else ""
    return (f"data-parallel: {dp.describe()}, gradients averaged by {agent.grad_sync}; per process: "
            f"env.num_envs={n_envs} worlds{per_step}; the job: {dp.world_size * n_envs} worlds{job_step}; "
            "train.total_timesteps, checkpoint_every and eval.every count the steps of all processes")


def _train_follower(opts, dp: DataParallel) -> int:
    """Rank > 0 of a data-parallel job: the agent rank 0 trains, on this process's own worlds,
    writing nothing (no run directory, logs, checkpoints or evaluations)."""
    if opts.resume is None:
        recipe = _new_recipe(opts)
        _check_train_settings(recipe)
        agent = _constructed(lambda: _new_agent(opts, recipe, dp), recipe)
    else:
        recipe, _, overrides = _resume_recipe(opts)
        checkpoint = Path(dp.broadcast_object(None))  # the one rank 0 resumes from
        agent = _constructed(lambda: _resume_agent(opts, recipe, checkpoint, overrides, dp), recipe)
    try:
        callbacks, _ = _callbacks(recipe, None, None, resuming=opts.resume is not None, agent=agent)
        remaining = recipe["train"]["total_timesteps"] - agent.num_timesteps
        with _SigtermAsInterrupt(deferred=True) as signals:
            try:
                if remaining > 0:
                    agent.learn(remaining, callback=signals.callbacks(callbacks), progress_bar=False,
                                reset_num_timesteps=opts.resume is None, log_interval=recipe["train"]["log_interval"])
            except KeyboardInterrupt as stop:
                return TERMINATED if isinstance(stop, Terminated) else INTERRUPTED
            except PeerError as e:
                if signals.received is None:
                    print_error(str(e))
                    return PEER_LOST
            if signals.received is not None:
                return TERMINATED if signals.received == signal.SIGTERM else INTERRUPTED
        return 0
    finally:
        agent.close()


class Terminated(KeyboardInterrupt):
    """SIGTERM (what schedulers and `timeout` send) raised in the main thread, so training stops
    the way Ctrl-C stops it: last.pt saved, the resume command printed."""


class _SigtermAsInterrupt:
    """While active, the first SIGTERM raises Terminated; later ones are ignored until
    `disarm` ends that too. The previous handler comes back on exit.

    `deferred` (a data-parallel job, where a rank leaving in the middle of a collective would
    leave the others waiting in it): SIGTERM and SIGINT only set `received` (the signal), and
    the callbacks made with `callbacks` stop training on every rank at the end of the
    iteration; while those callbacks run (rank 0's evaluations and saves, nothing collective)
    a signal raises at once, as without `deferred`."""

    def __init__(self, deferred: bool = False):
        self.armed, self.deferred = True, deferred
        self.received: int | None = None
        self.immediate = False
        self.previous: dict[int, Any] = {}

    def _handle(self, signum, frame) -> None:
        if not self.armed:
            return
        self.armed = False  # one signal: a second must not interrupt the save
        if self.deferred and not self.immediate:
            self.received = signum
            return
        raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()

    def disarm(self) -> None:
        self.armed = False

    def callbacks(self, callbacks: list) -> list:
        return [_UntilSignal(self, callbacks)] if self.deferred else callbacks

    def __enter__(self) -> "_SigtermAsInterrupt":
        # Python lets only the main thread set handlers (main() called from a worker thread
        # then keeps the default: SIGTERM ends the process).
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGTERM, signal.SIGINT) if self.deferred else (signal.SIGTERM,):
                self.previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for signum, handler in self.previous.items():
            signal.signal(signum, handler)


class _UntilSignal(Callback):
    """A data-parallel job's callbacks: none once a signal has arrived (training stops, on every
    rank, as `learn` agrees on it); a signal during them interrupts at once."""

    def __init__(self, signals: _SigtermAsInterrupt, callbacks: list):
        from .callbacks import CallbackList

        self.signals, self.inner = signals, CallbackList(callbacks)

    def on_training_start(self, agent) -> None:
        self.inner.on_training_start(agent)

    def on_iteration(self, agent) -> bool:
        if self.signals.received is not None:
            return False
        self.signals.immediate = True
        try:
            return self.inner.on_iteration(agent)
        finally:
            self.signals.immediate = False

    def on_training_end(self, agent) -> None:
        self.inner.on_training_end(agent)


def _check_train_settings(recipe: dict) -> None:
    """Settings that pass the recipe's checks but would only fail later: the device when the
    agent is built, the seed at the env's first reset (which comes after the run directory)."""
    seed = recipe["train"]["seed"]
    if seed is not None and seed < 0:
        raise RecipeError(f"train.seed must be >= 0 (Gymnasium seeds are non-negative), got {seed}")
    check_device(recipe["train"]["device"], "train.device")


def _constructed(build, recipe: dict):
    """build(), with the errors a bad setting raises during construction (an unknown env kwarg,
    a learning rate of "fast" or -1, a hidden size that is not a list, a backend whose extra is
    not installed) turned into RecipeError: they are the user's mistakes, to be reported in one
    line."""
    try:
        return build()
    except RecipeError:
        raise
    except (ValueError, TypeError, RuntimeError, MissingExtraError) as e:
        raise RecipeError(f"cannot build {recipe['agent']['class']} on {recipe['env']['id']} with these settings "
                          f"(check env.kwargs, agent.policy, agent.hyperparams and train.device): {e}") from None


def _new_agent(opts, recipe: dict, dp: DataParallel):
    # No logs yet: the run directory does not exist until the agent has been built (_attach_logger).
    return new_agent(recipe, verbose=0 if opts.quiet else 1, log_dir=None, tensorboard=False,
                     update_threads=opts.update_threads, **_job_options(opts, recipe, dp))


def _job_options(opts, recipe: dict, dp: DataParallel) -> dict:
    """A data-parallel process's own constructor arguments: its device (its GPU of the
    machine's) and how it averages gradients. None in one process."""
    if not dp.enabled:
        return {}
    return {"device": distributed.rank_device(recipe["train"]["device"]), "grad_sync": opts.grad_sync}


def _attach_logger(agent, run: Path, resume_step: int | None = None) -> None:
    """Point the agent's logs at the run directory. `resume_step`: the checkpoint's step count,
    from which a resumed run's logs continue (rows a killed run wrote after it are dropped)."""
    from .logger import Logger

    agent.logger.close()
    # Set directly rather than with set_logger, which has no resume_step.
    agent.logger = Logger(run / "logs", stdout=agent.verbose > 0, tensorboard=True, resume_step=resume_step)
    dropped = agent.logger.dropped_rows
    if dropped:
        print(f"logs: dropped {dropped} row(s) of progress.csv logged after the checkpoint's step "
              f"{resume_step:,} (the run stopped before its next checkpoint); those steps are trained again",
              file=sys.stderr)


def _clean_temp_files(directory: Path) -> None:
    # A run directory has one writer (its RunLock), so any temporary checkpoint file in it is a
    # killed save's.
    removed = clean_stale_temp_files(directory)
    if removed:
        print(f"removed {len(removed)} temporary file(s) left by an interrupted save: "
              f"{', '.join(str(p) for p in removed)}", file=sys.stderr)


def _resume_recipe(opts) -> tuple[dict, Path, list[str]]:
    """The stored recipe of the run to resume, with this command's overrides applied."""
    if opts.recipe is not None or opts.profile is not None or opts.run_dir is not None:
        raise RecipeError("--resume continues a run with its own config.yaml; give no RECIPE, --profile or "
                          "--run-dir (change the budget with --set train.total_timesteps=...)")
    run = opts.resume
    overrides = opts.overrides + ([f"train.device={opts.device}"] if opts.device else [])
    stored = read_config(run)
    recipe = apply_overrides(stored, overrides)
    # The checkpoint fixes the env and the networks. Repeating their values is fine (the same
    # command line with --resume added); changing them is not.
    for key in FIXED_ON_RESUME:
        if _get_dotted(recipe, key) != _get_dotted(apply_overrides(stored), key):
            raise RecipeError(f"--set {key}: a resumed run keeps the env id, agent class and policy (its class and "
                              "arguments, the network sizes) of its checkpoint")
    # So does what the policy's actions and observations mean (smpl_envs.policy_settings).
    from smpl_envs.policy_settings import contradictions

    changed = contradictions(recipe["env"]["id"], apply_overrides(stored)["env"]["kwargs"], recipe["env"]["kwargs"])
    if changed:
        name, (given, trained) = next(iter(changed.items()))
        raise RecipeError(f"--set env.kwargs.{name}={given}: a resumed run keeps the policy settings of its "
                          f"checkpoint ({name}={trained!r}); train a new run to change it")
    return recipe, run, overrides


def _resume_checkpoint(run: Path) -> Path:
    """last.pt, or when it is damaged (a kill mid-write on a filesystem without atomic renames,
    a full disk) the newest numbered checkpoint that reads back intact, saying which and why."""
    directory = run / "checkpoints"
    path, skipped = newest_readable_checkpoint(directory)
    if path is None:
        why = "; ".join(f"{p.name}: {_brief(p, reason)}" for p, reason in skipped) or "no last.pt or ckpt_*.pt"
        raise RecipeError(f"cannot resume {run}: no readable checkpoint in {directory} ({why})")
    if path.name != "last.pt":
        why = "; ".join(f"skipped {p} ({_brief(p, reason)})" for p, reason in skipped) or \
            f"there is no {directory / 'last.pt'}"
        print(f"warning: {why}; resuming from {path} instead", file=sys.stderr)
    return path


def _brief(path: Path, reason: str, limit: int = 200) -> str:
    """A load error shortened for one line: without the path it starts with, up to its first
    sentence (torch appends a paragraph of advice)."""
    text = " ".join(reason.split())
    if text.startswith(str(path)):
        text = text[len(str(path)):].lstrip(" :").removeprefix("is ")
    text = text.split(". ")[0]
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _resume_agent(opts, recipe: dict, checkpoint: Path, overrides: list[str], dp: DataParallel):
    import agents

    # Hyperparameters changed on this command (a lower learning rate ...) replace the saved ones.
    # (Those of the policy, which the checkpoint fixes, the recipe has moved to agent.policy; a
    # repeated value of one is no change: FIXED_ON_RESUME.)
    prefix, hp = "agent.hyperparams.", recipe["agent"]["hyperparams"]
    names = {k[len(prefix):].split(".")[0] for k in (o.partition("=")[0].strip() for o in overrides)
             if k.startswith(prefix)}
    changed = {name: hp[name] for name in names if name in hp}
    return agents.load(checkpoint, env="auto", **{"device": recipe["train"]["device"], **_job_options(opts, recipe, dp)},
                       n_envs=recipe["env"]["num_envs"], env_kwargs=recipe["env"]["kwargs"],
                       verbose=0 if opts.quiet else 1, log_dir=None, tensorboard=False,
                       update_threads=opts.update_threads, **changed)


def _callbacks(recipe: dict, run: Path | None, evaluator: "Evaluator | None", resuming: bool, agent=None):
    """The run's callbacks, and its EvalCallback (or None). Without a run directory (rank > 0 of
    a data-parallel job) only those every rank needs: the curriculum and the time budget."""
    from .callbacks import CheckpointCallback, EvalCallback

    callbacks, eval_cb = [], None
    if recipe["train"]["curriculum"] is not None:
        from .curriculum import StartCurriculum

        curriculum = StartCurriculum(recipe["train"]["curriculum"])
        if agent is not None:  # now, so the env's first reset already draws from the schedule
            curriculum.on_training_start(agent)
        callbacks.append(curriculum)
    if recipe["train"]["checkpoint_every"] > 0 and run is not None:
        callbacks.append(CheckpointCallback(recipe["train"]["checkpoint_every"], run / "checkpoints"))
    if recipe["eval"]["every"] > 0 and run is not None:
        key, minimize = evaluator.protocol.key, evaluator.protocol.minimize
        eval_cb = EvalCallback(recipe["eval"]["every"], evaluator, run / "checkpoints", key=key, minimize=minimize,
                               best=_best_logged(run, key, minimize) if resuming else None)
        callbacks.append(eval_cb)
    if recipe["train"]["max_minutes"] is not None:
        callbacks.append(WallClockBudget(recipe["train"]["max_minutes"]))
    return callbacks, eval_cb


class WallClockBudget:
    """Stops training after `minutes` of this command's wall-clock time (train.max_minutes):
    on a CPU a time budget is often what the user has, not a step count."""

    def __init__(self, minutes: float):
        self.deadline = time.monotonic() + 60.0 * minutes

    def __call__(self, agent) -> bool:
        return time.monotonic() < self.deadline


def _best_logged(run: Path, key: str, minimize: bool = False) -> float | None:
    """The best eval/<key> the run logged before, so a resumed run's best.pt only gets replaced
    by a better policy. None when there is no best.pt to protect."""
    import numpy as np

    csv_path = run / "logs" / "progress.csv"
    if not (run / "checkpoints" / "best.pt").is_file() or not csv_path.is_file():
        return None
    try:
        values = read_progress(csv_path).get(f"eval/{key}")
    except EmptyLogError:
        return None
    if values is None or not np.isfinite(values).any():
        return None
    return float(np.nanmin(values) if minimize else np.nanmax(values))


def _finish_run(agent, recipe: dict, run: Path, evaluator: Evaluator, eval_cb, progress: bool) -> None:
    """The end of training: a final evaluation (logged like the periodic ones), eval.json/.txt,
    curves.png and a video of the deterministic policy."""
    if eval_cb is not None:
        # Go through the callback, so best.pt also considers the final policy; skip when the
        # last periodic evaluation already saw exactly this policy.
        if not eval_cb.history or eval_cb.history[-1][0] != agent.num_timesteps or evaluator.last is None:
            eval_cb.fire(agent)
    else:
        for k, v in evaluator(agent).items():
            agent.logger.record(f"eval/{k}", v)
    if agent.logger.values:  # the final evaluation's row (unless learn() already wrote it)
        agent.logger.dump(agent.num_timesteps)
    write_eval(evaluator.last, run / "eval.json")
    print(plot_run(run, run / "curves.png"))
    steps = recipe["video"]["steps"]
    if steps > 0:
        info = record_video(agent, run / "videos" / "final.mp4", steps=steps, motions=recipe["video"]["motions"],
                            fps=recipe["video"]["fps"], seed=recipe["train"]["seed"], progress=progress)
        print(info["path"])


def _get_dotted(tree: dict, key: str) -> Any:
    for part in key.split("."):
        tree = tree.get(part) if isinstance(tree, dict) else None
    return tree


__all__ = ["train", "TrainOptions", "new_agent", "with_checkpoints_loaded", "WallClockBudget", "FIXED_ON_RESUME",
           "INTERRUPTED", "TERMINATED", "DISK_FULL", "PEER_LOST", "print_error", "no_space_message",
           "describe_data_parallel"]
