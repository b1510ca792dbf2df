"""The `smpl-envs` command: train agents from recipes, then evaluate, record and plot their runs.

    smpl-envs train demo_walk_ppo                       # runs/demo_walk_ppo-<time>/
    smpl-envs train recovery_tracker_ppo --init tracker # a new run from another checkpoint's weights
    smpl-envs train imitation_ppo --set env.num_envs=16 --set agent.hyperparams.learning_rate=3e-4
    smpl-envs train imitation_ppo --set agent.policy.kwargs.actor_hidden=[1024,512]
    smpl-envs train imitation_amp --profile paper       # PHC's scale, for a GPU box
    smpl-envs train --resume runs/imitation_ppo-<time> --set train.total_timesteps=8e6
    smpl-envs train imitation_ppo --nproc 4              # data-parallel: 4 processes (torchrun) on this machine
    torchrun --nproc-per-node 4 -m agents train imitation_ppo   # the same, launched by hand (or on several machines)
    smpl-envs eval runs/imitation_ppo-<time> --motions walk run
    smpl-envs record runs/imitation_ppo-<time> --steps 600
    smpl-envs generate pulse --seconds 20                # a PULSE prior's motion, no task
    smpl-envs plot runs/imitation_ppo-<time>
    smpl-envs plot runs/speed_pulse runs/speed_ppo --label PULSE --label scratch --x minutes --out speed.png
    smpl-envs plot runs/reach_stage1,runs/reach_stage2      # stages started from each other with --init
    smpl-envs recipes                                   # the shipped recipes, one line each
    smpl-envs info                                      # versions, GL backend, devices: for bug reports
    smpl-envs pmcp pmcp_corpus                          # PMCP's pipeline, runs/pmcp_corpus/; resumes
    smpl-envs perpetual runs/pmcp_corpus/pmcp.pt        # chained clips, shoves: falls, recoveries

This module parses the command line and hands each command to `agents.run`, which holds what a
run is (its directory, locking, stopping and resuming) and documents it, or to
`agents.checkpoint_commands` (evaluation, videos and generation from a checkpoint).
Mistakes in what the user typed end in one `error: ...` line and exit status 2; a full disk in
one `error:` line naming the file and exit status 74 (training stops with what it had saved and
prints the `--resume` command); anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import os
import json
import sys
from pathlib import Path

from smpl_envs.backend import BACKENDS, MissingExtraError

from . import checkpoint_commands, distributed, run
from .checkpoint import NO_SPACE
from .plot import EmptyLogError, plot_run, plot_runs
from .recipes import RecipeError, available_recipes, parse_override, recipe_description, recipe_dirs
from .run import DISK_FULL, INTERRUPTED, PEER_LOST, TERMINATED, no_space_message, print_error  # noqa: F401


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    try:
        if args.threads is not None:
            _set_threads(args.threads)
        return args.func(args) or 0
    except (RecipeError, EmptyLogError, FileNotFoundError, MissingExtraError) as e:
        print_error(str(e))
        raise SystemExit(2) from None
    except BrokenPipeError:  # `smpl-envs recipes | head`: the reader has gone, nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as e:
        if e.errno not in NO_SPACE:
            raise
        print_error(no_space_message(e))
        raise SystemExit(DISK_FULL) from None


# ---------------------------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    import smpl_envs

    parser = argparse.ArgumentParser(prog="smpl-envs", description=__doc__.split("\n\n")[0])
    parser.add_argument("--version", action="version", version=f"smpl-envs {smpl_envs.__version__}")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--threads", type=int, default=None, metavar="N",
                        help="torch CPU threads (default: torch's choice; 1 is often fastest on a shared or "
                             "small CPU, where torch's thread pool fights the simulation for cores)")
    common.add_argument("--no-progress", action="store_true", help="no progress bars")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("train", parents=[common], help="train an agent from a recipe",
                       description="Train an agent from a recipe (tasks/<name>.yaml or a YAML path).")
    p.add_argument("recipe", nargs="?", help=f"recipe name or YAML file; shipped: {', '.join(available_recipes())}")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a recipe setting by dotted key, e.g. agent.hyperparams.learning_rate=3e-4 "
                        "(repeatable; with --resume: the budget, eval, video and hyperparameters)")
    p.add_argument("--profile", help="apply one of the recipe's profiles (e.g. paper) before the --set overrides")
    p.add_argument("--run-dir", type=Path, help="the run directory (default: RUNS_ROOT/<recipe>-<time>)")
    p.add_argument("--runs-root", type=Path, default=Path("runs"), help="where new run directories go (runs)")
    p.add_argument("--overwrite", action="store_true",
                   help="delete an existing --run-dir first (default: refuse to mix two runs)")
    p.add_argument("--resume", type=Path, metavar="RUN_DIR",
                   help="continue a run from its checkpoints/last.pt up to train.total_timesteps")
    p.add_argument("--init", metavar="CHECKPOINT",
                   help="start the policy from this checkpoint's weights and normalisers (a shipped name, a .pt "
                        "file or a run directory; fresh optimiser and step count): sets agent.init")
    p.add_argument("--device", help="torch device (auto, cpu, cuda ...); overrides train.device")
    p.add_argument("--backend", choices=BACKENDS,
                   help="where the physics runs: warp puts the env on MuJoCo Warp, on --device when one is "
                        "given, else on CUDA where there is one (sets env.kwargs.backend and .device)")
    p.add_argument("--quiet", action="store_true", help="no per-iteration log table on stdout")
    p.add_argument("--update-threads", type=int, default=None, metavar="M",
                   help="torch CPU threads during the network update, when the simulation is idle "
                        "(default: as --threads); e.g. --threads 1 --update-threads 2 on a 2-core CPU")
    p.add_argument("--nproc", type=int, default=None, metavar="N",
                   help="train data-parallel in N processes on this machine (starts torchrun; env.num_envs and "
                        "the batch sizes are per process). Several machines: torchrun ... -m agents train")
    p.add_argument("--grad-sync", choices=distributed.GRAD_SYNCS, default="allreduce",
                   help="how data-parallel processes average gradients: one all-reduce of the flattened gradient "
                        "(allreduce, the default) or DistributedDataParallel (ddp)")
    p.add_argument("--dist-timeout", type=float, default=distributed.DEFAULT_TIMEOUT_S, metavar="SECONDS",
                   help="how long data-parallel processes wait for each other before a dead or stalled one ends "
                        f"the job (default {distributed.DEFAULT_TIMEOUT_S:g}; longer than rank 0's evaluations)")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("eval", parents=[common], help="evaluate a run or checkpoint (PHC protocol)")
    p.add_argument("target", metavar="RUN_OR_CHECKPOINT")
    p.add_argument("--motions", nargs="+", help="clip names or paths (default: the run's eval or training motions)")
    p.add_argument("--num-envs", type=int, help="worlds evaluated at once (default: the run's eval.num_envs, or 8)")
    p.add_argument("--threshold", type=float, help="imitation: failure distance in metres (default: the run's, or 0.5)")
    p.add_argument("--episodes", type=int, help="goal tasks: episodes to run (default: the run's, or 32)")
    p.add_argument("--option", dest="options", action="append", default=[], metavar="KEY=VALUE",
                   help="any other option of the task's evaluation protocol (repeatable)")
    p.add_argument("--checkpoint", choices=("best", "last"), default="best",
                   help="which checkpoint of a run (best falls back to last)")
    p.add_argument("--out", type=Path, help="JSON result path (default for a run: RUN/eval.json); "
                                            "the table goes next to it as .txt")
    p.add_argument("--device", default="auto")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("record", parents=[common], help="record an mp4 of a run's policy")
    p.add_argument("target", metavar="RUN_OR_CHECKPOINT")
    p.add_argument("--steps", type=int, help="video length in env steps (default: the run's video.steps, or 300)")
    p.add_argument("--motions", help="clip name or path (default: the run's first training clip)")
    p.add_argument("--out", type=Path, help="mp4 path (default: RUN/videos/<checkpoint name>.mp4)")
    p.add_argument("--checkpoint", choices=("best", "last"), default="best")
    p.add_argument("--seed", type=int, help="seed of the first reset (default: the run's train.seed)")
    p.add_argument("--device", default="auto")
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("generate", parents=[common], help="record a PULSE prior driving the humanoid (mp4)",
                       description="Sample z from a PULSE prior every step, decode it, record an mp4: motion with no task.")
    p.add_argument("target", metavar="RUN_OR_CHECKPOINT", help="a PULSE run, checkpoint or shipped name (pulse)")
    p.add_argument("--seconds", type=float, default=20.0, help="video length in seconds (20)")
    p.add_argument("--seed", type=int, default=0, help="seeds the first reset and the prior's noise (0)")
    p.add_argument("--noise-scale", type=float, default=1.0,
                   help="multiplies the prior's std (1: samples of the prior; 0: its mean)")
    p.add_argument("--motions", help="the clip whose first frame is the start pose (stand)")
    p.add_argument("--out", type=Path, help="mp4 path (default: RUN/videos/<checkpoint>_generate.mp4)")
    p.add_argument("--checkpoint", choices=("best", "last"), default="best")
    p.add_argument("--device", default="auto")
    p.set_defaults(func=cmd_generate)
    p = sub.add_parser("pmcp", parents=[common], help="run (or resume) PHC's progressive pipeline into one directory",
                       description="PMCP as one command (agents.pmcp): primitives on mined hard clips, the recovery "
                                   "primitive, the composer; the same command resumes where it stopped.")
    p.add_argument("recipe", help="pipeline recipe name (tasks/pipelines/<name>.yaml) or YAML file")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a pipeline setting by dotted key, e.g. max_primitives=2 (repeatable)")
    p.add_argument("--run-dir", type=Path, help="the pipeline's directory (default: RUNS_ROOT/<recipe>)")
    p.add_argument("--runs-root", type=Path, default=Path("runs"))
    p.add_argument("--overwrite", action="store_true", help="delete the pipeline's directory first")
    p.add_argument("--device", help="torch device for every stage (overrides their train.device)")
    p.add_argument("--quiet", action="store_true", help="no per-iteration log table on stdout")
    p.add_argument("--update-threads", type=int, default=None, metavar="M")
    p.set_defaults(func=cmd_pmcp)

    p = sub.add_parser("perpetual", parents=[common], help="perpetual-control test: chained clips, shoves, recovery",
                       description="A long reference of chained clips in Imitation-v0 with recovery on and random "
                                   "shoves; counts losses, falls, recoveries and resets (smpl_envs.perpetual).")
    p.add_argument("target", metavar="RUN_OR_CHECKPOINT")
    p.add_argument("--motions", nargs="+", help="the clips to chain (default: corpus:test)")
    p.add_argument("--minutes", type=float, help="length of the reference (default: 5)")
    p.add_argument("--trials", type=int, help="worlds run at once, each with its own shoves (default: 1)")
    p.add_argument("--no-shoves", action="store_true", help="no shoves")
    p.add_argument("--reference-waits", action="store_true",
                   help="the reference's clock stops while a body is lost and goes on from there once it is back "
                        "(input that can wait, as a generated motion); by default it walks on, as live input does")
    p.add_argument("--option", dest="options", action="append", default=[], metavar="KEY=VALUE",
                   help="any other option of smpl_envs.perpetual (shove_every=[10,20], shove_speed=[0.5,1.5] ...)")
    p.add_argument("--checkpoint", choices=("best", "last"), default="best")
    p.add_argument("--out", type=Path, help="JSON result path (the table goes next to it as .txt)")
    p.add_argument("--video", type=Path, help="an mp4 of world 0")
    p.add_argument("--device", default="auto")
    p.set_defaults(func=cmd_perpetual)

    p = sub.add_parser("plot", parents=[common], help="draw a run's learning curves to a PNG, or compare runs")
    p.add_argument("runs", nargs="+", metavar="RUN",
                   help="a run directory (a run trained in stages, each started from the last with --init: "
                        "the stages' directories joined with commas); two or more: their evaluation and "
                        "episode curves on shared panels")
    p.add_argument("--out", type=Path, help="PNG path (default for one run: RUN/curves.png; a comparison needs it)")
    p.add_argument("--label", action="append", help="a comparison's legend name of each run, in order")
    p.add_argument("--metric", action="append", help="a comparison's column to draw (e.g. success_rate, "
                   "no_fall; repeat it; default: the evaluation's headline columns and the episode statistics)")
    p.add_argument("--x", choices=("timesteps", "minutes"), default="timesteps",
                   help="a comparison's x axis (minutes: of training, for agents that pay differently per sample)")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("recipes", help="list the recipes train finds by name, with what each trains")
    p.set_defaults(func=cmd_recipes, threads=None)

    p = sub.add_parser("info", help="print versions, the GL backend and the devices (for bug reports)")
    p.set_defaults(func=cmd_info, threads=None)
    return parser


# ---------------------------------------------------------------------------------------- commands
def cmd_train(args) -> int:
    if args.nproc is not None and args.nproc != 1:
        if args.nproc < 1:
            raise RecipeError(f"--nproc must be a positive number of processes, got {args.nproc}")
        if distributed.launched():
            raise RecipeError("--nproc starts torchrun, and this process already runs under it "
                              f"(WORLD_SIZE={os.environ.get('WORLD_SIZE')}); leave --nproc out")
        command = distributed.torchrun_command(args.nproc, without_nproc(args.argv))
        os.execv(command[0], command)  # torchrun replaces this process: signals reach it directly
    if args.backend is not None:
        device = None if args.backend == "cpu" or args.device in (None, "auto") else args.device
        args.overrides = [*args.overrides, f"env.kwargs.backend={args.backend}",
                          f"env.kwargs.device={json.dumps(device)}"]
    if args.init is not None:
        if args.resume is not None:
            raise RecipeError("--init starts a new run from a checkpoint's weights; a resumed run continues its own")
        args.overrides = [*args.overrides, f"agent.init={json.dumps(args.init)}"]
    return run.train(args.recipe, overrides=args.overrides, profile=args.profile, run_dir=args.run_dir,
                     runs_root=args.runs_root, overwrite=args.overwrite, resume=args.resume, device=args.device,
                     quiet=args.quiet, update_threads=args.update_threads, progress=not args.no_progress,
                     grad_sync=args.grad_sync, dist_timeout=args.dist_timeout)


def without_nproc(argv: list[str]) -> list[str]:
    """The command line without its --nproc option (spelt as argparse accepts it: abbreviated,
    with its value apart or after "="): what each process torchrun starts is given."""
    out, skip = [], False
    for token in argv:
        if skip:
            skip = False
            continue
        name, eq, _ = token.partition("=")
        if len(name) > 3 and "--nproc".startswith(name):
            skip = not eq
            continue
        out.append(token)
    return out


def cmd_eval(args) -> int:
    # --threshold and --episodes are shorthands for the options of the imitation and goal-task
    # protocols, --option for any; they go over the run's own.
    options = dict(parse_override(o) for o in args.options)
    options.update({k: v for k, v in (("threshold", args.threshold), ("episodes", args.episodes)) if v is not None})
    motions = args.motions[0] if args.motions and len(args.motions) == 1 else args.motions
    return checkpoint_commands.evaluate_checkpoint(
        args.target, which=args.checkpoint, motions=motions, num_envs=args.num_envs, options=options, out=args.out,
        device=args.device, progress=not args.no_progress)


def cmd_record(args) -> int:
    return checkpoint_commands.record_checkpoint(
        args.target, which=args.checkpoint, steps=args.steps, motions=args.motions, out=args.out, seed=args.seed,
        device=args.device, progress=not args.no_progress)


def cmd_generate(args) -> int:
    return checkpoint_commands.generate_checkpoint(
        args.target, which=args.checkpoint, seconds=args.seconds, seed=args.seed, noise_scale=args.noise_scale,
        motions=args.motions, out=args.out, device=args.device, progress=not args.no_progress)


def cmd_pmcp(args) -> int:
    from .pmcp import pmcp

    if distributed.launched():  # its mining and evaluations between stages would run in every process
        raise RecipeError("smpl-envs pmcp runs in one process, not under torchrun; a stage can be trained "
                          "data-parallel with smpl-envs train --nproc N")

    return pmcp(args.recipe, overrides=args.overrides, run_dir=args.run_dir, runs_root=args.runs_root,
                overwrite=args.overwrite, device=args.device, quiet=args.quiet, update_threads=args.update_threads,
                progress=not args.no_progress)


def cmd_perpetual(args) -> int:
    from .pmcp import perpetual_checkpoint

    options = dict(parse_override(o) for o in args.options)
    motions = args.motions[0] if args.motions and len(args.motions) == 1 else args.motions
    options.update({k: v for k, v in (("motions", motions), ("minutes", args.minutes), ("trials", args.trials))
                    if v is not None})
    if args.no_shoves:
        options["shoves"] = False
    if args.reference_waits:
        options["reference_waits"] = True
    return perpetual_checkpoint(args.target, which=args.checkpoint, options=options, out=args.out, video=args.video,
                                device=args.device, progress=not args.no_progress)


def cmd_plot(args) -> int:
    if len(args.runs) == 1:
        if args.label or args.metric or args.x != "timesteps":
            raise RecipeError("--label, --metric and --x are for a comparison of two or more runs")
        print(plot_run(args.runs[0], args.out))
        return 0
    if args.out is None:
        raise RecipeError("a comparison of several runs needs --out PATH.png")
    if args.label is not None and len(args.label) != len(args.runs):
        raise RecipeError(f"{len(args.label)} --label(s) for {len(args.runs)} runs; give one a run, in order")
    try:
        print(plot_runs(args.runs, args.out, labels=args.label, x=args.x, metrics=args.metric))
    except ValueError as e:
        raise RecipeError(str(e)) from None
    return 0


def cmd_recipes(args) -> int:
    for directory in recipe_dirs():
        paths = sorted(directory.glob("*.yaml")) if directory.is_dir() else []
        if paths:
            print(f"{directory}:")
            width = max(len(p.stem) for p in paths)
            for path in paths:
                print(f"  {path.stem:<{width}}  {recipe_description(path)}")
    return 0


def cmd_info(args) -> int:
    from .info import format_info, system_info

    print(format_info(system_info()))
    return 0


def _set_threads(n: int) -> None:
    import torch

    if n < 1:
        raise RecipeError(f"--threads must be >= 1, got {n}")
    torch.set_num_threads(n)


if __name__ == "__main__":
    sys.exit(main())
