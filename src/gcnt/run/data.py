"""A run directory read as data, defensively (the recipe as a plain dict): what every command
that reads runs starts from (the analysis commands, a fine-tune reading its source's identity),
below :mod:`gcnt.rl` and :mod:`gcnt.analysis`.

A run directory, as ``gcnt train`` writes it::

    recipe.yaml            the resolved recipe (its ``resolved:`` section: what the run derived,
                           its robots and plugins: :mod:`gcnt.run.record`)
    metrics.jsonl          one JSON row per log step: env_steps, train_return/mean, ...
                           (a non-finite value is ``null``; read back as NaN)
    checkpoints/last.pt    the latest checkpoint
    eval/*.json            evaluations: {"env_steps": N, "robots": {name: {"mean", ...}}, ...}
    robots/<sha256>.xml    the MJCF of its training and test robots
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from gcnt.files import MiB, read_json, read_yaml
from gcnt.run.layout import CHECKPOINT, METRICS_FILE, RECIPE_FILE

#: Recipe keys that do not change the experiment a run is one seed of, so that runs differing
#: only in them are seeds of one experiment (:attr:`Run.experiment`; a section's name stands for
#: every key in it): the seed itself; where the run is written and how it logs; the device; how
#: often it checkpoints and evaluates during training, and videos; the physics threads; and the
#: speed switches that compute the same updates (compiled, CUDA-graphed, threaded, the replay's
#: device; not ``compile.amp``, whose bfloat16 updates differ). ``resolved`` holds what the run
#: derived from the other keys, and where a fine-tuned run started (its ``init_from`` record,
#: which enters as the source run's task and fingerprint instead); ``plugins``, the code that
#: defines the names the recipe uses, as gcnt's own code does not enter either.
NOT_THE_EXPERIMENT = (
    "seed",
    "run_dir",
    "logger",
    "device",
    "checkpoint_interval",
    "eval.interval",
    "eval.video",
    "env.num_threads",
    "compile.compile",
    "compile.mode",
    "compile.cudagraphs",
    "compile.replay_on_device",
    "compile.policy_compile",
    "compile.policy_cudagraphs",
    "compile.warmup",
    "compile.torch_threads",
    "compile.twin_threads",
    "compile.twin_processes",
    "td3.checkpoint_buffers",
    "resolved",
    "plugins",
)


@functools.cache
def recipe_defaults() -> dict[str, Any]:
    """Every recipe key's current default as a dotted key (``td3.target``: ``auto``): a key an
    older recipe lacks stands for its default, so a key at its default is left out of
    :attr:`Run.experiment` in every recipe, old or new."""
    import dataclasses

    from gcnt.recipes import Recipe, algorithm_names, algorithm_section

    def default(f: dataclasses.Field) -> Any:
        if f.default is not dataclasses.MISSING:
            return f.default
        if f.default_factory is not dataclasses.MISSING:
            return f.default_factory()
        return dataclasses.MISSING

    tree: dict[str, Any] = {}
    for f in dataclasses.fields(Recipe):
        value = default(f)
        if dataclasses.is_dataclass(value):
            tree[f.name] = dataclasses.asdict(value)
        elif value is not dataclasses.MISSING and f.name not in ("sections", "resolved"):
            tree[f.name] = value
    for name in algorithm_names():
        try:
            tree[name] = dataclasses.asdict(algorithm_section(name)())
        except TypeError:  # a section without defaults for every field
            continue
    return dict(_flatten(tree))


class AnalysisError(ValueError):
    """Run directories that cannot give what was asked; the message names the path."""


class InitFromCycleError(AnalysisError):
    """Runs whose ``init_from`` records lead back to one of them."""


#: the runs whose fingerprints are being worked out, through their ``init_from`` sources
_FINGERPRINTING: list[Path] = []


@dataclass(frozen=True)
class EvalRecord:
    """One evaluation file of a run."""

    path: Path
    #: what was evaluated: the file name without ``step<N>`` ("" for training's own evaluations)
    label: str
    env_steps: int
    #: robot name -> {"mean", "stderr", "episodes", "returns"}
    robots: dict[str, dict[str, Any]]
    #: extra keys (robots_spec, episodes, seed, deterministic, ...) when the file has them
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def specs(self) -> list[str]:
        """The robot specifications evaluated, as given (``gcnt eval --robots``: may be
        ``test`` or ``train``)."""
        spec = self.meta.get("robots_spec") or []
        return [spec] if isinstance(spec, str) else [str(s) for s in spec]

    def matches(self, name: str) -> bool:
        """True if set ``name`` is this whole evaluation: its label (``training`` for the
        evaluations made during training), or its one robot specification (as given or as
        ``gcnt eval`` resolved it), or that specification's split (``variants-kinematics`` for
        ``Unimal:variants-kinematics``). An evaluation of several specifications is matched by
        :meth:`specs_named` instead."""
        if name == self.label or (name == "training" and self.label == ""):
            return True
        for specs in (self.specs, self.meta.get("resolved_specs") or []):
            if len(specs) == 1 and _names_spec(name, str(specs[0])):
                return True
        return False

    def specs_named(self, name: str) -> list[str]:
        """The specifications of this evaluation that set ``name`` names (a part of it)."""
        return [s for s in self.specs if _names_spec(name, s)]

    @property
    def deterministic(self) -> bool | None:
        """The policy's mean action (True) or sampled actions (False); None if not recorded."""
        value = self.meta.get("deterministic")
        return bool(value) if value is not None else None

    @property
    def episodes(self) -> int:
        """Episodes per robot (the fewest of any robot when they differ; 0 if not recorded)."""
        counts = [_int(r.get("episodes")) for r in self.robots.values() if isinstance(r, dict)]
        return min(counts) if counts else _int(self.meta.get("episodes"))

    @property
    def protocol(self) -> str:
        """How the numbers were made (:func:`protocol_text`)."""
        return protocol_text(self.deterministic, self.episodes)


def _names_spec(name: str, spec: str) -> bool:
    """``name`` is robot specification ``spec``, or its split (the part after ``Benchmark:``)."""
    return name == spec or (":" in spec and name == spec.split(":", 1)[1])


def _int(value: Any) -> int:
    try:
        return int(value)
    except (TypeError, ValueError):
        return 0


def score(result: Any) -> float:
    """A robot's mean return in an evaluation file (NaN when missing or ``null``)."""
    value = result.get("mean") if isinstance(result, dict) else None
    return float(value) if isinstance(value, int | float) else math.nan


def protocol_text(deterministic: bool | None, episodes: int | None) -> str:
    """``deterministic actions, 100 episodes per robot`` (the policy's mean action), ``sampled
    actions, 32 episodes per robot``; ``actions not recorded`` for old evaluation files."""
    mode = {True: "deterministic actions", False: "sampled actions", None: "actions not recorded"}
    return (
        f"{mode[deterministic]}, {episodes} episodes per robot" if episodes else mode[deterministic]
    )


def protocols_text(protocols: Iterable[str]) -> str:
    """One protocol, or ``mixed: A; B`` when the numbers come from several."""
    kinds = sorted(set(protocols))
    if len(kinds) == 1:
        return kinds[0]
    return "mixed: " + "; ".join(kinds) if kinds else "no evaluations"


#: ``step<N>`` (training), ``<label>-step<N>`` or ``<label>-step<N>-<mode>-seed<S>`` (gcnt eval)
_STEP = re.compile(r"^(?P<label>.*?)[-_]?step(?P<steps>\d+)(?:[-_].*)?$")


def _get(d: Any, *path: str, default: Any = None) -> Any:
    for p in path:
        if not isinstance(d, dict) or p not in d:
            return default
        d = d[p]
    return d


def _whole(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _count(value: Any) -> bool:
    """A whole number, or a float that is one (``2e4``)."""
    return _whole(value) or (isinstance(value, float) and value.is_integer())


def _strings(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def _scalar(value: Any) -> bool:
    return isinstance(value, str | int | float | bool)


#: the keys of a run's recipe the analysis reads, and what each must be (null: unset)
_RUN_KEYS: tuple[tuple[tuple[str, ...], Any, str], ...] = (
    (("seed",), _whole, "a whole number"),
    (("task",), _scalar, "a name"),
    (("benchmark",), _scalar, "a name"),
    (("algo",), _scalar, "a name"),
    (("label",), _scalar, "a name"),
    (("init_from",), lambda v: isinstance(v, str), "a run directory"),
    (("network",), lambda v: isinstance(v, dict), "a mapping"),
    (("network", "name"), _scalar, "a name"),
    (("env",), lambda v: isinstance(v, dict), "a mapping"),
    (("env", "benchmark"), _scalar, "a name"),
    (("env", "robots"), _strings, "a list of robot specs"),
    (("env", "test_robots"), _strings, "a list of robot specs"),
    (("eval",), lambda v: isinstance(v, dict), "a mapping"),
    (("eval", "deterministic"), lambda v: isinstance(v, bool), "true or false"),
    (("collector",), lambda v: isinstance(v, dict), "a mapping"),
    (("collector", "total_frames"), _count, "a whole number"),
    (("resolved",), lambda v: isinstance(v, dict), "a mapping"),
    (("resolved", "init_from"), lambda v: isinstance(v, dict), "a mapping"),
    (("resolved", "init_from", "run"), lambda v: isinstance(v, str), "a run directory"),
    (("resolved", "init_from", "task"), _scalar, "a name"),
    (("resolved", "init_from", "fingerprint"), lambda v: isinstance(v, str), "a fingerprint"),
)


def check_run_recipe(data: dict[str, Any], path: Path) -> None:
    """An AnalysisError naming ``path`` and the key where a key the analysis reads is not what
    ``gcnt train`` writes there (a seed that is not a whole number, robots that are not a list
    of specs, an ``init_from`` record whose run is not a path), as ``gcnt eval`` refuses it."""
    for keys, valid, what in _RUN_KEYS:
        value = _get(data, *keys)
        if value is not None and not valid(value):
            raise AnalysisError(
                f"{path}: {'.'.join(keys)} must be {what}, not {_shown(value)}; a run's "
                "recipe.yaml is what gcnt train writes"
            )


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else f"a {type(value).__name__}"


def _flatten(d: dict[str, Any], prefix: str = "") -> Iterable[tuple[str, Any]]:
    """``(dotted key, value)`` of every value in nested mappings (an empty mapping has none),
    a whole number written as a float read as the integer (``2e4`` is ``20000``)."""
    for key, value in d.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _flatten(value, dotted + ".")
        else:
            yield dotted, _plain_number(value)


def _plain_number(value: Any) -> Any:
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, list):
        return [_plain_number(v) for v in value]
    return value


class Run:
    """A run directory, read lazily."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not (self.path / RECIPE_FILE).is_file():
            raise AnalysisError(f"{self.path}: no {RECIPE_FILE}; is this a gcnt run directory?")

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r}, {self.task}, {self.method}, seed {self.seed})"

    @cached_property
    def recipe(self) -> dict[str, Any]:
        path = self.path / RECIPE_FILE
        data = read_yaml(path, MiB, "a run's recipe is YAML", AnalysisError) or {}
        if not isinstance(data, dict):
            raise AnalysisError(f"{path}: the recipe is not a mapping")
        check_run_recipe(data, path)
        return data

    # --- identity (new field names first, then the old ones)
    @property
    def task(self) -> str:
        return str(self.recipe.get("task") or self.recipe.get("benchmark") or "custom")

    @property
    def algo(self) -> str:
        return str(self.recipe.get("algo") or "td3")

    @property
    def method(self) -> str:
        return str(_get(self.recipe, "network", "name", default="?"))

    @property
    def label(self) -> str:
        """The name the run is shown under: the recipe's ``label`` (e.g. SR-fair), else the
        method."""
        return str(self.recipe.get("label") or self.method)

    @property
    def seed(self) -> int:
        return int(self.recipe.get("seed") or 0)

    @property
    def benchmark(self) -> str:
        """The env benchmark (smpenv, unimal); old recipes had none: smpenv."""
        return str(_get(self.recipe, "env", "benchmark", default=None) or "smpenv")

    @property
    def eval_deterministic(self) -> bool:
        """The recipe's evaluation protocol: the policy's mean action (True, the default) or
        sampled actions (False: ModuMorph's PPO protocol)."""
        return bool(_get(self.recipe, "eval", "deterministic", default=True))

    @property
    def init_random_frames(self) -> int | None:
        """Env steps of uniform random actions before learning (TD3): the run's own count from
        the recipe's ``resolved:`` section (rounded to whole batches), else ``td3``'s; None for
        algorithms without the phase."""
        for path in (("resolved", "init_random_frames"), (self.algo, "init_random_frames")):
            value = _get(self.recipe, *path)
            if isinstance(value, int | float):
                return int(value)
        return None

    @property
    def total_frames(self) -> int | None:
        value = _get(self.recipe, "collector", "total_frames")
        return int(value) if value is not None else None

    @property
    def train_robot_specs(self) -> list[str]:
        return list(_get(self.recipe, "env", "robots", default=[]) or [])

    @property
    def test_robot_specs(self) -> list[str]:
        return list(_get(self.recipe, "env", "test_robots", default=[]) or [])

    @cached_property
    def single_robot(self) -> str | None:
        """The one robot the run trains, when its recipe names exactly one robot (a catalogue
        name or an .xml file: ``gcnt sweep --per-robot``); None for a robot set."""
        specs = self.train_robot_specs
        if len(specs) != 1 or not isinstance(specs[0], str):
            return None
        spec = specs[0]
        if spec.endswith(".xml"):
            return Path(spec).stem
        from gcnt.morphology.catalogues import robot_catalogue

        try:
            return spec if robot_catalogue(spec) is not None else None
        except Exception:  # noqa: BLE001 - an unreadable catalogue: not known as one robot
            return None

    # --- which experiment the run is a seed of
    @cached_property
    def experiment(self) -> dict[str, Any]:
        """The resolved recipe as dotted keys (``collector.total_frames``: value), without the
        keys that do not change the experiment (:data:`NOT_THE_EXPERIMENT`) and those set to
        null (a default, as in a recipe written before the key existed): runs with equal ones
        are seeds of one experiment. A run that trains one robot leaves out ``env.robots``
        (the per-robot runs of ``gcnt sweep --per-robot`` are one experiment); a fine-tuned run
        whose record names its source run's fingerprint holds ``init_from.task`` and
        ``init_from.fingerprint`` instead of the source's path (fine-tunes of different seeds
        of one experiment are seeds of one fine-tune)."""
        defaults = recipe_defaults()
        unset = object()
        flat = {
            key: value
            for key, value in _flatten(self.recipe)
            # null or the default: as a key an older recipe lacks
            if value is not None
            and value != defaults.get(key, unset)
            and not any(key == k or key.startswith(k + ".") for k in NOT_THE_EXPERIMENT)
        }
        # settings of the methods the run does not train, and workers the collector does not use
        method = self.method
        for section in ("network.method_kwargs.", "ppo.kl_stop."):
            for key in [k for k in flat if k.startswith(section)]:
                if key[len(section) :].split(".", 1)[0] not in (method, "default"):
                    del flat[key]
        if _get(self.recipe, "ppo", "collector", default="single") != "multi":
            flat.pop("ppo.workers", None)
            flat.pop("ppo.worker_envs", None)
        if self.single_robot is not None:
            flat.pop("env.robots", None)
        source = self._init_source()
        if source is not None:
            flat.pop("init_from", None)
            flat["init_from.task"], flat["init_from.fingerprint"] = source
        return flat

    def _init_source(self) -> tuple[str, str] | None:
        """(task, fingerprint) of the run a fine-tuned run started from: from its record, or
        (a record written before it held them) from the source run itself where it still is;
        None when the run was trained from scratch or its source cannot be read."""
        record = _get(self.recipe, "resolved", "init_from")
        if not isinstance(record, dict):
            return None
        if record.get("fingerprint"):
            return str(record.get("task")), str(record["fingerprint"])
        path = record.get("run")
        if not path or not (Path(path) / RECIPE_FILE).is_file():
            return None
        here = self.path.resolve()
        if here in _FINGERPRINTING:
            raise InitFromCycleError(
                f"{self.path / RECIPE_FILE}: resolved.init_from.run leads back to this run "
                f"({' -> '.join(map(str, [*_FINGERPRINTING, here]))}); a run cannot start from "
                "itself"
            )
        _FINGERPRINTING.append(here)
        try:
            source = Run(path)
            return source.task, source.fingerprint
        except InitFromCycleError:
            raise
        except AnalysisError:
            return None
        finally:
            _FINGERPRINTING.pop()

    @cached_property
    def fingerprint(self) -> str:
        """A short hash of :attr:`experiment`: equal for the seeds of one experiment."""
        text = json.dumps(self.experiment, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:12]

    @property
    def record(self) -> Any:
        """The run's record as it wrote it (:class:`gcnt.run.resolved.RunRecord`: benchmark,
        robots with their hashes, method and network sizes, algorithm settings, plugins, device,
        seed); None for a run written before the record."""
        from gcnt.run.resolved import RunRecord

        section = self.recipe.get("resolved")
        return RunRecord.from_resolved(section) if isinstance(section, dict) else None

    @cached_property
    def plugins(self) -> tuple[str, ...]:
        """The plugins the run was trained with, as it recorded them (``resolved.plugins``, or
        an older run's ``plugins:`` list): each one's name and the start of its sha256
        (``my_methods.py sha256 0123456789abcdef``), sorted; never imported."""
        from gcnt.plugins import recorded_identity
        from gcnt.run.record import recorded_plugins

        shown = set()
        for entry in recorded_plugins(self.recipe):
            ident = recorded_identity(entry)
            if ident is not None:
                sha = ident["sha256"]
                shown.add(f"{ident['name']} sha256 {sha[:16]}" if sha else ident["name"])
        return tuple(sorted(shown))

    @property
    def fine_tune_of(self) -> str | None:
        """Where a fine-tuned run started (``init_from``): ``<task> run <path>`` from the
        record of its source run, or the path alone in a recipe without that record; None for
        a run trained from scratch."""
        record = _get(self.recipe, "resolved", "init_from")
        if isinstance(record, dict) and record.get("run"):
            task = record.get("task")
            return f"{task} run {record['run']}" if task else str(record["run"])
        source = self.recipe.get("init_from")
        return str(source) if source else None

    # --- metrics
    def metrics(self) -> list[dict[str, Any]]:
        """Rows of ``metrics.jsonl`` with a numeric ``env_steps``, ``null`` read as NaN
        (:func:`gcnt.run.metrics.read_metrics`: an incomplete last line, from a run stopped
        mid-write, is dropped with a warning; a damaged line before it is an AnalysisError
        naming the file and line). Read once per :class:`Run`: a command's metrics and their
        lengths, curves and per-seed rows, come from one reading."""
        return list(self._metric_rows)

    @cached_property
    def _metric_rows(self) -> list[dict[str, Any]]:
        from gcnt.run.metrics import MetricsFileError, read_metrics

        try:
            rows = read_metrics(self.path / METRICS_FILE)
        except MetricsFileError as e:
            raise AnalysisError(str(e)) from None
        return [r for r in rows if isinstance(r.get("env_steps"), int | float)]

    def last_env_steps(self) -> int:
        rows = self.metrics()
        return int(rows[-1]["env_steps"]) if rows else 0

    def has_checkpoint(self) -> bool:
        return (self.path / CHECKPOINT).is_file()

    def policy_state(self) -> dict[str, Any]:
        """The trained policy's weights from the last checkpoint (``{"actor": ...}``, and the
        observation statistics where the algorithm keeps them); an unreadable checkpoint is an
        AnalysisError naming it."""
        from gcnt.run.directory import CheckpointError, RunDir

        try:
            state = RunDir(self.path).load_checkpoint()
        except CheckpointError as e:
            raise AnalysisError(str(e)) from None
        policy = state.get("policy") or {"actor": state.get("actor")}
        if policy.get("actor") is None:
            raise AnalysisError(f"{self.path / CHECKPOINT}: no 'actor' weights in the checkpoint")
        return policy

    def finished(self) -> bool:
        """The run logged its last step (``collector.total_frames``) and saved a checkpoint."""
        total = self.total_frames
        return total is not None and self.has_checkpoint() and self.last_env_steps() >= total

    # --- evaluations
    def evals(self) -> list[EvalRecord]:
        out = []
        for path in sorted((self.path / "eval").glob("*.json")):
            try:
                data = read_json(path, 64 * MiB, "an evaluation is JSON", AnalysisError)
            except AnalysisError:
                continue
            if not isinstance(data, dict) or not isinstance(data.get("robots"), dict):
                continue
            m = _STEP.match(path.stem)
            label = m.group("label") if m else path.stem
            steps = data.get("env_steps")
            if steps is None and m:
                steps = int(m.group("steps"))
            meta = {k: v for k, v in data.items() if k not in ("robots", "env_steps")}
            out.append(EvalRecord(path, label, int(steps or 0), data["robots"], meta))
        return out

    def set_robots(self, record: EvalRecord, name: str) -> list[str]:
        """The robots of evaluation ``record`` that set ``name`` selects: all of them when the
        set is the whole evaluation (:meth:`EvalRecord.matches`), else those of the
        specifications it names (the test robots of ``Walker++:test`` inside training's
        evaluation of train and test robots), never more; [] when it names none."""
        if record.matches(name):
            return list(record.robots)
        wanted: set[str] = set()
        for spec in record.specs_named(name):
            if spec == "test":
                wanted.update(self.test_robot_names())
            elif spec == "train":
                wanted.update(self.train_robot_names())
            else:
                wanted.update(_robot_names([spec], self.recipe))
        return [r for r in record.robots if r in wanted]

    def _recorded_names(self, key: str) -> list[str] | None:
        """The names of the run's ``train`` or ``test`` robots as it recorded them
        (``resolved.robots``; None for a run written before robots were stored)."""
        names = _get(self.recipe, "resolved", "robots", key)
        return [n for n in names if isinstance(n, str)] if isinstance(names, list) else None

    def test_robot_names(self) -> list[str]:
        """Names of the recipe's test robots: as the run recorded them, else resolved through the
        robot catalogues."""
        recorded = self._recorded_names("test")
        if recorded is not None:
            return recorded
        return _robot_names(self.test_robot_specs, self.recipe)

    def train_robot_names(self) -> list[str]:
        recorded = self._recorded_names("train")
        if recorded:
            return recorded
        names = _robot_names(self.train_robot_specs, self.recipe)
        if names:
            return names
        rows = self.metrics()
        row = rows[-1] if rows else {}
        return [
            k.split("/", 1)[1]
            for k in sorted(row)
            if k.startswith("train_return/") and k != "train_return/mean"
        ]


def _robot_names(specs: Sequence[str], recipe: dict | None = None) -> list[str]:
    """Names of the robots of ``specs``, as the run of ``recipe`` names them (robot files of
    one name are named apart among all of the run's robot lists)."""
    if not specs:
        return []
    from gcnt.morphology.catalogues import resolve_robots

    lists = [("env", "robots"), ("env", "test_robots"), ("eval", "robots")]
    run_specs = [s for key in lists for s in _get(recipe or {}, *key, default=[]) or []]
    try:
        robots = resolve_robots(list(specs), names_from=run_specs)
        return list(dict.fromkeys(r.name for r in robots))
    except Exception:  # noqa: BLE001 - a robot file that moved: fall back to what evals name
        return []
