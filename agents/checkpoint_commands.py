"""What a trained checkpoint gives: its evaluation with its task's own protocol, a video of it, and
(for a PULSE prior) generated motion. The `smpl-envs eval`, `record` and `generate` commands call
these; training (`agents.run`) evaluates and records through the same functions.

    from agents import checkpoint_commands as cc
    cc.evaluate_checkpoint("runs/demo")                 # RUN/eval.json, the task's own protocol
    cc.record_checkpoint("walk", out=Path("walk.mp4"))
    agent, ckpt, run, config = cc.load_target("tracker", "best", "cpu")   # a run, a .pt or a shipped name

A target is a run directory (its `which` checkpoint: best or last), a .pt file or a shipped
policy's name. Mistakes in what the user asked for are `RecipeError`s; output paths are checked
before the work starts.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from .recipes import RecipeError, check_device, check_writable, find_checkpoint, read_config, run_dir_of


# ---------------------------------------------------------------------------------------- evaluation
class Evaluator:
    """`evaluate_fn` for EvalCallback: the task's own evaluation protocol on the agent's env,
    returning the summary's numbers; keeps the full result of the latest call for eval.json.

    Once `history_dir` is set (by `agents.run`, when the run directory exists), every evaluation's
    full result (per clip or per episode, which the progress CSV's summary columns leave out) is
    also kept as `<timesteps>.json` / `.txt` there: how each clip of a multi-clip run came along,
    after the run's checkpoints have rotated out."""

    def __init__(self, recipe: dict, progress: bool = True):
        from smpl_envs.evaluation import protocol_for

        self.protocol = protocol_for(recipe["env"]["id"])
        self.motions, self.num_envs = recipe["eval"]["motions"], recipe["eval"]["num_envs"]
        self.options, self.progress = recipe["eval"]["options"], progress
        self.history_dir: Path | None = None
        self.last = None

    def __call__(self, agent) -> dict[str, float]:
        self.last = evaluate_agent(agent, self.motions, self.num_envs, self.progress, **self.options)
        if self.history_dir is not None:
            save_result(self.last, self.history_dir / f"{agent.num_timesteps:012d}.json")
        return summary_metrics(self.last.summary)


def evaluate_agent(agent, motions=None, num_envs: int = 8, progress: bool = True, **options):
    """smpl_envs.evaluate of `agent` on the env it trained on, which evaluate sets up from the
    agent's record (its settings, the env kwargs the task's protocol carries over, the training
    motions unless `motions`)."""
    import smpl_envs

    if agent.env_id is None:
        raise RecipeError("the checkpoint records no env id to evaluate on")
    try:
        return smpl_envs.evaluate(agent, env=agent.env_id, motions=motions or None, num_envs=num_envs,
                                  progress=progress, **options)
    except ValueError as e:  # an option or kwarg the task's protocol refuses
        raise RecipeError(str(e)) from None


def summary_metrics(summary: dict) -> dict[str, float]:
    """The summary's numbers without the clip count (a property of the motions, not the policy)."""
    return {k: float(v) for k, v in summary.items()
            if k != "clips" and isinstance(v, (int, float)) and not isinstance(v, bool)}


def save_result(result, json_path: Path) -> str:
    """An evaluation's result as JSON at `json_path` and its table next to it (.txt); returns
    the table."""
    result.save(json_path)  # creates the directory
    table = result.table()
    json_path.with_suffix(".txt").write_text(table + "\n")
    return table


def write_eval(result, json_path: Path) -> None:
    print(save_result(result, json_path))
    print(json_path)


def eval_settings(config: dict | None, motions=None, num_envs: int | None = None,
                  options: dict | None = None) -> tuple[object, int, dict]:
    """(motions, num_envs, protocol options) of an evaluation: the ones asked for, else the run
    config's eval settings (`config`: a run's config.yaml; None for a bare checkpoint). The world
    count matters beyond speed: an episode task's seeded episodes are drawn per world."""
    ev = (config or {}).get("eval", {})
    run_options = dict(ev.get("options") or {})
    if "threshold" in ev:  # run configs from before eval.options
        run_options["threshold"] = ev["threshold"]
    return motions or ev.get("motions"), num_envs or ev.get("num_envs") or 8, {**run_options, **(options or {})}


def evaluate_checkpoint(target: str | Path, *, which: str = "best", motions=None, num_envs: int | None = None,
                        options: dict | None = None, out: Path | None = None, device: str = "auto",
                        progress: bool = True) -> int:
    """Evaluate the checkpoint of `target` (a run directory, whose `which` checkpoint: best or
    last; a .pt file; a shipped policy's name) with its task's protocol, in the env it trained
    in. `motions`, `num_envs` and the protocol's `options` default to the run's eval settings.
    The result goes to `out` (for a run directory: RUN/eval.json), with its table beside it as
    .txt, else to stdout. Returns 0."""
    if num_envs is not None and num_envs < 1:
        raise RecipeError(f"--num-envs must be >= 1, got {num_envs}")
    agent, ckpt, run, config = load_target(target, which, device)
    motions, num_envs, options = eval_settings(config, motions, num_envs, options)
    given_out = out is not None
    out = out or (run / "eval.json" if run is not None and Path(target).is_dir() else None)
    if out is not None:  # the JSON and the table beside it, checked before the evaluation runs
        for path in (out, out.with_suffix(".txt")):
            check_writable(path, _output_option(given_out))
    result = evaluate_agent(agent, motions, num_envs, progress=progress, **options)
    print(f"checkpoint: {ckpt} ({agent.num_timesteps:,} timesteps)")
    if out is None:
        print(result.table())
    else:
        write_eval(result, out)
    return 0


# ---------------------------------------------------------------------------------------- video
def record_video(agent, path: Path, steps: int, motions=None, fps: float | None = None, seed: int | None = None,
                 progress: bool = True) -> dict:
    """An mp4 of the deterministic policy in one world of its training env, which record sets up
    from the agent's record as its task's protocol says (imitation: from the start of a clip)."""
    import smpl_envs

    if agent.env_id is None:
        raise RecipeError("the checkpoint records no env id to record in")
    kwargs = {"motions": motions} if motions else {}
    return smpl_envs.record(agent.env_id, agent, path, steps=steps, episodes=None, fps=fps, seed=seed,
                            progress=progress, **kwargs)


def record_checkpoint(target: str | Path, *, which: str = "best", steps: int | None = None, motions=None,
                      out: Path | None = None, seed: int | None = None, device: str = "auto",
                      progress: bool = True) -> int:
    """An mp4 of the checkpoint of `target` (as `evaluate_checkpoint` finds it) in one world of
    its training env. `steps`, `motions` and `seed` default to the run's video settings and seed;
    `out` to RUN/videos/<checkpoint>.mp4 (beside the checkpoint for a lone file). Returns 0."""
    if steps is not None and steps < 1:
        raise RecipeError(f"--steps must be >= 1, got {steps}")
    agent, ckpt, run, config = load_target(target, which, device)
    video = (config or {}).get("video", {})
    given_out = out is not None
    if out is None:
        out = run / "videos" / f"{ckpt.stem}.mp4" if run is not None else ckpt.with_suffix(".mp4")
    check_writable(out, _output_option(given_out))  # before the video renders
    seed = seed if seed is not None else (config or {}).get("train", {}).get("seed")
    info = record_video(agent, out, steps=steps or video.get("steps") or 300,
                        motions=motions or video.get("motions"), fps=video.get("fps"), seed=seed,
                        progress=progress)
    print(info["path"])
    return 0


# ---------------------------------------------------------------------------------------- generation
def generate_checkpoint(target: str | Path, *, which: str = "best", seconds: float = 20.0, seed: int = 0,
                        noise_scale: float = 1.0, motions: str | None = None, out: Path | None = None,
                        device: str = "auto", progress: bool = True) -> int:
    """An mp4 of the PULSE prior of `target` (as `evaluate_checkpoint` finds it: a PULSE run or
    checkpoint, or a latent-task policy holding one) driving the humanoid with no task, z
    sampled every step (`smpl_envs.render.generate`). `out` defaults to
    RUN/videos/<checkpoint>_generate.mp4 (beside the checkpoint for a lone file). Returns 0."""
    from smpl_envs import policy_settings
    from smpl_envs.render import generate

    if not seconds > 0:
        raise RecipeError(f"--seconds must be positive, got {seconds}")
    if not noise_scale >= 0:
        raise RecipeError(f"--noise-scale must be >= 0, got {noise_scale}")
    agent, ckpt, run, _ = load_target(target, which, device)
    # A PULSE agent's decoder knows the settings of its env; a latent-task policy's gets its task's.
    owner = agent if hasattr(agent, "latent_decoder") else agent.policy
    decoder = getattr(owner, "latent_decoder", None)
    if decoder is None:
        raise RecipeError(f"{ckpt}: its policy ({type(agent.policy).__name__}) has no latent space; give a PULSE "
                          "checkpoint (or a latent-task policy)")
    if decoder.settings is None and agent.env_id is not None:  # a latent-task policy: its env's control period
        decoder.settings = {"substeps": policy_settings.trained_settings(agent.env_id, agent.env_kwargs)["substeps"]}
    given_out = out is not None
    if out is None:
        name = f"{ckpt.stem}_generate.mp4"
        out = run / "videos" / name if run is not None else ckpt.with_name(name)
    check_writable(out, _output_option(given_out))  # before the video renders
    try:
        info = generate(decoder, out, seconds=seconds, seed=seed, noise_scale=noise_scale,
                        **({"motions": motions} if motions else {}), progress=progress)
    except ValueError as e:  # a motion that does not exist, a decoder the env cannot take
        raise RecipeError(str(e)) from None
    print(f"{info['path']} ({info['steps']} steps, {info['episodes']} episode(s))")
    return 0


# ---------------------------------------------------------------------------------------- helpers
def load_target(target: str | Path, which: str, device: str) -> tuple[Any, Path, Path | None, dict | None]:
    """(agent without an env, its checkpoint, its run directory or None, the run's config or None)."""
    import agents

    check_device(device, "--device")
    ckpt = find_checkpoint(target, which)
    run = Path(target) if Path(target).is_dir() else run_dir_of(ckpt)
    config = read_config(run) if run is not None and (run / "config.yaml").is_file() else None
    try:
        agent = agents.load(ckpt, env=None, device=device, verbose=0, tensorboard=False)
    except ValueError as e:  # not a checkpoint of ours, or its policy class cannot be imported
        raise RecipeError(str(e)) from None
    return agent, ckpt, run, config


def _output_option(given: bool) -> str:
    """How an error about the output path names it: the option, or the default the user never typed."""
    return "--out" if given else "the default output (choose another with --out)"


__all__ = ["evaluate_checkpoint", "record_checkpoint", "generate_checkpoint", "load_target", "evaluate_agent",
           "eval_settings", "record_video", "Evaluator", "summary_metrics", "save_result", "write_eval"]
