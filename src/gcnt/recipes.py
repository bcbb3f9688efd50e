"""Recipes: typed, validated training configurations read from YAML, with dotted overrides.

A recipe has sections in the spirit of TorchRL's sota-implementations (env / collector /
replay_buffer / optim / network / logger / eval). Every field is declared here with its default and
a comment; a YAML key that is not declared is an error that names it and suggests the closest key.

    recipe = load_recipe("recipes/smpenv/walker.yaml", ["network.name=swat", "seed=2"])
"""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml


class RecipeError(ValueError):
    """A recipe that cannot be used; the message names the file and the key."""


@dataclass
class EnvConfig:
    #: robots to train on: names (walker_7_main), robot files (path/to.xml) or Benchmark:split
    robots: list[str] = field(default_factory=lambda: ["Walker++:train"])
    #: zero-shot robots (evaluated, never trained on); same syntax as ``robots``
    test_robots: list[str] = field(default_factory=list)
    #: copies of each training robot stepped in parallel (more data per lockstep step)
    copies: int = 1
    #: pad limbs to this many (default: the largest robot); also caps what eval can load
    max_limbs: int | None = None
    #: episode length; the end is a truncation (bootstrapped), not a termination
    max_episode_steps: int = 1000
    #: physics threads (default: all cores)
    num_threads: int | None = None


@dataclass
class CollectorConfig:
    #: environment steps to train for, counted over all robots (every stored transition counts)
    total_frames: int = 10_000_000
    #: first steps with uniform random actions in [-1, 1] (counted over all robots)
    init_random_frames: int = 10_000
    #: "paper": lockstep until every robot has finished an episode, then per-robot updates from
    #: its own buffer, as many as its transitions. "mixed": every ``steps_per_batch`` lockstep
    #: steps, updates on padded batches that mix all robots (batch_size samples of each robot)
    schedule: Literal["paper", "mixed"] = "paper"
    #: lockstep steps between update phases in the "mixed" schedule
    steps_per_batch: int = 50
    #: std of the Gaussian exploration noise added to the actor's actions
    exploration_noise: float = 0.126


@dataclass
class ReplayBufferConfig:
    #: transitions kept per robot (the paper: 500k) ...
    size_per_robot: int = 500_000
    #: ... and over all robots (the paper: 4M): each robot gets min(size_per_robot, total/robots)
    total_size: int = 4_000_000
    #: mini-batch size (per robot, also in the mixed schedule)
    batch_size: int = 100


@dataclass
class OptimConfig:
    #: Adam learning rate of actor and critic
    lr: float = 1e-4
    gamma: float = 0.99
    #: soft target update rate (target = (1 - tau) target + tau online)
    tau: float = 0.046
    #: critic updates per actor (and target) update
    policy_delay: int = 2
    #: target-policy smoothing noise std and clip
    policy_noise: float = 0.2
    noise_clip: float = 0.5
    #: gradient-norm clip of actor and critic (<= 0: off)
    max_grad_norm: float = 0.1
    #: critic updates per stored environment step (the paper: 1)
    updates_per_step: float = 1.0


@dataclass
class NetworkConfig:
    #: gcnt | amorpheus | swat | smp | mlp (ablations: gcnt_no_gcn, gcnt_no_wl, gcnt_no_dist)
    name: str = "gcnt"
    #: size preset: smpenv (paper appendix table 1) or unimal (table 3)
    preset: str = "smpenv"
    #: keyword overrides of the preset (e.g. d_model: 64); validated by the network builder
    kwargs: dict[str, Any] = field(default_factory=dict)


@dataclass
class LoggerConfig:
    #: wandb (offline by default) | csv | none; metrics.jsonl in the run directory always
    backend: Literal["wandb", "csv", "none"] = "wandb"
    #: wandb mode: offline needs no network; sync later with `wandb sync`
    mode: Literal["offline", "online"] = "offline"
    #: default project/group/name are derived from benchmark, method and seed
    project: str | None = None
    group: str | None = None
    name: str | None = None
    #: environment steps between log lines
    log_interval: int = 5_000
    #: terminal progress bar
    progress: bool = True


@dataclass
class EvalConfig:
    #: environment steps between evaluations (0: only at the end)
    interval: int = 0
    #: deterministic episodes per robot
    episodes: int = 10
    #: robots to evaluate (default: the recipe's train and test robots)
    robots: list[str] = field(default_factory=list)
    #: render a video of the first robot at each evaluation
    video: bool = False


@dataclass
class Recipe:
    #: name used for run names and W&B project/group (e.g. Walker++)
    benchmark: str = "custom"
    seed: int = 0
    #: cpu | cuda | cuda:N
    device: str = "cpu"
    #: run directory (default: runs/<benchmark>/<network>/seed<seed>)
    run_dir: str | None = None
    #: environment steps between checkpoints
    checkpoint_interval: int = 100_000
    #: also checkpoint the replay buffers (large; makes resume exact)
    checkpoint_buffers: bool = False
    env: EnvConfig = field(default_factory=EnvConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    replay_buffer: ReplayBufferConfig = field(default_factory=ReplayBufferConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# ----------------------------------------------------------------------------- validation


def _check_type(value: Any, tp: Any, where: str) -> Any:
    """Check (and lightly coerce: int -> float) ``value`` against the annotation ``tp``."""
    origin = typing.get_origin(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        errors = []
        for arm in typing.get_args(tp):
            if arm is type(None):
                if value is None:
                    return None
                continue
            try:
                return _check_type(value, arm, where)
            except RecipeError as e:
                errors.append(str(e))
        raise RecipeError(errors[0] if errors else f"{where}: expected {tp}, got {value!r}")
    if origin is Literal:
        if value not in typing.get_args(tp):
            choices = ", ".join(map(repr, typing.get_args(tp)))
            raise RecipeError(f"{where}: {value!r} is not one of {choices}")
        return value
    if origin is list:
        if not isinstance(value, list):
            value = [value] if isinstance(value, str) else value
        if not isinstance(value, list):
            raise RecipeError(f"{where}: expected a list, got {value!r}")
        (arm,) = typing.get_args(tp)
        return [_check_type(v, arm, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise RecipeError(f"{where}: expected a mapping, got {value!r}")
        return dict(value)
    if tp is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if tp in (float, int) and isinstance(value, str):
        # YAML 1.1 reads "3e-4" (no dot) as a string; accept plain numeric literals.
        try:
            return tp(float(value)) if tp is float else int(value)
        except ValueError:
            pass
    if tp is int and isinstance(value, bool) or not isinstance(value, tp):
        raise RecipeError(f"{where}: expected {tp.__name__}, got {type(value).__name__} {value!r}")
    return value


def _build(cls: type, data: dict[str, Any], where: str) -> Any:
    if not isinstance(data, dict):
        raise RecipeError(f"{where or 'recipe'}: expected a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else str(key)
        if key not in names:
            close = difflib.get_close_matches(str(key), names, n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else f"; known keys: {', '.join(names)}"
            raise RecipeError(f"unknown recipe key {path!r}{hint}")
        tp = hints[key]
        if dataclasses.is_dataclass(tp):
            kwargs[key] = _build(tp, value or {}, path)
        else:
            kwargs[key] = _check_type(value, tp, path)
    return cls(**kwargs)


def _apply_override(data: dict[str, Any], override: str) -> None:
    if "=" not in override:
        raise RecipeError(f"override {override!r} must look like section.key=value")
    key, raw = override.split("=", 1)
    value = yaml.safe_load(raw) if raw != "" else ""
    parts = key.strip().split(".")
    node = data
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise RecipeError(f"override {override!r}: {p!r} is not a section")
    node[parts[-1]] = value


def recipe_from_dict(
    data: dict[str, Any], overrides: list[str] | None = None, source: str = "<dict>"
) -> Recipe:
    data = yaml.safe_load(yaml.safe_dump(data or {}))  # deep copy, plain types
    try:
        for o in overrides or []:
            _apply_override(data, o)
        return _build(Recipe, data, "")
    except RecipeError as e:
        raise RecipeError(f"{source}: {e}") from None


def _merge(base: dict[str, Any], top: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in top.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _read_yaml(path: Path, chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """A recipe file's mapping, with ``base: other.yaml`` (relative to the file) merged under it."""
    if path.resolve() in chain:
        raise RecipeError(f"{path}: recipe bases form a cycle: {' -> '.join(map(str, chain))}")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except OSError as e:
        raise RecipeError(f"{path}: cannot read recipe ({e.strerror})") from e
    except yaml.YAMLError as e:
        raise RecipeError(f"{path}: not valid YAML ({e})") from e
    if not isinstance(data, dict):
        raise RecipeError(f"{path}: a recipe must be a mapping of sections")
    base = data.pop("base", None)
    if base is None:
        return data
    return _merge(_read_yaml(path.parent / base, (*chain, path.resolve())), data)


def load_recipe(path: str | Path, overrides: list[str] | None = None) -> Recipe:
    """Load a recipe file, apply ``section.key=value`` overrides, validate everything.

    A recipe may start from another with ``base: relative/path.yaml``; its keys override the
    base's, section by section.
    """
    path = Path(path)
    return recipe_from_dict(_read_yaml(path), overrides, source=str(path))


def save_recipe(recipe: Recipe, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(recipe.to_dict(), sort_keys=False))
