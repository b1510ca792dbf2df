"""Training recipes: YAML files that pin an env, an agent, its hyperparameters and a budget.

    recipe = load_recipe("imitation_ppo", overrides=["env.num_envs=8"], profile="paper")
    run = make_run_dir(recipe)            # runs/imitation_ppo-20250101-120000/{checkpoints,logs,videos}
    find_checkpoint(run)                  # run/checkpoints/best.pt, else last.pt, else the newest ckpt

A recipe has the sections `env`, `agent`, `train`, `eval` and `video` (see tasks/*.yaml) and may
carry `profiles`: named sets of dotted-key overrides (`agent.hyperparams.batch_size: 16384`) that
rescale it, e.g. from this CPU box to PHC's GPU budget. `base: <recipe>` starts from another
recipe and overrides only what differs (mappings merge key by key, profiles included, except
env.kwargs, agent.policy and eval.options, which are stated whole; anything else is replaced),
so shared values are written once.

`agent.init: NAME_OR_PATH` (or `{checkpoint: ..., exclude: [...]}`) starts a new run's policy
from another checkpoint's weights and normalisers (`agents.warm_start`; `train --init`), and
`train.curriculum` schedules the start mix of a recovery env over training (`agents.curriculum`).

The agent's policy is `agent.policy: {class: NAME, kwargs: {...}}`: a registered policy class
(`ActorCritic`, the default) or an importable path (`my_package.policies:Composer`) and its
keyword arguments, where `{checkpoint: NAME_OR_PATH}` stands for another run's or a shipped
checkpoint's policy (loaded, frozen, when the agent is built: `agents.run`). The actor-critic's
arguments were agent hyperparameters before policies were plug-ins; written there
(`agent.hyperparams.actor_hidden`, in an old recipe, a run's config.yaml or a `--set`), they
move to `agent.policy.kwargs`, replacing the value there. `eval.options` are the task's evaluation options (imitation:
threshold; goal tasks: episodes, seed), checked against the task's protocol. Resolving a recipe applies the profile,
then the command line's `key=value` overrides, fills in defaults and validates every section, so a
typo fails before any env is built rather than hours into a run.
"""
from __future__ import annotations

import copy
import inspect
import os
import re
import tempfile
from datetime import datetime
from pathlib import Path
from typing import Any, Iterable

import yaml

from . import AGENTS
from .networks import ActorCritic
from .policies import PolicyClassError, class_name, policy_class, split_former_hyperparams

try:
    import fcntl
except ImportError:  # Windows: no flock
    fcntl = None

CONFIG_NAME = "config.yaml"
RUN_SUBDIRS = ("checkpoints", "logs", "videos")
LOCK_NAME = ".lock"  # a live run's hold on its directory (`RunLock`), with its process id

# Every key a section may hold, with its default. `env.kwargs` and `agent.hyperparams` are free
# form here; the hyperparameters are checked against the agent class's constructor instead.
DEFAULTS: dict[str, dict[str, Any]] = {
    "env": {"id": None, "num_envs": 1, "kwargs": {}},
    "agent": {"class": None, "policy": None, "hyperparams": {}, "init": None},
    "train": {"total_timesteps": None, "max_minutes": None, "seed": 0, "checkpoint_every": 0, "log_interval": 1,
              "device": "auto", "curriculum": None},
    "eval": {"every": 0, "num_envs": 8, "motions": None, "options": {}},
    "video": {"steps": 300, "fps": None, "motions": None},
}
# Bookkeeping written into a resolved recipe (and so into a run's config.yaml).
META_KEYS = ("recipe_name", "recipe_path", "profile", "overrides")

# Constructor arguments the recipe sets elsewhere (or the CLI sets itself), with where they belong.
RESERVED_HYPERPARAMS = {
    "n_envs": "env.num_envs", "env_kwargs": "env.kwargs", "seed": "train.seed", "device": "train.device",
    "verbose": "the command line (--quiet)", "log_dir": "the run directory", "tensorboard": "the run directory",
    "update_threads": "the command line (--update-threads)", "grad_sync": "the command line (--grad-sync)",
    "policy": "agent.policy.class",
    "policy_kwargs": "agent.policy.kwargs",
}

# A float YAML 1.1 reads as a string because it lacks a dot ("3e-4", "1e6").
_FLOAT_RE = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


class RecipeError(ValueError):
    """A recipe, an override, a run directory or a checkpoint path the user gave is unusable."""


# ---------------------------------------------------------------------------------------- lookup
# The shipped recipes: tasks/ at the top of a source checkout (an editable install reads them
# there); an installed wheel carries them as agents/tasks/ (setup.py copies them in).
SOURCE_RECIPES = Path(__file__).resolve().parents[1] / "tasks"
PACKAGED_RECIPES = Path(__file__).resolve().parent / "tasks"


def shipped_recipe_dir() -> Path:
    return PACKAGED_RECIPES if PACKAGED_RECIPES.is_dir() else SOURCE_RECIPES


def recipe_dirs() -> list[Path]:
    """Where bare recipe names are looked up: ./tasks first (the user's own), then the shipped ones."""
    dirs = [Path.cwd() / "tasks", shipped_recipe_dir()]
    return [d for i, d in enumerate(dirs) if d.resolve() not in [e.resolve() for e in dirs[:i]]]


def available_recipes() -> list[str]:
    return sorted({p.stem for d in recipe_dirs() if d.is_dir() for p in d.glob("*.yaml")})


def recipe_description(path: str | os.PathLike, width: int = 110) -> str:
    """A recipe's one-line description: the first sentence of the comment that opens its file."""
    lines = []
    for line in Path(path).read_text().splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    text = " ".join(part for part in lines if part)
    sentence = re.split(r"(?<=[.!?])\s+(?=[A-Z`(])", text, maxsplit=1)[0]
    if len(sentence) > width:
        sentence = sentence[:width - 3].rsplit(" ", 1)[0] + "..."
    return sentence


def resolve_recipe_path(name_or_path: str | os.PathLike) -> Path:
    """A YAML file path as is, or a bare name as tasks/<name>.yaml (see `recipe_dirs`)."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise RecipeError(f"recipe file {path} does not exist")
        return path
    for d in recipe_dirs():
        candidate = d / f"{path.name}.yaml"
        if candidate.is_file():
            return candidate
    names = ", ".join(available_recipes()) or "none"
    raise RecipeError(f"no recipe named {str(name_or_path)!r} (looked in {', '.join(map(str, recipe_dirs()))}); "
                      f"available: {names}")


# ---------------------------------------------------------------------------------------- values
def parse_value(text: str) -> Any:
    """A command-line value as YAML reads it (numbers, lists, true, null ...), with the floats
    YAML 1.1 leaves as strings ("3e-4") made floats."""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text  # not YAML (e.g. an unbalanced bracket in a path): keep the literal string
    return _fix_floats(value)


def _fix_floats(value: Any) -> Any:
    if isinstance(value, str) and _FLOAT_RE.fullmatch(value.strip()):
        return float(value)
    if isinstance(value, dict):
        return {k: _fix_floats(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_fix_floats(v) for v in value]
    return value


def parse_override(text: str) -> tuple[str, Any]:
    """"a.b.c=value" -> ("a.b.c", parsed value)."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise RecipeError(f"bad override {text!r}: expected KEY=VALUE with a dotted KEY, e.g. env.num_envs=8")
    return key, parse_value(value)


def set_dotted(tree: dict, key: str, value: Any) -> None:
    """tree["a"]["b"]["c"] = value for key "a.b.c", creating missing levels."""
    *parents, leaf = key.split(".")
    node = tree
    for i, part in enumerate(parents):
        child = node.setdefault(part, {})
        if child is None:  # `kwargs:` left empty in YAML reads as null
            child = node[part] = {}
        if not isinstance(child, dict):
            raise RecipeError(f"cannot set {key!r}: {'.'.join(parents[:i + 1])!r} is {child!r}, not a mapping")
        node = child
    node[leaf] = value


# ---------------------------------------------------------------------------------------- resolve
def load_recipe(name_or_path: str | os.PathLike, overrides: Iterable[str] = (), profile: str | None = None) -> dict:
    """Read a recipe, apply `profile` then the `KEY=VALUE` overrides, and validate it.

    The result has no `profiles` key; it records `recipe_name`, `recipe_path`, `profile` and
    `overrides` so a run's config.yaml says how it was made.
    """
    path = resolve_recipe_path(name_or_path)
    raw = _read_with_bases(path, ())
    profiles = raw.pop("profiles", None) or {}
    if not isinstance(profiles, dict):
        raise RecipeError(f"{path}: `profiles` must map profile names to overrides")
    raw.update(recipe_name=path.stem, recipe_path=str(path.resolve()), profile=None, overrides=[])
    if profile is not None:
        if profile not in profiles:
            raise RecipeError(f"recipe {path.stem!r} has no profile {profile!r}; "
                              f"available: {', '.join(profiles) or 'none'}")
        for key, value in (profiles[profile] or {}).items():
            set_dotted(raw, str(key), _fix_floats(value))
        raw["profile"] = profile
    return apply_overrides(raw, overrides)


def _read_with_bases(path: Path, seen: tuple[Path, ...]) -> dict:
    """The recipe at `path` merged over its `base:` chain."""
    if path.resolve() in seen:
        chain = " -> ".join(p.stem for p in (*seen, path))
        raise RecipeError(f"recipe bases form a loop: {chain}")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise RecipeError(f"{path} is not valid YAML: {' '.join(str(e).split())}") from None
    if not isinstance(raw, dict):
        raise RecipeError(f"{path} must hold a mapping with sections {', '.join(DEFAULTS)}")
    base = raw.pop("base", None)
    if base is None:
        return raw
    if not isinstance(base, str):
        raise RecipeError(f"{path}: base must be a recipe name or path, got {base!r}")
    # A relative base path is relative to the recipe that names it; a bare name is looked up.
    candidate = path.parent / base
    base_path = candidate if candidate.suffix in (".yaml", ".yml") and candidate.is_file() else resolve_recipe_path(base)
    return _deep_merge(_read_with_bases(base_path, (*seen, path.resolve())), raw)


# Mappings a recipe states whole: their keys belong to one task, so a base's do not carry over.
_REPLACED_WHOLE = ("env.kwargs", "agent.policy", "eval.options")


def _deep_merge(base: dict, over: dict, prefix: str = "") -> dict:
    out = copy.deepcopy(base)
    for key, value in over.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict) and isinstance(out.get(key), dict) and path not in _REPLACED_WHOLE:
            out[key] = _deep_merge(out[key], value, f"{path}.")
        else:
            out[key] = copy.deepcopy(value)
    return out


def apply_overrides(recipe: dict, overrides: Iterable[str] = ()) -> dict:
    """A validated copy of `recipe` with the `KEY=VALUE` overrides applied (and appended to its
    `overrides` record). Also used to change a stored run config when resuming."""
    recipe = _fix_floats(copy.deepcopy(recipe))
    overrides = list(overrides)
    for text in overrides:
        key, value = parse_override(text)
        if key.split(".")[0] in META_KEYS:
            raise RecipeError(f"bad override {text!r}: {key.split('.')[0]!r} is bookkeeping, not a setting")
        set_dotted(recipe, key, value)
    recipe["overrides"] = list(recipe.get("overrides") or []) + overrides
    return validate_recipe(recipe)


def validate_recipe(recipe: dict) -> dict:
    """Fill in defaults and check every setting; RecipeError names the offending key."""
    unknown = sorted(set(recipe) - set(DEFAULTS) - set(META_KEYS) - {"profiles"})
    if unknown:
        raise RecipeError(f"unknown recipe section(s) {unknown}; sections are {', '.join(DEFAULTS)}")
    out = {k: recipe.get(k) for k in META_KEYS}
    for section, defaults in DEFAULTS.items():
        given = recipe.get(section) or {}
        if not isinstance(given, dict):
            raise RecipeError(f"recipe section {section!r} must be a mapping, got {given!r}")
        if section == "eval" and "threshold" in given:  # run configs from before eval.options
            given = {**given, "options": {**(given.get("options") or {}), "threshold": given["threshold"]}}
            given.pop("threshold")
        extra = sorted(set(given) - set(defaults))
        if extra:
            raise RecipeError(f"unknown key(s) {[f'{section}.{k}' for k in extra]}; "
                              f"{section} has {', '.join(f'{section}.{k}' for k in defaults)}")
        out[section] = {**copy.deepcopy(defaults), **given}
    _check_env(out["env"])
    _check_agent(out["agent"])
    _check_budgets(out)
    return out


def _check_env(env: dict) -> None:
    env_id = env["id"]
    if not isinstance(env_id, str) or not env_id:
        raise RecipeError(f"env.id must be an env id such as 'SMPL/Imitation-v0', got {env_id!r}")
    if env_id.startswith("SMPL/"):
        import smpl_envs

        if env_id not in smpl_envs.ENV_IDS:
            raise RecipeError(f"env.id {env_id!r} is not an smpl_envs task; tasks: {', '.join(smpl_envs.ENV_IDS)}")
    elif ":" not in env_id:  # "module:Id" ids register on import, when the env is made
        import gymnasium as gym

        if env_id not in gym.registry:
            raise RecipeError(f"env.id {env_id!r} is not a registered Gymnasium id")
    _positive_int(env, "env", "num_envs")
    if env["kwargs"] is None:
        env["kwargs"] = {}
    if not isinstance(env["kwargs"], dict):
        raise RecipeError(f"env.kwargs must be a mapping of gym.make keyword arguments, got {env['kwargs']!r}")
    if "num_envs" in env["kwargs"]:
        raise RecipeError("env.kwargs.num_envs: set the number of worlds with env.num_envs")


def _check_agent(agent: dict) -> None:
    name = agent["class"]
    if name not in AGENTS:
        raise RecipeError(f"agent.class must be one of {', '.join(AGENTS)}, got {name!r}")
    hp = agent["hyperparams"]
    if hp is None:
        hp = agent["hyperparams"] = {}
    if not isinstance(hp, dict):
        raise RecipeError(f"agent.hyperparams must be a mapping, got {hp!r}")
    for key in hp:
        if key in RESERVED_HYPERPARAMS:
            raise RecipeError(f"agent.hyperparams.{key} is not a hyperparameter here: set it with "
                              f"{RESERVED_HYPERPARAMS[key]}")
    agent["policy"] = _check_policy(agent, AGENTS[name])
    _check_init(agent)
    hp = agent["hyperparams"]
    accepted = accepted_hyperparams(AGENTS[name])
    unknown = sorted(set(hp) - accepted)
    if unknown:
        raise RecipeError(f"unknown {name} hyperparameter(s) {[f'agent.hyperparams.{k}' for k in unknown]}; "
                          f"{name} takes {', '.join(sorted(accepted))}")


def _check_policy(agent: dict, agent_class) -> dict:
    """agent.policy as {"class": name, "kwargs": {...}}: the class importable, its arguments
    named in its constructor, checkpoint references found; the actor-critic's former
    hyperparameters moved from agent.hyperparams into its kwargs."""
    spec = agent["policy"]
    if spec is None or isinstance(spec, str):
        spec = {"class": spec}
    if not isinstance(spec, dict):
        raise RecipeError(f"agent.policy must be a mapping with class and kwargs, got {spec!r}")
    extra = sorted(set(spec) - {"class", "kwargs"})
    if extra:
        raise RecipeError(f"unknown key(s) {[f'agent.policy.{k}' for k in extra]}; agent.policy has class and kwargs")
    name = spec.get("class") or class_name(agent_class.default_policy)
    try:
        cls = policy_class(name)
    except PolicyClassError as e:
        raise RecipeError(f"agent.policy.class: {e}") from None
    kwargs = spec.get("kwargs") or {}
    if not isinstance(kwargs, dict):
        raise RecipeError(f"agent.policy.kwargs must be a mapping of {name}'s keyword arguments, got {kwargs!r}")
    agent["hyperparams"], former = split_former_hyperparams(agent["hyperparams"])
    if former:
        if not issubclass(cls, ActorCritic):
            keys = ", ".join(f"agent.hyperparams.{k}" for k in sorted(former))
            raise RecipeError(f"{keys}: arguments of ActorCritic, but agent.policy.class is {name}; give {name}'s "
                              "arguments in agent.policy.kwargs")
        kwargs = {**kwargs, **former}
    params = inspect.signature(cls.__init__).parameters
    if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        accepted = [p for p in list(params)[3:] if params[p].kind is not inspect.Parameter.VAR_POSITIONAL]
        unknown = sorted(set(kwargs) - set(accepted))
        if unknown:
            raise RecipeError(f"unknown {name} argument(s) {[f'agent.policy.kwargs.{k}' for k in unknown]}; "
                              f"{name} takes {', '.join(accepted) or 'none'}")
    _check_checkpoint_references(kwargs, "agent.policy.kwargs")
    return {"class": name, "kwargs": kwargs}


def _check_init(agent: dict) -> None:
    """agent.init: a checkpoint to start the policy from (`agents.warm_start`). Whether it exists
    is asked when the agent is built (a recipe may name a policy that a run will ship later)."""
    from .warm_start import init_spec

    try:
        init_spec(agent["init"])
    except ValueError as e:
        raise RecipeError(str(e)) from None


def _check_checkpoint_references(value: Any, where: str) -> None:
    """Each {checkpoint: NAME_OR_PATH} in `value` names a checkpoint that exists."""
    if isinstance(value, dict):
        if set(value) == {"checkpoint"}:
            try:
                find_checkpoint(value["checkpoint"])
            except RecipeError as e:
                raise RecipeError(f"{where}: {e}") from None
            return
        for k, v in value.items():
            _check_checkpoint_references(v, f"{where}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_checkpoint_references(v, f"{where}[{i}]")


def accepted_hyperparams(cls) -> set[str]:
    """The hyperparameters `cls` takes: the fields of its settings dataclass (`cls.config_class`,
    e.g. `PPOConfig`), or for a class without one the keyword arguments of its constructor,
    following `**kwargs` up to the base classes."""
    import dataclasses  # (kept local: this function is the only user)

    config = getattr(cls, "config_class", None)
    if config is not None:
        return {f.name for f in dataclasses.fields(config)} - set(RESERVED_HYPERPARAMS)
    names: set[str] = set()
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        params = inspect.signature(init).parameters.values()
        names |= {p.name for p in params
                  if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)}
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
            break
    return names - {"self", "env"} - set(RESERVED_HYPERPARAMS)


def _check_budgets(recipe: dict) -> None:
    train, ev, video = recipe["train"], recipe["eval"], recipe["video"]
    _positive_int(train, "train", "total_timesteps")
    _positive_int(train, "train", "log_interval")
    _positive_int(train, "train", "checkpoint_every", allow_zero=True)
    if train["seed"] is not None and not _is_int(train["seed"]):
        raise RecipeError(f"train.seed must be an integer or null, got {train['seed']!r}")
    minutes = train["max_minutes"]
    if minutes is not None and (not isinstance(minutes, (int, float)) or isinstance(minutes, bool) or minutes <= 0):
        raise RecipeError(f"train.max_minutes must be a positive number of minutes or null, got {minutes!r}")
    if not isinstance(train["device"], str):
        raise RecipeError(f"train.device must be a string such as auto, cpu or cuda, got {train['device']!r}")
    _positive_int(ev, "eval", "every", allow_zero=True)
    _positive_int(ev, "eval", "num_envs")
    if ev["options"] is None:
        ev["options"] = {}
    if not isinstance(ev["options"], dict):
        raise RecipeError(f"eval.options must be a mapping of the task's evaluation options, got {ev['options']!r}")
    env_id = recipe["env"]["id"]
    if env_id.startswith("SMPL/"):
        from smpl_envs.evaluation import protocol_for

        try:
            ev["options"] = protocol_for(env_id).check_options(ev["options"])
        except ValueError as e:
            raise RecipeError(f"eval.options: {e}") from None
    if train["curriculum"] is not None:
        from .curriculum import check_curriculum

        try:
            train["curriculum"] = check_curriculum(train["curriculum"])
        except ValueError as e:
            raise RecipeError(f"train.curriculum: {e}") from None
    _positive_int(video, "video", "steps", allow_zero=True)
    if video["fps"] is not None and (not isinstance(video["fps"], (int, float)) or video["fps"] <= 0):
        raise RecipeError(f"video.fps must be a positive number or null, got {video['fps']!r}")


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _positive_int(section: dict, name: str, key: str, allow_zero: bool = False) -> None:
    value = section[key]
    # 1e6 from the command line is a float; accept it when it is a whole number.
    if isinstance(value, float) and value.is_integer():
        value = section[key] = int(value)
    if not _is_int(value) or value < (0 if allow_zero else 1):
        bound = ">= 0" if allow_zero else "> 0"
        raise RecipeError(f"{name}.{key} must be an integer {bound}, got {value!r}")


# ---------------------------------------------------------------------------------------- runs
def make_run_dir(recipe: dict, root: str | os.PathLike = "runs", name: str | None = None, *,
                 resume: bool = False) -> Path:
    """Create `<root>/<recipe_name>-<YYYYmmdd-HHMMSS>` (or `<root>/<name>`) with checkpoints/,
    logs/ and videos/, and write the resolved recipe to its config.yaml.

    An existing non-empty directory is refused unless `resume` (a run continuing where it
    stopped), so a new run never mixes its logs and checkpoints into an old one's.
    """
    root = Path(root)
    if name is None:
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        run = root / f"{recipe.get('recipe_name') or 'run'}-{stamp}"
        suffix = 1
        while run.exists():  # two runs started within the same second
            run = root / f"{recipe.get('recipe_name') or 'run'}-{stamp}-{suffix}"
            suffix += 1
    else:
        run = root / name
    if resume:
        if not run.is_dir():
            raise RecipeError(f"cannot resume {run}: no such run directory")
    else:
        check_run_dir_free(run)
    for sub in RUN_SUBDIRS:
        (run / sub).mkdir(parents=True, exist_ok=True)
    write_config(run, recipe)
    return run


def check_run_dir_free(run: str | os.PathLike) -> None:
    """Refuse `run` as a new run's directory when a live training holds it (naming its process),
    or when it exists and is not empty, with advice that fits what it holds: --resume only helps
    a run that saved a checkpoint. The lock file alone does not count, nor this process's lock."""
    run = Path(run)
    pid = live_run_pid(run)
    if pid is not None and pid != os.getpid():
        raise RecipeError(in_use_message(run, pid))
    if not run.exists() or (run.is_dir() and all(e.name == LOCK_NAME for e in run.iterdir())):
        return
    if run.is_dir() and is_unused_run_dir(run):
        raise RecipeError(f"run directory {run} already exists, holding only the config.yaml of a start that "
                          "never trained; delete it or pass --overwrite")
    raise RecipeError(f"run directory {run} already exists and is not empty; choose another "
                      f"--run-dir or continue it with --resume {run}")


def check_device(device: str, what: str) -> None:
    """Refuse a torch device this machine does not have (`what` names the setting), as a RecipeError."""
    from .on_policy import resolve_device

    try:
        resolve_device(device, name=what)
    except ValueError as e:
        raise RecipeError(str(e)) from None


def check_writable(path: str | os.PathLike, what: str, directory: bool = False) -> None:
    """Refuse an output path the command could not write, before the work that fills it: a file
    path (`directory=False`) that is a directory, a directory path that is a file, or a place
    where no file can be created (the path's nearest existing directory is tried with a temporary
    file, which catches permissions, read-only filesystems and a file where a directory should
    be). `what` names the option in the message (--out, --run-dir)."""
    path = Path(path)
    if path.is_dir() and not directory:
        raise RecipeError(f"{what} {path} is a directory; give a file path inside it")
    if path.exists() and not path.is_dir() and directory:
        raise RecipeError(f"{what} {path} is a file, not a directory")
    if path.is_file() and not os.access(path, os.W_OK):
        raise RecipeError(f"{what} {path}: the file exists and is read-only")
    place = path if path.is_dir() else path.parent
    while not place.exists() and place != place.parent:  # try where it would be created
        place = place.parent
    if not place.is_dir():
        raise RecipeError(f"{what} {path}: {place} is a file, not a directory")
    try:
        with tempfile.TemporaryFile(dir=place):
            pass
    except OSError as e:
        raise RecipeError(f"{what} {path}: cannot create files in {place} ({e.strerror or e})") from None


def is_unused_run_dir(run: str | os.PathLike) -> bool:
    """True for a directory holding nothing but config.yaml and the run subdirectories without
    any file in them: what a start that failed before training leaves, nothing worth keeping."""
    run = Path(run)
    if not run.is_dir():
        return False
    for entry in run.iterdir():
        if entry.name in (CONFIG_NAME, LOCK_NAME) and entry.is_file():
            continue
        if entry.name in RUN_SUBDIRS and entry.is_dir() and not any(p.is_file() for p in entry.rglob("*")):
            continue
        return False
    return True


class RunLock:
    """One training at a time in a run directory: an exclusive `flock` on RUN/.lock, which holds
    the owner's process id. The kernel drops the lock when its process ends, however it ends
    (Ctrl-C, SIGKILL, a crash, a reboot), so it is never left stale; the file stays behind,
    harmless, since only a held lock counts. Without `fcntl` (Windows) nothing is locked."""

    def __init__(self, run: str | os.PathLike):
        self.run = Path(run)
        self.path = self.run / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> "RunLock":
        """Take the lock (creating the directory); RecipeError names the process of a live run
        that holds it."""
        if self.run.exists() and not self.run.is_dir():
            raise RecipeError(f"run directory {self.run} is a file, not a directory")
        self.run.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise RecipeError(in_use_message(self.run, live_run_pid(self.run))) from None
        # Written only once the lock is held: a process that failed to take it must not
        # overwrite the owner's id.
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing drops the flock
            self._fd = None

    def __enter__(self) -> "RunLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def live_run_pid(run: str | os.PathLike) -> int | None:
    """The process id of the live training that holds `run`'s lock (0 when it has not written its
    id yet), or None when no live training holds it."""
    path = Path(run) / LOCK_NAME
    if fcntl is None or not path.is_file():
        return None
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:  # removed meanwhile (an --overwrite): nobody holds it
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            text = os.pread(fd, 32, 0).decode(errors="replace").strip()
            return int(text) if text.isdigit() else 0
        return None  # the lock was free: its run has ended
    finally:
        os.close(fd)  # also drops the shared lock just taken


def in_use_message(run: Path, pid: int | None) -> str:
    who = f"process {pid}" if pid else "a process that has not written its id yet"
    return (f"run directory {run} is in use by a live training ({who}); two trainings never write into one "
            "run directory: wait for that one to end or stop it")


def write_config(run: str | os.PathLike, recipe: dict) -> Path:
    path = Path(run) / CONFIG_NAME
    path.write_text(yaml.safe_dump(recipe, sort_keys=False, default_flow_style=None))
    return path


def read_config(run: str | os.PathLike) -> dict:
    """The resolved recipe a run was made with (its config.yaml)."""
    path = Path(run) / CONFIG_NAME
    if not path.is_file():
        raise RecipeError(f"{run} is not a run directory: it has no {CONFIG_NAME}")
    recipe = yaml.safe_load(path.read_text())
    if not isinstance(recipe, dict):
        raise RecipeError(f"{path} does not hold a recipe")
    return recipe


def find_checkpoint(run_or_ckpt: str | os.PathLike, which: str = "best") -> Path:
    """The checkpoint to use for `run_or_ckpt`: a .pt file as is; for a run directory (or its
    checkpoints/ directory) best.pt when `which` is "best" and it exists, else last.pt, else the
    newest ckpt_*.pt."""
    if which not in ("best", "last"):
        raise RecipeError(f"which must be 'best' or 'last', got {which!r}")
    path = Path(run_or_ckpt)
    if path.is_file():
        return path
    if not path.is_dir():
        shipped = pretrained_checkpoints()
        if str(run_or_ckpt) in shipped:
            return shipped[str(run_or_ckpt)]
        raise RecipeError(f"no checkpoint or run directory at {path}; shipped policies: "
                          f"{', '.join(shipped) or 'none'}")
    directory = path / "checkpoints" if (path / "checkpoints").is_dir() else path
    candidates = ([directory / "best.pt"] if which == "best" else []) + [directory / "last.pt"]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    # Numbered checkpoints carry zero-padded step counts, so name order is step order.
    numbered = sorted(directory.glob("ckpt_*.pt"))
    if numbered:
        return numbered[-1]
    raise RecipeError(f"no checkpoint in {directory} (looked for best.pt, last.pt and ckpt_*.pt)")


PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"


def pretrained_checkpoints() -> dict[str, Path]:
    """{name: path} of the policies shipped in the package (agents/pretrained/<name>.pt), which
    `smpl-envs eval NAME` and `smpl-envs record NAME` find by name when no such path exists."""
    return {p.stem: p for p in sorted(PRETRAINED_DIR.glob("*.pt"))}


def run_dir_of(checkpoint: str | os.PathLike) -> Path | None:
    """The run directory a checkpoint lies in (<run>/checkpoints/x.pt), or None."""
    checkpoint = Path(checkpoint)
    parent = checkpoint.parent
    if parent.name == "checkpoints" and (parent.parent / CONFIG_NAME).is_file():
        return parent.parent
    return None


__all__ = ["RecipeError", "load_recipe", "apply_overrides", "validate_recipe", "parse_override", "parse_value",
           "set_dotted", "make_run_dir", "check_run_dir_free", "is_unused_run_dir", "RunLock", "live_run_pid",
           "read_config", "write_config",
           "find_checkpoint", "run_dir_of",
           "available_recipes", "recipe_dirs", "shipped_recipe_dir", "recipe_description", "resolve_recipe_path", "accepted_hyperparams", "pretrained_checkpoints"]
