"""Recipes: typed, validated training configurations read from YAML, with dotted overrides.

A recipe has sections in the spirit of TorchRL's sota-implementations (env / collector /
replay_buffer / optim / network / logger / eval). Every field is declared here with its default and
a comment; a YAML key that is not declared is an error that names it and suggests the closest key.

    recipe = load_recipe("recipes/smpenv/walker.yaml", ["network.name=swat", "seed=2"])
"""

from __future__ import annotations

import copy
import dataclasses
import importlib
import logging
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal

import yaml

from gcnt.files import CappedLoader, parse_yaml, write_text
from gcnt.suggest import KEY_ALIASES, did_you_mean

log = logging.getLogger(__name__)


class RecipeError(ValueError):
    """A recipe that cannot be used; the message names the file and the key."""


@dataclass
class EnvConfig:
    #: the benchmark whose env and robot catalogue to use: smpenv | unimal (``gcnt robots``)
    benchmark: str = "smpenv"
    #: the benchmark's world (UNIMAL: ft | incline | mt | obstacles); unset: its default
    world: str | None = None
    #: robots to train on: names (walker_7_main), robot files or folders, or Benchmark:split.
    #: No default: a recipe that names no robots cannot train
    robots: list[str] = field(default_factory=list)
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


@dataclass
class NetworkConfig:
    #: the method: gcnt | amorpheus | swat | smp | mlp | ... (``gcnt params`` lists them;
    #: ablations gcnt_no_gcn, gcnt_no_wl, gcnt_no_dist, gcnt_dist_first, gcnt_gcn_context)
    name: str = "gcnt"
    #: size preset: smpenv (paper appendix table 1) or unimal (table 3); unset: the benchmark's
    preset: str | None = None
    #: keyword overrides of the preset (e.g. d_model: 64), for every method whose config has
    #: these fields; a method whose config has none of them (another family: SMP, an MLP, a
    #: plugin method with a config of its own) runs at its preset's sizes. Validated by the
    #: network builder
    kwargs: dict[str, Any] = field(default_factory=dict)
    #: per-method overrides that replace ``kwargs`` when that method is chosen (e.g.
    #: ``{smp: {msg_dim: 16}}`` in a recipe whose ``kwargs`` shrink the Transformers), so that a
    #: shrunk recipe runs every method: ``network.name=smp`` then uses these
    method_kwargs: dict[str, dict[str, Any]] = field(default_factory=dict)

    def sizes(self) -> dict[str, Any]:
        """The overrides of the chosen method: ``method_kwargs[name]`` if set, else what
        ``kwargs`` give it (:func:`gcnt.nn.registry.shared_sizes`)."""
        if self.name in self.method_kwargs:
            return dict(self.method_kwargs[self.name])
        from gcnt.nn.registry import shared_sizes

        return shared_sizes(self.name, self.kwargs)


@dataclass
class LoggerConfig:
    #: wandb (offline by default: seconds per run, docs/runs.md) | csv | none; metrics.jsonl in
    #: the run directory always
    backend: Literal["wandb", "csv", "none"] = "wandb"
    #: wandb mode: offline needs no network; sync later with `wandb sync`
    mode: Literal["offline", "online"] = "offline"
    #: default project/group/name are derived from task, algorithm, method and seed
    project: str | None = None
    group: str | None = None
    name: str | None = None
    #: W&B tags besides ``seed:N``, which every run gets (a sweep adds ``sweep:NAME``)
    tags: list[str] = field(default_factory=list)
    #: environment steps between log lines
    log_interval: int = 5_000
    #: terminal progress bar
    progress: bool = True


@dataclass
class EvalConfig:
    #: environment steps between evaluations (0: only at the end)
    interval: int = 0
    #: episodes per robot
    episodes: int = 10
    #: robots to evaluate (default: the recipe's train and test robots)
    robots: list[str] = field(default_factory=list)
    #: the policy's mean action (True) or sampled actions (False: ModuMorph's PPO protocol)
    deterministic: bool = True
    #: render a video at each evaluation: every training robot side by side (up to 16)
    video: bool = False


@dataclass
class CompileConfig:
    """Speed switches of the learner and the collector, shared by every algorithm (the names of
    torchrl's sota-implementations). Off by default, but ``compile`` and ``matmul_precision``,
    which are ``auto``: on a CPU torch.compile takes minutes to compile small networks, repaid
    only by a long enough run, and oneDNN's float32 products round to bfloat16 on some CPUs
    (docs/performance.md); the CUDA switches need CUDA."""

    #: torch.compile the learner's loss forwards, each as one graph (TD3: the critic loss and
    #: the actor loss, the optimiser tail eager; PPO: the loss forward), their backward through
    #: AOTAutograd. auto (default): TD3 on a CPU compiles when the run plans more updates than
    #: compiling repays (gcnt.rl.td3.learner.choose_compile, logged); eager otherwise, and for
    #: algorithms without such a rule (PPO)
    compile: bool | Literal["auto"] = "auto"
    #: torch.compile mode: default | reduce-overhead | max-autotune (unset: default)
    mode: str | None = None
    #: capture each update step in a CUDA graph (tensordict.nn.CudaGraphModule); CUDA and TD3
    #: only (PPO's KL early stop decides between forward and optimiser step)
    cudagraphs: bool = False
    #: bfloat16 autocast in the update steps; CUDA only
    amp: bool = False
    #: keep the replay storage on the learner's device instead of CPU memory; CUDA only (PPO's
    #: iteration buffer, GAE and update are always on the recipe's device)
    replay_on_device: bool = False
    #: torch.compile the collector's policy
    policy_compile: bool = False
    #: capture the collector's policy in a CUDA graph; CUDA only
    policy_cudagraphs: bool = False
    #: eager calls before a step is captured in a CUDA graph
    warmup: int = 2
    #: where torch.compile caches compiled code; null: $TORCHINDUCTOR_CACHE_DIR if set, else
    #: $XDG_CACHE_HOME/gcnt/inductor (~/.cache/gcnt/inductor), never the shared /tmp. A run's
    #: recorded cache_dir is not used when it is resumed or loaded (the cache holds code torch
    #: runs): give it again on the command line (compile.cache_dir=...)
    cache_dir: str | None = None
    #: torch's intra-op (OpenMP) threads for the run; null (default): torch's own, one per core.
    #: On a machine shared with other jobs, 1 keeps every small kernel from waiting for a thread
    #: another job has taken (PPO's quick start ran 3.7x faster end to end on 1 than on 2 beside
    #: a busy loop on 2 cores, and 1.08x slower on 1 when idle)
    torch_threads: int | None = None
    #: TD3: run the two critics (and the two target critics) of each update at once on two
    #: threads, with torch's intra-op threads set to 1 for the process; null (default): on when
    #: the update runs eagerly on a CPU with 2 to 4 usable cores, without dropout, and
    #: torch_threads is unset or 1
    twin_threads: bool | None = None
    #: TD3: where the twin critics run at once (twin_threads, on or automatic), run them in two
    #: processes instead of two threads: the second critic, the second target critic and half of
    #: the target actor's and the actor's batch in a helper process on shared-memory weights
    #: (two threads share one interpreter lock, which every small operator holds; two processes
    #: do not). CPU only; a compiled or graphed update runs its critics in one call instead
    twin_processes: bool = False

    #: float32 matrix products (``torch.set_float32_matmul_precision``, set for the run and
    #: recorded in ``resolved``): highest | high | medium, or auto (default): on a CPU, medium
    #: (oneDNN's products) where a probe finds it keeps float32's accuracy, highest where it
    #: rounds to bfloat16 (CPUs with AMX or AVX512-BF16); elsewhere highest
    matmul_precision: Literal["auto", "highest", "high", "medium"] = "auto"

    #: switches that need a CUDA device
    CUDA_ONLY = ("cudagraphs", "amp", "replay_on_device", "policy_cudagraphs")
    #: what a recorded run whose compile section lacks a key ran with (the key's default changed)
    BEFORE_KEY: ClassVar[dict[str, Any]] = {"compile": False, "matmul_precision": "highest"}

    def check(self) -> None:
        if self.torch_threads is not None and self.torch_threads < 1:
            raise ValueError(f"torch_threads must be >= 1, got {self.torch_threads}")
        if self.twin_threads and (self.torch_threads or 1) > 1:
            raise ValueError(
                f"twin_threads=true runs torch on 1 intra-op thread, but torch_threads is "
                f"{self.torch_threads}; drop one of the two"
            )
        if self.twin_threads and (self.compile is True or self.cudagraphs):
            raise ValueError(
                "twin_threads=true runs the critics on two Python threads, which a compiled or "
                "CUDA-graphed step cannot hold; set compile.twin_threads=false"
            )
        if self.warmup < 1:
            raise ValueError(f"warmup must be >= 1, got {self.warmup}")
        modes = (None, "default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")
        if self.mode not in modes:
            raise ValueError(
                f"mode must be one of {', '.join(map(str, modes[1:]))}, got {self.mode!r}"
            )


#: algorithm name -> its recipe section (a dataclass); see :func:`register_algorithm_section`
ALGORITHM_SECTIONS: dict[str, type] = {}
#: built-in sections, imported when first needed
_BUILTIN_SECTIONS: dict[str, str] = {
    "td3": "gcnt.rl.td3.config:TD3Config",
    "ppo": "gcnt.rl.ppo.config:PPOConfig",
}


def register_algorithm_section(name: str, section: type, *, replace: bool = False) -> None:
    """Declare the recipe section of algorithm ``name`` (a dataclass, validated like the others
    when ``algo: name``; the sections of other algorithms are kept but not validated)."""
    if not dataclasses.is_dataclass(section):
        raise TypeError(f"the recipe section of {name!r} must be a dataclass, got {section!r}")
    if name in _BUILTIN_SECTIONS and name not in ALGORITHM_SECTIONS:
        algorithm_section(name)
    if name in _BUILTIN_SECTIONS and ALGORITHM_SECTIONS[name] is not section:
        raise ValueError(
            f"algorithm {name!r} is built into gcnt; its recipe section cannot be replaced"
        )
    if name in ALGORITHM_SECTIONS and not replace and ALGORITHM_SECTIONS[name] is not section:
        raise ValueError(f"algorithm {name!r} already has a recipe section")
    ALGORITHM_SECTIONS[name] = section


def algorithm_names() -> list[str]:
    return sorted({*ALGORITHM_SECTIONS, *_BUILTIN_SECTIONS})


def algorithm_section(name: str) -> type:
    """The recipe section dataclass of algorithm ``name``."""
    if name not in ALGORITHM_SECTIONS and name in _BUILTIN_SECTIONS:
        module, attr = _BUILTIN_SECTIONS[name].split(":")
        ALGORITHM_SECTIONS[name] = getattr(importlib.import_module(module), attr)
    if name not in ALGORITHM_SECTIONS:
        raise RecipeError(
            f"algo: unknown algorithm {name!r}{did_you_mean(name, algorithm_names())} "
            f"(known: {', '.join(algorithm_names())})"
        )
    return ALGORITHM_SECTIONS[name]


@dataclass
class Recipe:
    #: the experiment's label, used in run names and W&B project/group (e.g. Walker++); runs of
    #: the same task are drawn in the same panel by ``gcnt curves``
    task: str = "custom"
    #: the name the runs are shown under in curves and tables, and the method part of sweep run
    #: ids (e.g. SR-fair, SR-top: two recipes of the same network told apart); unset: the
    #: network's name
    label: str | None = None
    #: the learning algorithm: td3 | ppo; its settings are in the section of the same name
    algo: str = "td3"
    seed: int = 0
    #: cpu | cuda | cuda:N
    device: str = "cpu"
    #: your own modules (``my_pkg.methods``) or .py files (relative to the recipe file),
    #: imported before a recipe file given to ``gcnt train`` or ``gcnt sweep`` is read: the
    #: methods, benchmarks and algorithms they register can be named here (:mod:`gcnt.plugins`).
    #: A run records its plugins by identity (``resolved.plugins``; here, files by their name
    #: alone) and never imports them; its recipe read back lists the plugins of the command
    #: reading it
    plugins: list[str] = field(default_factory=list)
    #: run directory (default: runs/<task>/<algo>-<network>/seed<seed>)
    run_dir: str | None = None
    #: a trained run directory to start from (fine-tuning): its networks' weights and, for PPO,
    #: observation statistics; fresh optimisers, replay and counters (``gcnt.rl.init_from``).
    #: Same algorithm, benchmark and network sizes; unset: networks from scratch
    init_from: str | None = None
    #: environment steps between checkpoints
    checkpoint_interval: int = 100_000
    env: EnvConfig = field(default_factory=EnvConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    #: learner/collector speed switches (torch.compile, CUDA graphs, bf16), off by default
    compile: CompileConfig = field(default_factory=CompileConfig)
    #: the algorithm sections: the active one validated (a dataclass), others as written
    sections: dict[str, Any] = field(default_factory=dict)
    #: sizes the run derived from the recipe (written by the run into its recipe.yaml; read-only)
    resolved: dict[str, Any] = field(default_factory=dict)

    @property
    def algo_config(self) -> Any:
        """The validated section of the active algorithm (``recipe.td3`` when ``algo: td3``)."""
        section = self.sections.get(self.algo)
        if section is None or isinstance(section, dict):
            section = _build(algorithm_section(self.algo), section or {}, self.algo)
            self.sections[self.algo] = section
        return section

    def __setstate__(self, state: dict[str, Any]) -> None:
        # a recipe sent to another process (a collector's worker) imports its plugins there
        self.__dict__.update(state)
        if state.get("plugins"):
            from gcnt import plugins

            plugins.load(state["plugins"], via="the recipe")

    def __getattr__(self, name: str) -> Any:
        # recipe.td3 / recipe.ppo: the algorithm's section
        if name != "sections" and name in self.__dict__.get("sections", {}):
            if name == self.__dict__.get("algo"):
                return self.algo_config
            return self.__dict__["sections"][name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def check(self) -> None:
        """Values and relations that cannot make a run (checked when the recipe is loaded)."""
        if self.collector.total_frames < 1:
            raise ValueError(
                f"collector.total_frames must be >= 1, got {self.collector.total_frames}"
            )
        if self.env.copies < 1:
            raise ValueError(f"env.copies must be >= 1, got {self.env.copies}")
        if self.env.max_episode_steps < 1:
            raise ValueError(
                f"env.max_episode_steps must be >= 1, got {self.env.max_episode_steps}"
            )
        if self.env.max_limbs is not None and self.env.max_limbs < 1:
            raise ValueError(f"env.max_limbs must be >= 1, got {self.env.max_limbs}")
        if self.env.num_threads is not None and self.env.num_threads < 1:
            raise ValueError(f"env.num_threads must be >= 1, got {self.env.num_threads}")
        if self.checkpoint_interval < 1:
            raise ValueError(f"checkpoint_interval must be >= 1, got {self.checkpoint_interval}")
        if self.logger.log_interval < 1:
            raise ValueError(f"logger.log_interval must be >= 1, got {self.logger.log_interval}")
        if self.eval.episodes < 0 or self.eval.interval < 0:
            raise ValueError("eval.episodes and eval.interval must be >= 0")
        _check_device(self.device)
        if self.label is not None and not self.label.strip():
            raise ValueError("label must not be empty (leave it out to show the network's name)")
        self._check_single_robot_network()
        # relations between the active algorithm's settings and the shared ones
        relations = getattr(self.sections.get(self.algo), "check_recipe", None)
        if callable(relations):
            relations(self)
        if not self.device.startswith("cuda"):
            for key in CompileConfig.CUDA_ONLY:
                if getattr(self.compile, key):
                    raise ValueError(
                        f"compile.{key}=true needs a CUDA device; this recipe has "
                        f"device={self.device!r}"
                    )

    def _check_single_robot_network(self) -> None:
        """SR's flat MLP is one network per robot: refuse it on several robots (it would train
        one shared MLP over padded inputs). Recipes written by a run (``resolved`` set) are what
        was trained, and stay readable."""
        name = self.network.name
        if name not in SINGLE_ROBOT_NETWORKS or self.resolved or not self.env.robots:
            return
        n = count_robots(self.env.robots)
        if n > 1:
            raise ValueError(
                f"network {name!r} is one MLP per robot, but env.robots names {n} robots; train "
                f"one run per robot with `gcnt sweep RECIPE --per-robot SPLIT` (e.g. --per-robot "
                f"{_split_hint(self.env.robots)}), or set env.robots to one robot"
            )

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "sections":
                for algo, section in value.items():
                    out[algo] = (
                        dataclasses.asdict(section)
                        if dataclasses.is_dataclass(section)
                        else section
                    )
            elif f.name == "resolved":
                if value:
                    out[f.name] = dict(value)
            elif f.name == "plugins":  # written and logged: no folder of this machine
                from gcnt import plugins

                out[f.name] = plugins.shared_names(value)
            else:
                out[f.name] = (
                    dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value
                )
        return out


# ----------------------------------------------------------------------------- validation

#: networks that are one model per robot (a flat MLP over one robot's padded limbs: paper SR)
SINGLE_ROBOT_NETWORKS = ("sr", "mlp")


def run_robot_specs(recipe: Recipe) -> list[str]:
    """Every robot spec of the run: ``env.robots``, ``env.test_robots`` and ``eval.robots``.
    Robot names are chosen among all of them (``resolve_robots(..., names_from=...)``), so a
    robot file has one name in the run's training metrics, evaluations and analysis."""
    return [*recipe.env.robots, *recipe.env.test_robots, *recipe.eval.robots]


def count_robots(specs: list[str]) -> int:
    """How many robots ``specs`` name, resolved as the run resolves them (a bad spec counts as
    one robot: training reports it)."""
    from gcnt.morphology import resolve_robots

    try:
        return len(resolve_robots(list(specs)))
    except Exception:  # noqa: BLE001 - an unknown robot or file: the run names it
        return len(specs)


def _split_hint(specs: list[str]) -> str:
    return ",".join(specs) if len(specs) > 1 else specs[0]


def _check_device(device: str) -> None:
    if device == "cpu":
        return
    if not (device == "cuda" or device.startswith("cuda:")):
        raise ValueError(f"device must be cpu, cuda or cuda:N, got {device!r}")
    import torch  # only for a GPU recipe

    if not torch.cuda.is_available():
        raise ValueError(f"device={device!r} but no CUDA GPU is available here; use device=cpu")
    index = int(device.split(":")[1]) if ":" in device else 0
    if index >= torch.cuda.device_count():
        raise ValueError(
            f"device={device!r} but this machine has {torch.cuda.device_count()} CUDA device(s)"
        )


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
    names = [f.name for f in dataclasses.fields(cls) if f.name not in _INTERNAL]
    is_recipe = cls is Recipe
    if is_recipe:
        algo = data.get("algo", "td3")
        if not isinstance(algo, str):
            raise RecipeError(f"algo: expected an algorithm name, got {algo!r}")
        algorithm_section(algo)  # an unknown algorithm is an error naming the known ones
        known = [*names, *algorithm_names()]
    else:
        known = names
    kwargs: dict[str, Any] = {}
    sections: dict[str, Any] = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else str(key)
        if is_recipe and key in algorithm_names() and key not in names:
            # only the active algorithm's section is validated; the others are kept as written
            sections[key] = (
                _build(algorithm_section(key), value or {}, path) if key == algo else value
            )
            continue
        if key not in names:
            hint = did_you_mean(str(key), known, aliases=KEY_ALIASES) or (
                f"; known keys: {', '.join(known)}"
            )
            raise RecipeError(f"unknown recipe key {path!r}{hint}")
        tp = hints[key]
        if dataclasses.is_dataclass(tp):
            kwargs[key] = _build(tp, value or {}, path)
        else:
            kwargs[key] = _check_type(value, tp, path)
    if is_recipe:
        if algo not in sections:
            sections[algo] = _build(algorithm_section(algo), {}, algo)
        kwargs["sections"] = sections
    obj = cls(**kwargs)
    check = getattr(obj, "check", None)
    if callable(check):
        try:
            check()
        except ValueError as e:
            raise RecipeError(f"{where + ': ' if where else ''}{e}") from None
    return obj


def import_recipe_plugins(data: dict[str, Any], source: str) -> dict[str, Any]:
    """Import the plugins a recipe file given to this command names (its ``plugins:`` key: the
    methods, benchmarks and algorithms they register can then be named), as this command's own
    (:func:`gcnt.plugins.add_to_session`); ``data`` with them normalized. Only a recipe the
    user gives is read for plugins: a run's or a sweep's recorded recipe never is."""
    from gcnt import plugins

    own = _check_type(data.get("plugins", []), list[str], "plugins")
    if not own:
        return data
    try:
        names = plugins.load(own, via="the recipe key plugins")
    except plugins.PluginError as e:
        raise RecipeError(f"{source}: {e}") from None
    plugins.add_to_session(names)
    return {**data, "plugins": names}


#: Recipe fields that are not written as keys of their own
_INTERNAL = ("sections",)


def _apply_override(data: dict[str, Any], override: str) -> None:
    if "=" not in override:
        raise RecipeError(f"override {override!r} must look like section.key=value")
    key, raw = override.split("=", 1)
    try:
        value = yaml.load(raw, Loader=RecipeLoader) if raw != "" else ""
    except yaml.YAMLError as e:
        raise RecipeError(
            f"override {override!r}: the value is not valid YAML ({_yaml_problem(e)})"
        ) from None
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


#: the largest recipe file read (a recipe is a few kilobytes)
MAX_RECIPE_BYTES = 1 << 20


class RecipeLoader(CappedLoader):
    """The loader of recipes and overrides: :class:`gcnt.files.CappedLoader` (anchors and
    aliases allowed, an alias bomb refused as soon as it is composed)."""


def _recipe_keys() -> set[str]:
    """The keys a recipe file's top level may hold."""
    return {f.name for f in dataclasses.fields(Recipe)} - set(_INTERNAL) | {
        *algorithm_names(),
        "base",
    }


def _read_text(path: Path) -> str:
    """A recipe file's text. It must be a regular file (not a device, FIFO or directory) of at
    most :data:`MAX_RECIPE_BYTES`; the error names the file and never quotes it."""
    from gcnt.files import read_regular

    raw = read_regular(path, MAX_RECIPE_BYTES, "a recipe is a YAML file", RecipeError)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise RecipeError(f"{path}: not a text file; a recipe is YAML") from None


def _read_yaml(path: Path, chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """A recipe file's mapping, with ``base: other.yaml`` (relative to the file) merged under it.
    A file that is not a recipe (none of its top-level keys is a recipe key) is refused without
    quoting it: a ``base:`` may name any file."""
    try:
        resolved = path.resolve()
    except (RuntimeError, OSError) as e:  # a symlink loop (RuntimeError up to Python 3.12)
        raise RecipeError(f"{path}: cannot be resolved ({e})") from None
    if resolved in chain:
        raise RecipeError(f"{path}: recipe bases form a cycle: {' -> '.join(map(str, chain))}")
    text = _read_text(path)
    data = parse_yaml(text, path, "a recipe is YAML", RecipeError, loader=RecipeLoader) or {}
    if not isinstance(data, dict):
        raise RecipeError(f"{path}: a recipe must be a mapping of sections")
    if data and not any(isinstance(k, str) and k in _recipe_keys() for k in data):
        raise RecipeError(
            f"{path}: not a recipe (none of its top-level keys is a recipe section or setting)"
        )
    _plugin_paths(data, path)
    base = data.pop("base", None)
    if base is None:
        return data
    if not isinstance(base, str) or not base.strip():
        raise RecipeError(
            f"{path}: base: expected the path of a recipe file, got "
            f"{'an empty string' if isinstance(base, str) else type(base).__name__}"
        )
    return _merge(_read_yaml(_base_path(path, base), (*chain, resolved)), data)


def _base_path(path: Path, base: str) -> Path:
    """The file ``base:`` names in the recipe at ``path``: relative to the recipe's folder, or,
    where no such file is there, a recipe that ships with gcnt by its name (``base: quickstart``,
    ``base: smpenv/walker``), as ``gcnt train`` takes it."""
    local = path.parent / base
    if local.exists() or Path(base).is_absolute():
        return local
    from gcnt.data_folders import packaged_recipes

    name = Path(base).as_posix().removeprefix("./").removeprefix("recipes/")
    for candidate in (name, f"{name}.yaml"):
        packaged = packaged_recipes() / candidate
        if candidate.endswith(".yaml") and packaged.is_file():
            return packaged
    return local  # not there either: read (and refused) as written


def _plugin_paths(data: dict[str, Any], path: Path) -> None:
    """A recipe file's plugin files, relative to the file, made absolute (modules stay)."""
    from gcnt import plugins

    listed = data.get("plugins")
    if not isinstance(listed, list):
        return
    try:
        data["plugins"] = [
            plugins.normalize(p, base=path.parent) if isinstance(p, str) else p for p in listed
        ]
    except plugins.PluginError as e:
        raise RecipeError(f"{path}: plugins: {e}") from None


def _yaml_problem(e: yaml.YAMLError) -> str:
    """A YAML error in one line: the problem and where."""
    mark = getattr(e, "problem_mark", None)
    problem = getattr(e, "problem", None) or str(e).splitlines()[0]
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return f"{problem}{where}"


#: the recipe the benchmark commands use when none is given (one that ships with gcnt)
QUICKSTART = "quickstart"


def packaged_recipe_names() -> list[str]:
    """The recipes that ship with gcnt, by name (``quickstart``, ``smpenv/walker``, ...); the
    bases of other recipes (``_td3.yaml``) are left out."""
    from gcnt.data_folders import packaged_recipes

    root = packaged_recipes()
    return sorted(
        p.relative_to(root).with_suffix("").as_posix()
        for p in root.rglob("*.yaml")
        if not p.name.startswith("_")
    )


def find_recipe(spec: str | Path) -> Path:
    """The recipe file ``spec`` names: a path to a file, or else a recipe that ships with gcnt,
    by its name (``quickstart``, ``smpenv/walker``), with ``.yaml`` or not, or as the checkout
    writes it (``recipes/smpenv/walker.yaml``, which thus works from any folder). A RecipeError
    names ``spec`` and the closest recipe names otherwise."""
    from gcnt.data_folders import packaged_recipes

    path = Path(spec)
    name = path.as_posix().removeprefix("./").removeprefix("recipes/")
    if path.is_dir() and not path.is_absolute() and (packaged_recipes() / f"{name}.yaml").is_file():
        raise RecipeError(
            f"{spec}: a folder here, and a recipe that ships with gcnt: give recipes/{name}.yaml "
            f"for gcnt's recipe, or the path of a recipe file in the folder ({spec}/<file>.yaml)"
        )
    if path.exists() or path.is_absolute():
        return path
    for candidate in (name, f"{name}.yaml"):
        packaged = packaged_recipes() / candidate
        if candidate.endswith(".yaml") and packaged.is_file():
            return packaged
    names = packaged_recipe_names()
    raise RecipeError(
        f"{spec}: no such recipe file, nor a recipe that ships with gcnt"
        f"{did_you_mean(name.removesuffix('.yaml'), names)} (gcnt's recipes: {', '.join(names)})"
    )


def default_recipe(name: str = QUICKSTART) -> str:
    """The path of a recipe that ships with gcnt (the benchmark commands' default)."""
    return str(find_recipe(name))


def read_recipe_file(path: str | Path) -> dict[str, Any]:
    """A recipe file's mapping with its bases merged in, not yet validated (``load_recipe`` is
    ``recipe_from_dict(read_recipe_file(path), overrides, source=path)``). ``path`` may name a
    recipe that ships with gcnt (:func:`find_recipe`)."""
    path = find_recipe(path)
    data = _read_yaml(path)
    if not data:
        raise RecipeError(
            f"{path}: the recipe is empty; it must say at least what to train on (env.robots), "
            "e.g. start from gcnt's quickstart recipe or write base: <a recipe>"
        )
    return data


def load_recipe(path: str | Path, overrides: list[str] | None = None) -> Recipe:
    """Load a recipe file, apply ``section.key=value`` overrides, validate everything.

    ``path`` is a recipe file, or the name of a recipe that ships with gcnt (:func:`find_recipe`:
    ``quickstart``, ``smpenv/walker``). A recipe may start from another with
    ``base: relative/path.yaml``; its keys override the base's, section by section.
    """
    data = read_recipe_file(path)
    source = str(find_recipe(path))
    effective = copy.deepcopy(data)
    try:
        for o in overrides or []:
            _apply_override(effective, o)
    except RecipeError:
        # a bad override: nothing the recipe names is imported (a later plugins=[] would not
        # have been applied); recipe_from_dict says what is wrong
        return recipe_from_dict(data, overrides, source=source)
    if isinstance(effective, dict) and effective.get("plugins"):
        # imported first: they may register the algorithm, the method, the benchmark
        import_recipe_plugins(effective, source)
    return recipe_from_dict(data, overrides, source=source)


def recorded_recipe(
    recorded: dict[str, Any], path: str | Path, overrides: list[str] | None, anywhere: bool
) -> Recipe:
    """The recipe a run recorded (``recorded``, read from ``path``) with ``overrides``, to go on
    with on this machine (:func:`gcnt.run.record.load_run_recipe`: the device and CUDA-only
    switches as it describes). A recorded ``compile.cache_dir`` is not used (one info line):
    the run may come from someone else, and torch's compile cache holds code that it loads and
    runs, so compiled code is cached where this command says (a ``compile.cache_dir`` override,
    else the user's own cache: :func:`gcnt.rl.accelerate.inductor_cache_dir`)."""
    data = _as_recorded(recorded)
    overrides = list(overrides or [])
    given = {o.split("=", 1)[0].strip() for o in overrides if "=" in o}
    effective = yaml.safe_load(yaml.safe_dump(data or {}))
    try:
        for o in overrides:
            _apply_override(effective, o)
    except RecipeError:
        return recipe_from_dict(data, overrides, source=str(path))  # says what is wrong
    device = str(effective.get("device", "cpu"))
    if anywhere and "device" not in given and not _device_here(device):
        log.info("%s: recorded on %s, which this machine lacks: read on the cpu", path, device)
        overrides.append("device=cpu")
        device = "cpu"
    switches = effective.get("compile") if isinstance(effective.get("compile"), dict) else {}
    if switches.get("cache_dir") is not None and not given & {"compile", "compile.cache_dir"}:
        log.info(
            "%s: its compile.cache_dir (%s) is not used: compiled code is cached where this "
            "command says (compile.cache_dir=..., else the user's cache)",
            path,
            switches["cache_dir"],
        )
        overrides.append("compile.cache_dir=null")
    dropped = [
        key
        for key in CompileConfig.CUDA_ONLY
        if switches.get(key) is True and f"compile.{key}" not in given
    ]
    if dropped and not device.startswith("cuda"):
        log.warning(
            "%s: continuing on %s without %s (CUDA only)",
            path,
            device,
            ", ".join(f"compile.{key}" for key in dropped),
        )
        overrides += [f"compile.{key}=false" for key in dropped]
    return recipe_from_dict(data, overrides, source=str(path))


def _as_recorded(data: Any) -> Any:
    """A recorded recipe with the keys it predates set to what its run trained with: the
    ``BEFORE_KEY`` values of its algorithm's section and of ``compile``, where the section
    lacks the key (keys added, or defaults changed, that changed what a missing key means)."""
    if not isinstance(data, dict):
        return data
    compile_section = data.get("compile")
    if compile_section is None or isinstance(compile_section, dict):
        data = {**data, "compile": {**CompileConfig.BEFORE_KEY, **(compile_section or {})}}
    if not isinstance(data.get("algo"), str):
        return data
    try:
        before = getattr(algorithm_section(data["algo"]), "BEFORE_KEY", {})
    except RecipeError:
        return data
    section = data.get(data["algo"])
    if before and isinstance(section, dict):
        data = {**data, data["algo"]: {**before, **section}}
    return data


def _device_here(device: str) -> bool:
    """Whether this machine has the CUDA device ``device`` names (True for anything else: a
    malformed device is left to the recipe's own check)."""
    index = device.removeprefix("cuda").removeprefix(":") or "0"
    if not device.startswith("cuda") or not index.isdigit():
        return True
    import torch  # only for a GPU recipe

    return torch.cuda.is_available() and int(index) < torch.cuda.device_count()


def save_recipe(recipe: Recipe, path: str | Path) -> None:
    write_text(Path(path), yaml.safe_dump(recipe.to_dict(), sort_keys=False))
