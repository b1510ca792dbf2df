"""PHC's progressive multiplicative control policy (PMCP) as one command:

    smpl-envs pmcp pmcp_corpus                    # runs/pmcp_corpus/; the same command resumes it
    smpl-envs pmcp my_pipeline.yaml --run-dir runs/pmcp --set max_primitives=2

A pipeline recipe (tasks/pipelines/<name>.yaml, or a YAML path) names the stages; `DEFAULTS`
below lists its keys. The pipeline, into one run directory:

1. primitive0: a given checkpoint (the tracker), evaluated on the whole set (`motions`) with
   PHC's clip protocol; the clips it fails form Q_hard(0).
2. primitive k = 1 .. max_primitives, while Q_hard(k-1) is not empty: a training run of the
   `primitive.recipe` started from primitive k-1's weights (`agent.init`, `agents.warm_start`:
   PHC's weight sharing), or with `primitive.lateral: true` a progressive-network column beside
   the frozen primitive k-1 (`agents.ProgressiveActorCritic`, shaped after it), on the whole set
   with the library's sampling weights putting weight 1 on the clips of Q_hard(k-1) and
   `primitive.rest_weight` (0) on the others (env kwarg `motion_weights`: a sampling weight, not a
   copied subset). It is evaluated on the whole set; the clips of Q_hard(k-1) it fails form
   Q_hard(k). `primitive.given` (checkpoints) stands for primitives 1, 2, ... instead of training
   them, evaluated and mined all the same: an earlier run's primitives reused, so that another
   recovery primitive or composer setting costs only the composer's training.
3. recovery: the recovery primitive, a run of `recovery.recipe` started from the last primitive
   (`recovery.init: previous`, or a checkpoint), or a given checkpoint (`recovery.checkpoint`:
   e.g. a separate 4-hour run). `recovery: null` leaves it out.
4. composer: a run of `composer.recipe` (policy class Composer) over all primitives, recovery
   last, on the whole set with fail-state recovery on; the env's recovery settings (switch and
   clamp distance, the action base) are the recovery primitive's, and every primitive must have
   been trained with the composer env's action settings (checked, by name).
5. The composed policy exported as RUN/pmcp.pt (no optimiser state: the file to ship), the
   perpetual-control test (`perpetual`, `smpl_envs.perpetual`; null to skip) and the tables
   (RUN/summary.txt, .json): each stage's success on the whole set and on the set it trained on,
   forgetting (each stage on every hard set), the composer against the best single primitive on
   the same evaluation, and the recovery table (recovery primitive and composer, PHC beside).

Layout: RUN/pmcp.yaml (the resolved pipeline recipe), RUN/state.json (the pipeline state: each
stage's status, checkpoint and hard set), RUN/recipes/<stage>.yaml (the training recipe each
stage ran), RUN/stages/<stage>/ (a trained stage is an ordinary run directory: config.yaml,
checkpoints/, logs/, evals/, eval.json, curves.png; every stage also holds set_eval.json/.txt,
its evaluation on the whole set, and the recovery stage and the composer recovery_eval.json).
A given stage (primitive0, a given primitive or recovery primitive) holds a copy of its checkpoint as
checkpoints/best.pt. `smpl-envs eval` and `record` take RUN/stages/<stage> and RUN/pmcp.pt as
they take any run.

Stopping and resuming: Ctrl-C or SIGTERM inside a stage's training saves its last.pt (as
`smpl-envs train` does) and the pipeline stops with that status; the same command continues at
that stage and step (`train --resume` of the stage's directory). A stop between trainings loses
at most one evaluation, which is redone. The state file is written atomically at each step.
"""
from __future__ import annotations

import copy
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any, Iterable

import yaml

from . import checkpoint_commands
from . import run as runs
from .checkpoint import newest_readable_checkpoint
from .recipes import (RecipeError, RunLock, apply_overrides, find_checkpoint, load_recipe, parse_override,
                      recipe_dirs, set_dotted)

FORMAT = "smpl-envs-pmcp/1"
IMITATION, RECOVERY = "SMPL/Imitation-v0", "SMPL/Recovery-v0"
# Every key of a pipeline recipe, with its default (None: required).
DEFAULTS: dict[str, Any] = {
    "motions": None,            # the set: mined, learnt and composed ("corpus:train", clip names, a tree)
    "primitive0": None,         # the first primitive: a shipped name, a .pt file or a run directory
    "max_primitives": 3,        # hard-clip primitives after primitive0 (PHC: 4 primitives in all, recovery one)
    "eval": {"num_envs": 16, "threshold": 0.5, "recovery_trials": 64},
    "primitive": {"recipe": "tracker_ppo", "set": [], "rest_weight": 0.0,
                  "lateral": False,       # True: a progressive column beside the one before; False: its copy
                  "given": []},           # checkpoints that stand for primitives 1, 2, ... instead of training them
    "recovery": {"recipe": "recovery_tracker_ppo", "set": [], "init": "previous", "checkpoint": None},
    "composer": {"recipe": "composer_ppo", "set": []},
    "perpetual": {"motions": "corpus:test", "minutes": 5.0, "trials": 1, "shoves": True},
}
# PHC's recovery numbers (Succ-5s / Succ-10s, %), for the table beside ours.
PHC_RECOVERY = {"fallen": (95.0, 98.8), "far": (83.7, 99.5), "fallen+far": (93.4, 98.8)}
# Settings of what an action does that every primitive must share with the composer's env.
ACTION_SETTINGS = ("substeps", "action_mode", "residual_scale")


def recovery_settings() -> tuple[str, ...]:
    """The policy settings Recovery-v0 has beyond Imitation-v0's: how the recovery goal is shown
    and what a residual acts around (the get-up and walk guides included). A recovery primitive
    trained with them runs with them in the composer's env."""
    from smpl_envs.envs.imitation import ImitationVecEnv
    from smpl_envs.envs.recovery import RecoveryVecEnv

    return tuple(k for k in RecoveryVecEnv.policy_kwargs if k not in ImitationVecEnv.policy_kwargs)


# ---------------------------------------------------------------------------------------- the recipe
def resolve_pipeline_path(name_or_path: str | os.PathLike) -> Path:
    """A YAML path as is, or a bare name as tasks/pipelines/<name>.yaml (./tasks first)."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise RecipeError(f"pipeline recipe {path} does not exist")
        return path
    for d in recipe_dirs():
        candidate = d / "pipelines" / f"{path.name}.yaml"
        if candidate.is_file():
            return candidate
    names = sorted({p.stem for d in recipe_dirs() for p in (d / "pipelines").glob("*.yaml")})
    raise RecipeError(f"no pipeline recipe named {str(name_or_path)!r} (looked in tasks/pipelines/); "
                      f"available: {', '.join(names) or 'none'}")


def load_pipeline(name_or_path: str | os.PathLike, overrides: Iterable[str] = ()) -> dict:
    """The pipeline recipe with the `KEY=VALUE` overrides applied, defaults filled in, checked."""
    path = resolve_pipeline_path(name_or_path)
    try:
        raw = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as e:
        raise RecipeError(f"{path} is not valid YAML: {' '.join(str(e).split())}") from None
    if not isinstance(raw, dict):
        raise RecipeError(f"{path} must hold a mapping with keys {', '.join(DEFAULTS)}")
    raw = copy.deepcopy(raw)
    for text in overrides:
        key, value = parse_override(text)
        set_dotted(raw, key, value)
    recipe = check_pipeline(raw)
    recipe["name"] = path.stem
    return recipe


def check_pipeline(raw: dict) -> dict:
    """Defaults filled in and every key checked (the stage recipes load with their overrides)."""
    raw = {k: v for k, v in raw.items() if k != "name"}
    unknown = sorted(set(raw) - set(DEFAULTS))
    if unknown:
        raise RecipeError(f"unknown pipeline key(s) {unknown}; a pipeline has {', '.join(DEFAULTS)}")
    out: dict[str, Any] = {}
    for key, default in DEFAULTS.items():
        given = raw.get(key, default)
        if isinstance(default, dict) and given is not None:
            if not isinstance(given, dict):
                raise RecipeError(f"{key} must be a mapping, got {given!r}")
            extra = sorted(set(given) - set(default)) if key != "perpetual" else []
            if extra:
                raise RecipeError(f"unknown key(s) {[f'{key}.{k}' for k in extra]}; {key} has {', '.join(default)}")
            given = {**default, **given}
        out[key] = given
    for key in ("motions", "primitive0"):
        if out[key] is None:
            raise RecipeError(f"a pipeline needs {key}")
    n = out["max_primitives"]
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise RecipeError(f"max_primitives must be an integer >= 0, got {n!r}")
    for stage in ("primitive", "recovery", "composer"):
        spec = out[stage]
        if spec is None:
            if stage != "recovery":
                raise RecipeError(f"{stage} must be a mapping with recipe and set")
            continue
        if not isinstance(spec["set"], list) or not all(isinstance(s, str) for s in spec["set"]):
            raise RecipeError(f"{stage}.set must be a list of KEY=VALUE overrides of its recipe, got {spec['set']!r}")
        if stage == "recovery" and spec["checkpoint"] is not None:
            continue
        load_recipe(spec["recipe"], spec["set"])  # a bad stage recipe fails now, not hours in
    given = out["primitive"]["given"]
    if not isinstance(given, list) or not all(isinstance(g, str) for g in given):
        raise RecipeError(f"primitive.given must be a list of checkpoints (names, .pt files, run directories), got {given!r}")
    if len(given) > n:
        raise RecipeError(f"primitive.given names {len(given)} primitives, more than max_primitives={n}")
    if not isinstance(out["primitive"]["lateral"], bool):
        raise RecipeError(f"primitive.lateral must be true or false, got {out['primitive']['lateral']!r}")
    w = out["primitive"]["rest_weight"]
    if isinstance(w, bool) or not isinstance(w, (int, float)) or w < 0:
        raise RecipeError(f"primitive.rest_weight must be a number >= 0, got {w!r}")
    if out["perpetual"] is not None:
        from smpl_envs.perpetual import check_options

        try:
            check_options(out["perpetual"])
        except ValueError as e:
            raise RecipeError(f"perpetual: {e}") from None
    ev = out["eval"]
    for k in ("num_envs", "recovery_trials"):
        if isinstance(ev[k], bool) or not isinstance(ev[k], int) or ev[k] < 1:
            raise RecipeError(f"eval.{k} must be an integer >= 1, got {ev[k]!r}")
    return out


# ---------------------------------------------------------------------------------------- mining
def hard_clips(rows: list[dict], within: Iterable[str] | None = None) -> list[str]:
    """The names of the clips an evaluation's rows (`ClipProtocol`) fail, in row order; only
    those in `within` when given (PHC: Q_hard(k) = the clips of Q_hard(k-1) primitive k fails)."""
    keep = None if within is None else set(within)
    return [r["name"] for r in rows if not r["success"] and (keep is None or r["name"] in keep)]


def success_on(rows: list[dict], names: Iterable[str] | None = None) -> float | None:
    """The success rate over the rows of `names` (all rows when None); None for no clip."""
    keep = None if names is None else set(names)
    mine = [bool(r["success"]) for r in rows if keep is None or r["name"] in keep]
    return sum(mine) / len(mine) if mine else None


# ---------------------------------------------------------------------------------------- evaluation
def settings_for(agent, env_id: str) -> dict:
    """Env kwargs that make `env_id` run `agent`'s actions and observations as it trained them,
    for an agent trained on the other of Imitation-v0 / Recovery-v0 (its recorded settings, the
    recovery ones moved between Recovery-v0's kwargs and Imitation's `recovery` dict)."""
    from smpl_envs import policy_settings

    trained = policy_settings.trained_settings(agent.env_id, agent.env_kwargs)
    out = {k: trained[k] for k in ACTION_SETTINGS if k in trained}
    if env_id == RECOVERY:
        recovery = agent.env_kwargs.get("recovery")
        recovery = recovery if isinstance(recovery, dict) else {}
        names = recovery_settings()
        out.update({k: recovery[k] for k in names if k in recovery})
        out.update({k: trained[k] for k in names if k in trained})
    return out


def evaluate_as(agent, env_id: str, motions=None, num_envs: int = 8, progress: bool = True, **options):
    """`smpl_envs.evaluate` of `agent` with `env_id`'s protocol: on its own task as `run.evaluate_agent`;
    on the other of Imitation-v0 / Recovery-v0 (a recovery primitive on the clips, a composer
    from fallen starts) as a plain policy in an env made with its settings (`settings_for`)."""
    import smpl_envs

    if agent.env_id == env_id:
        return checkpoint_commands.evaluate_agent(agent, motions, num_envs, progress, **options)
    act = lambda obs: agent.predict(obs)[0]  # noqa: E731 (no training record: the settings come below)
    return smpl_envs.evaluate(act, env=env_id, motions=motions, num_envs=num_envs, progress=progress,
                              env_kwargs=settings_for(agent, env_id), **options)


# ---------------------------------------------------------------------------------------- the pipeline
def pmcp(recipe: str | os.PathLike, *, overrides: Iterable[str] = (), run_dir: Path | None = None,
         runs_root: Path = Path("runs"), overwrite: bool = False, device: str | None = None, quiet: bool = False,
         update_threads: int | None = None, progress: bool = True) -> int:
    """Run (or resume) the pipeline `recipe` into `run_dir` (default RUNS_ROOT/<recipe name>, so
    the same command finds it again). Returns the exit status: 0, or the status a stage's
    training stopped with (INTERRUPTED, TERMINATED, DISK_FULL)."""
    spec = load_pipeline(recipe, overrides)
    run = Path(run_dir) if run_dir is not None else Path(runs_root) / spec["name"]
    lock = RunLock(run).acquire()
    try:
        if overwrite:
            for entry in run.iterdir():
                if entry.name != ".lock":
                    shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
        pipeline = Pipeline(spec, run, device=device, quiet=quiet, update_threads=update_threads, progress=progress,
                            command=_command(recipe, overrides, run_dir, runs_root))
        try:
            return pipeline.run()
        except KeyboardInterrupt:
            print(f"\ninterrupted in stage {pipeline.current}; continue with: {pipeline.command}", file=sys.stderr)
            return runs.INTERRUPTED
    finally:
        lock.release()


def _command(recipe, overrides, run_dir, runs_root) -> str:
    parts = ["smpl-envs pmcp", str(recipe)] + [f"--set {o}" for o in overrides]
    if run_dir is not None:
        parts.append(f"--run-dir {run_dir}")
    elif Path(runs_root) != Path("runs"):
        parts.append(f"--runs-root {runs_root}")
    return " ".join(parts)


class Pipeline:
    """The stages of one pipeline run directory (module docstring); `run` does what is left."""

    def __init__(self, spec: dict, run: Path, *, device=None, quiet=False, update_threads=None, progress=True,
                 command: str = "smpl-envs pmcp"):
        self.spec, self.run_dir = spec, Path(run)
        self.device, self.quiet, self.update_threads, self.progress = device, quiet, update_threads, progress
        self.command, self.current = command, None
        self.state_path = self.run_dir / "state.json"
        self.stages = self.run_dir / "stages"
        self.state = self._load_state()

    # --- state
    def _load_state(self) -> dict:
        stored = self.run_dir / "pmcp.yaml"
        if self.state_path.is_file():
            state = json.loads(self.state_path.read_text())
            if state.get("format") != FORMAT:
                raise RecipeError(f"{self.state_path} is not a pipeline state of this version ({FORMAT})")
            # Filled in again with today's defaults: a key added since the run began is no change.
            old = {**check_pipeline(state["recipe"]), "name": state["recipe"].get("name")}
            if old != self.spec:
                key = next(k for k in set(old) | set(self.spec) if old.get(k) != self.spec.get(k))
                raise RecipeError(f"{self.run_dir} holds a pipeline made with another recipe ({key}: "
                                  f"{old.get(key)!r} there, {self.spec.get(key)!r} now); give the same recipe and "
                                  "settings to resume it, or --overwrite / another --run-dir to start anew")
            return state
        others = [e for e in self.run_dir.iterdir() if e.name != ".lock"] if self.run_dir.is_dir() else []
        if others:
            raise RecipeError(f"{self.run_dir} exists and holds no pipeline state; choose another --run-dir or "
                              "--overwrite it")
        self.run_dir.mkdir(parents=True, exist_ok=True)
        stored.write_text(yaml.safe_dump(self.spec, sort_keys=False))
        state = {"format": FORMAT, "recipe": self.spec, "order": [], "stages": {}, "done": False}
        self._write(state)
        return state

    def _write(self, state: dict | None = None) -> None:
        state = self.state if state is None else state
        tmp = self.state_path.with_name(".state.json.tmp")
        tmp.write_text(json.dumps(state, indent=2))
        os.replace(tmp, self.state_path)

    def _stage(self, name: str, **fields) -> dict:
        if name not in self.state["stages"]:
            self.state["stages"][name] = {"name": name, "status": "new", **fields}
            self.state["order"].append(name)
            self._write()
        self.current = name
        return self.state["stages"][name]

    # --- the run
    def run(self) -> int:
        spec = self.spec
        for target in spec["primitive"]["given"] + [(spec["recovery"] or {}).get("checkpoint")]:
            if target is not None:  # a missing one fails now, not after an hour of stages
                composer, index = split_primitive_target(target)
                find_checkpoint(composer) if index is None else primitive_agent(find_checkpoint(composer), index)
        p0 = self._stage("primitive0", kind="primitive", index=0, trained_on=None)
        if p0["status"] == "new":
            self._given(p0, spec["primitive0"])
        self._evaluate_set(p0)
        primitives = ["primitive0"]
        for k in range(1, spec["max_primitives"] + 1):
            previous = self.state["stages"][primitives[-1]]
            if not previous["hard"]:
                break
            name = f"primitive{k}"
            stage = self._stage(name, kind="primitive", index=k, trained_on=previous["hard"])
            if k <= len(spec["primitive"]["given"]):
                if stage["status"] == "new":
                    self._given(stage, spec["primitive"]["given"][k - 1])
            else:
                rc = self._train(stage, lambda: self._primitive_recipe(previous))
                if rc:
                    return rc
            self._evaluate_set(stage, within=stage["trained_on"])
            primitives.append(name)
        if spec["recovery"] is not None:
            stage = self._stage("recovery", kind="recovery")
            if spec["recovery"]["checkpoint"] is not None:
                if stage["status"] == "new":
                    self._given(stage, spec["recovery"]["checkpoint"])
            else:
                last = self.state["stages"][primitives[-1]]["checkpoint"]
                rc = self._train(stage, lambda: self._recovery_recipe(last))
                if rc:
                    return rc
            self._evaluate_set(stage)
            self._evaluate_recovery(stage)
            primitives.append("recovery")
        composer = self._stage("composer", kind="composer", primitives=primitives)
        rc = self._train(composer, lambda: self._composer_recipe(primitives))
        if rc:
            return rc
        self._evaluate_set(composer)
        self._evaluate_recovery(composer)
        self._export(composer)
        self._perpetual()
        self.current = None
        print(self._summary())
        self.state["done"] = True
        self._write()
        print(f"pipeline done: {self.run_dir} (composed policy: {self.run_dir / 'pmcp.pt'})")
        return 0

    def _given(self, stage: dict, target: str) -> None:
        """A stage whose policy is a given checkpoint (or a composer's primitive, `COMPOSER#k`): a
        copy of it as the stage's checkpoints/best.pt, so the stage evaluates and records like a
        trained one."""
        copy_path = self.stages / stage["name"] / "checkpoints" / "best.pt"
        copy_path.parent.mkdir(parents=True, exist_ok=True)
        composer, index = split_primitive_target(target)
        if index is None:
            source = find_checkpoint(target)
            shutil.copyfile(source, copy_path)
        else:
            source = find_checkpoint(composer)
            primitive_agent(source, index).save(copy_path, optimizer=False)
        stage.update(source=str(source.resolve()) + ("" if index is None else f"#{index}"),
                     checkpoint=str(copy_path.resolve()), status="trained")
        self._write()

    # --- training a stage
    def _train(self, stage: dict, build) -> int:
        if stage["status"] in ("trained", "done"):
            return 0
        directory = self.stages / stage["name"]
        if stage["status"] == "new":
            recipe = build()
            path = self.run_dir / "recipes" / f"{stage['name']}.yaml"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(yaml.safe_dump(recipe, sort_keys=False, default_flow_style=None))
            stage.update(status="training", recipe=str(path))
            self._write()
        options = dict(device=self.device, quiet=self.quiet, update_threads=self.update_threads,
                       progress=self.progress)
        print(f"pmcp: stage {stage['name']}: {directory}", flush=True)
        checkpoint, _ = newest_readable_checkpoint(directory / "checkpoints")
        if checkpoint is not None:  # stopped in the middle: continue at its step
            rc = runs.train(resume=directory, **options)
        else:  # not started, or stopped before its first checkpoint: nothing to keep
            rc = runs.train(stage["recipe"], run_dir=directory, overwrite=directory.exists(), **options)
        if rc:
            print(f"pipeline stopped in stage {stage['name']}; continue with: {self.command}", file=sys.stderr)
            return rc
        stage.update(status="trained", checkpoint=str(find_checkpoint(directory, "best").resolve()))
        self._write()
        return 0

    def _stage_recipe(self, key: str) -> dict:
        spec = self.spec[key]
        return load_recipe(spec["recipe"], spec["set"])

    def _primitive_recipe(self, previous: dict) -> dict:
        recipe = self._stage_recipe("primitive")
        if recipe["env"]["id"] != IMITATION:
            raise RecipeError(f"primitive.recipe trains {recipe['env']['id']}; a hard-clip primitive imitates "
                              f"({IMITATION})")
        weights = {name: 1.0 for name in previous["hard"]}
        rest = float(self.spec["primitive"]["rest_weight"])
        if rest > 0:
            rows = _rows(self.stages / previous["name"] / "set_eval.json")
            weights = {r["name"]: weights.get(r["name"], rest) for r in rows}
        kwargs = recipe["env"]["kwargs"]
        kwargs.update(motions=self.spec["motions"], motion_weights=weights)
        if not self.spec["primitive"]["lateral"]:
            recipe["agent"]["init"] = previous["checkpoint"]
            return apply_overrides(recipe)
        # A column beside the frozen previous primitive, shaped after it (agents.progressive);
        # warm_start checks the action settings for a copy, a column needs them too.
        _check_action_settings(previous["checkpoint"], recipe["env"]["id"], kwargs,
                               lambda k, theirs, mine: f"{previous['name']} was trained with {k}={theirs!r}, "
                               f"primitive.recipe has {k}={mine!r}; a column beside it would read its features "
                               "under other actions")
        recipe["agent"]["init"] = None
        recipe["agent"]["policy"] = {"class": "ProgressiveActorCritic",
                                     "kwargs": {"previous": {"checkpoint": previous["checkpoint"]}}}
        return apply_overrides(recipe)

    def _recovery_recipe(self, last_primitive: str) -> dict:
        recipe = self._stage_recipe("recovery")
        init = self.spec["recovery"]["init"]
        if init == "previous":
            recipe["agent"]["init"] = last_primitive
        elif init is not None:
            recipe["agent"]["init"] = str(find_checkpoint(init).resolve())
        return apply_overrides(recipe)

    def _composer_recipe(self, primitives: list[str]) -> dict:
        import agents

        recipe = self._stage_recipe("composer")
        if recipe["env"]["id"] != IMITATION:
            raise RecipeError(f"composer.recipe trains {recipe['env']['id']}; the composer imitates with recovery "
                              f"on ({IMITATION})")
        policy = recipe["agent"]["policy"]
        if not issubclass(agents.policies.policy_class(policy["class"]), agents.Composer):
            raise RecipeError(f"composer.recipe's policy is {policy['class']}, not a Composer")
        kwargs = recipe["env"]["kwargs"]
        kwargs["motions"] = self.spec["motions"]
        recovery = kwargs.get("recovery")
        recovery = dict(recovery) if isinstance(recovery, dict) else {}
        paths = [self.state["stages"][name]["checkpoint"] for name in primitives]
        for name, path in zip(primitives, paths):
            agent, theirs = _check_action_settings(
                path, IMITATION, kwargs, lambda k, theirs, mine, name=name, path=path:
                f"primitive {name} ({path}) was trained with {k}={theirs!r}, the composer's env has {k}={mine!r}; "
                f"its actions would mean something else there (set composer env.kwargs.{k})")
            if name == "recovery":  # the composer's env recovers as the recovery primitive learnt to
                recovery.update(settings_for(agent, RECOVERY) if agent.env_id != RECOVERY else
                                {k: theirs[k] for k in recovery_settings() if k in theirs})
                for k in ACTION_SETTINGS:
                    recovery.pop(k, None)
        kwargs["recovery"] = recovery or True
        policy["kwargs"]["primitives"] = [{"checkpoint": p} for p in paths]
        return apply_overrides(recipe)

    # --- evaluations
    def _load(self, stage: dict):
        import agents

        return agents.load(stage["checkpoint"], device=self.device or "auto", verbose=0, tensorboard=False)

    def _evaluate_set(self, stage: dict, within: list[str] | None = None) -> None:
        """The stage's evaluation on the whole set (set_eval.json) and, for a primitive, its hard set."""
        if "set_eval" in stage:
            return
        ev = self.spec["eval"]
        agent = self._load(stage)
        print(f"pmcp: evaluating {stage['name']} on {self.spec['motions']}", flush=True)
        result = evaluate_as(agent, IMITATION, self.spec["motions"], ev["num_envs"], self.progress,
                             threshold=ev["threshold"])
        path = self.stages / stage["name"] / "set_eval.json"
        checkpoint_commands.save_result(result, path)
        stage["set_eval"] = str(path)
        stage["success"] = success_on(result.rows)
        if stage["kind"] == "primitive":
            stage["hard"] = hard_clips(result.rows, within)
            print(f"pmcp: {stage['name']} fails {len(stage['hard'])} clip(s)"
                  + (f" of the {len(within)} it learnt" if within is not None else ""), flush=True)
        stage["status"] = "done" if stage["kind"] == "primitive" else stage["status"]
        self._write()

    def _evaluate_recovery(self, stage: dict) -> None:
        if "recovery_eval" in stage:
            return
        ev = self.spec["eval"]
        agent = self._load(stage)
        print(f"pmcp: recovery evaluation of {stage['name']}", flush=True)
        result = evaluate_as(agent, RECOVERY, "stand", ev["num_envs"], self.progress, trials=ev["recovery_trials"])
        path = self.stages / stage["name"] / "recovery_eval.json"
        checkpoint_commands.save_result(result, path)
        stage.update(recovery_eval=str(path), status="done")
        self._write()

    def _export(self, composer: dict) -> None:
        target = self.run_dir / "pmcp.pt"
        if "export" in composer:
            return
        self._load(composer).save(target, optimizer=False)
        composer["export"] = str(target)
        self._write()

    def _perpetual(self) -> None:
        opts = self.spec["perpetual"]
        if opts is None or "perpetual" in self.state:
            return
        from smpl_envs.perpetual import evaluate_perpetual

        agent = self._load({"checkpoint": str(self.run_dir / "pmcp.pt")})
        print("pmcp: perpetual-control test of the composed policy", flush=True)
        result = evaluate_perpetual(agent, progress=self.progress, **opts)
        path = result.save(self.run_dir / "perpetual.json")
        path.with_suffix(".txt").write_text(result.table() + "\n")
        print(result.table())
        self.state["perpetual"] = str(path)
        self._write()

    # --- tables
    def _summary(self) -> str:
        text, data = summary_tables(self.state, self.stages)
        (self.run_dir / "summary.txt").write_text(text + "\n")
        (self.run_dir / "summary.json").write_text(json.dumps(data, indent=2) + "\n")
        return text


def _check_action_settings(checkpoint: str, env_id: str, kwargs: dict, message):
    """(agent, its trained settings) of `checkpoint`, after checking that env `env_id` with
    `kwargs` gives its actions the meaning they had (ACTION_SETTINGS); a RecipeError with
    `message(setting, trained value, value here)` otherwise."""
    import agents
    from smpl_envs import policy_settings

    agent = agents.load(checkpoint, device="cpu", verbose=0, tensorboard=False)
    theirs = policy_settings.trained_settings(agent.env_id, agent.env_kwargs)
    mine = policy_settings.trained_settings(env_id, kwargs)
    for setting in ACTION_SETTINGS:
        if setting in theirs and theirs[setting] != mine.get(setting):
            raise RecipeError(message(setting, theirs[setting], mine.get(setting)))
    return agent, theirs


def split_primitive_target(target: str) -> tuple[str, int | None]:
    """("pmcp", 1) for "pmcp#1" (a composer's primitive 1); (target, None) for anything else,
    a path that exists included."""
    if Path(target).exists():
        return str(target), None
    base, sep, index = str(target).rpartition("#")
    return (base, int(index)) if sep and base and index.isdigit() else (str(target), None)


def primitive_agent(composer_checkpoint: str | os.PathLike, index: int):
    """Primitive `index` of a composer checkpoint as an agent of its own: the primitive's weights
    (its normaliser included) with the composer's imitation settings, which every hard-clip
    primitive shares with it (checked when the composer was built). The last primitive of a
    composer that recovers is its recovery primitive, whose guide settings the composer keeps only
    for its env: it is refused (give the recovery primitive's own checkpoint)."""
    import agents

    agent = agents.load(composer_checkpoint, device="cpu", verbose=0, tensorboard=False)
    if not isinstance(agent.policy, agents.Composer):
        raise RecipeError(f"{composer_checkpoint} holds a policy of class {type(agent.policy).__name__}, not a Composer; "
                          "COMPOSER#k names a composer's primitive k")
    k = agent.policy.num_primitives
    recovers = bool(agent.env_kwargs.get("recovery"))
    usable = k - 1 if recovers else k
    if not 0 <= index < usable:
        raise RecipeError(f"{composer_checkpoint}#{index}: the composer has {k} primitives"
                          + (f", the last of them its recovery primitive; hard-clip primitives are #0 to #{usable - 1}"
                             if recovers else f" (#0 to #{k - 1})"))
    primitive = agent.policy.primitives[index]
    record = agents.policies.policy_record(primitive)
    policy = agents.policies.make_policy(record["class"], primitive.obs_dim, primitive.action_space, record["kwargs"])
    policy.load_state_dict(primitive.state_dict())
    agent._build(primitive.obs_dim, primitive.action_space, policy)  # its own optimiser, over its weights
    agent.env_kwargs = {key: v for key, v in agent.env_kwargs.items() if key != "recovery"}
    agent.num_timesteps = 0
    return agent


def _rows(path: Path) -> list[dict]:
    return json.loads(Path(path).read_text())["clips"]


def summary_tables(state: dict, stages: Path) -> tuple[str, dict]:
    """PHC's tables of a finished pipeline (module docstring): (text, the same as data)."""
    order = [state["stages"][n] for n in state["order"]]
    rows = {s["name"]: _rows(s["set_eval"]) for s in order if "set_eval" in s}
    hard_sets = [(f"Q_hard({s['index']})", s["hard"]) for s in order if s["kind"] == "primitive" and s["hard"]]
    pct = lambda x: "-" if x is None else f"{100 * x:5.1f}%"  # noqa: E731
    data: dict[str, Any] = {"stages": [], "forgetting": {}, "composer_vs_best": None, "recovery": {}}
    lines = ["stages (success on the whole set, and on the clips the stage trained on)",
             f"  {'stage':<12}{'whole set':>10}{'own set':>10}{'own clips':>10}{'fails':>7}"]
    for s in order:
        own = s.get("trained_on")
        whole = success_on(rows[s["name"]]) if s["name"] in rows else None
        mine = success_on(rows[s["name"]], own) if own is not None and s["name"] in rows else None
        fails = len(s["hard"]) if s.get("hard") is not None else None
        lines.append(f"  {s['name']:<12}{pct(whole):>10}{pct(mine):>10}{'-' if own is None else len(own):>10}"
                     f"{'-' if fails is None else fails:>7}")
        data["stages"].append({"stage": s["name"], "checkpoint": s.get("checkpoint"), "success": whole,
                               "success_own": mine, "own_clips": None if own is None else len(own), "fails": fails})
    if hard_sets:
        lines += ["", "forgetting (success of each stage on each hard set)",
                  "  " + f"{'stage':<12}" + "".join(f"{name:>12}" for name, _ in hard_sets)]
        for s in order:
            if s["name"] not in rows:
                continue
            values = [success_on(rows[s["name"]], clips) for _, clips in hard_sets]
            lines.append("  " + f"{s['name']:<12}" + "".join(f"{pct(v):>12}" for v in values))
            data["forgetting"][s["name"]] = dict(zip([n for n, _ in hard_sets], values))
    if "composer" in rows:
        singles = {n: success_on(r) for n, r in rows.items() if n != "composer"}
        best = max(singles, key=lambda n: singles[n])
        comp = success_on(rows["composer"])
        lines += ["", f"composer {pct(comp)} against the best single primitive, {best}, {pct(singles[best])} "
                      "(the same evaluation: every clip of the set once)"]
        data["composer_vs_best"] = {"composer": comp, "best": best, "best_success": singles[best]}
    recov = [s for s in order if "recovery_eval" in s]
    if recov:
        lines += ["", "recovery (Succ-5s / Succ-10s; PHC: 1000 trials on a standing clip)",
                  "  " + f"{'start':<12}" + "".join(f"{s['name']:>18}" for s in recov) + f"{'PHC':>18}"]
        summaries = {s["name"]: json.loads(Path(s["recovery_eval"]).read_text())["summary"] for s in recov}
        for kind, (p5, p10) in PHC_RECOVERY.items():
            cells = []
            for s in recov:
                m = summaries[s["name"]]
                cells.append(f"{100 * m[f'succ_5s_{kind}']:.1f} / {100 * m[f'succ_10s_{kind}']:.1f}"
                             if f"succ_5s_{kind}" in m else "-")
            lines.append("  " + f"{kind:<12}" + "".join(f"{c:>18}" for c in cells) + f"{f'{p5} / {p10}':>18}")
        data["recovery"] = summaries
    if state.get("perpetual"):
        lines += ["", Path(state["perpetual"]).with_suffix(".txt").read_text().rstrip()]
        data["perpetual"] = json.loads(Path(state["perpetual"]).read_text())["summary"]
    return "\n".join(lines), data


# ---------------------------------------------------------------------------------------- perpetual
def perpetual_checkpoint(target: str | Path, *, which: str = "best", options: dict | None = None,
                         out: Path | None = None, video: Path | None = None, device: str = "auto",
                         progress: bool = True) -> int:
    """The perpetual-control test (`smpl_envs.perpetual`) of the checkpoint of `target` (as
    `smpl-envs eval` finds it). The result goes to `out` (JSON, with its table beside it as .txt)
    or stdout; `video`: an mp4 of world 0. Returns 0."""
    import agents
    from smpl_envs.perpetual import check_options, evaluate_perpetual

    try:
        options = check_options(dict(options or {}))
    except ValueError as e:
        raise RecipeError(str(e)) from None
    path = find_checkpoint(target, which)
    try:
        agent = agents.load(path, device=device, verbose=0, tensorboard=False)
        result = evaluate_perpetual(agent, video=video, progress=progress, **options)
    except ValueError as e:
        raise RecipeError(str(e)) from None
    print(f"checkpoint: {path} ({agent.num_timesteps:,} timesteps)")
    print(result.table())
    if out is not None:
        result.save(out)
        out.with_suffix(".txt").write_text(result.table() + "\n")
        print(out)
    if video is not None:
        print(video)
    return 0


__all__ = ["pmcp", "Pipeline", "load_pipeline", "check_pipeline", "hard_clips", "success_on", "evaluate_as",
           "settings_for", "recovery_settings", "summary_tables", "perpetual_checkpoint", "primitive_agent",
           "split_primitive_target", "DEFAULTS"]
