"""Sweeps: a grid of recipes x methods x seeds, run as ``gcnt train`` subprocesses.

Every run gets an explicit ``run_dir=<sweep>/<task>/<algo>-<method>/seed<N>``, the sweep's W&B
group and a readable W&B name. With ``per_robot`` (``gcnt sweep --per-robot SPLIT``: single-robot
baselines such as SR) every robot of the split is a run of its own, trained alone
(``env.robots=[ROBOT] env.test_robots=[]``), under ``<task>/<algo>-<method>/<robot>/seed<N>``; a
recipe's ``label`` (e.g. SR-fair) takes the method's place in the run id.

A manifest (``<sweep>/manifest.json``) lists every run, its command and its state (and, per-robot,
its robot); running the sweep again skips finished runs and resumes unfinished ones from their
checkpoints (``gcnt train --resume RUN_DIR``). After training, evaluations (``gcnt eval RUN_DIR
--robots SPEC``) can follow in the same slot.

Two ways to run:

* locally (default): a bounded pool of ``jobs`` slots, each pinned to its own cores (CPU affinity
  and the OMP/MKL/OpenBLAS thread counts; unpinned torch processes sharing cores slow each other
  several-fold);
* through ``submitit``: one job array, one run per task (``executor="slurm"``), or submitit's
  ``local`` / ``debug`` executors on this machine.

States: ``pending`` (not started), ``running``, ``partial`` (a checkpoint, not finished),
``done`` (trained; evaluations may be listed separately), ``failed`` (the last attempt exited
non-zero: see its log), ``submitted`` (handed to submitit).
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gcnt.analysis.runs import CHECKPOINT, RECIPE_FILE, Run

if TYPE_CHECKING:
    from gcnt.recipes import Recipe

log = logging.getLogger(__name__)

MANIFEST = "manifest.json"
LOCK = ".sweep.lock"
THREAD_VARS = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
)


class SweepError(ValueError):
    """A sweep that cannot be set up; the message names the recipe, override or directory."""


def slug(text: str) -> str:
    """A folder-safe name: ``Walker++`` -> ``walkerpp``."""
    text = text.replace("+", "p").lower()
    return re.sub(r"[^a-z0-9._-]+", "-", text).strip("-") or "x"


def now() -> str:
    return _dt.datetime.now().isoformat(timespec="seconds")


@dataclass
class RunSpec:
    """One run of a sweep, as the manifest records it."""

    id: str
    run_dir: str
    recipe: str
    task: str
    algo: str
    method: str
    seed: int
    #: overrides given to ``gcnt train RECIPE`` (the method, seed, run_dir and W&B names included)
    overrides: list[str]
    #: robot specs to evaluate after training (``gcnt eval RUN_DIR --robots SPEC``)
    evals: list[str] = field(default_factory=list)
    #: episodes per robot for ``evals`` (None: ``gcnt eval``'s default for the protocol)
    eval_episodes: int | None = None
    #: actions for ``evals``: the mean (True), sampled (False), or None: the recipe's
    #: ``eval.deterministic``, as ``gcnt eval`` does without a flag
    eval_deterministic: bool | None = None
    state: str = "pending"
    #: spec -> "done" | "failed"
    eval_state: dict[str, str] = field(default_factory=dict)
    returncode: int | None = None
    log: str | None = None
    started: str | None = None
    finished: str | None = None
    job_id: str | None = None
    seconds: float | None = None
    #: the one robot this run trains (``--per-robot``); None: the recipe's robots
    robot: str | None = None

    def refresh(self) -> None:
        """Set the training state from the run directory (not for a run in progress)."""
        path = Path(self.run_dir)
        if not (path / RECIPE_FILE).is_file():
            if self.state not in ("failed",):
                self.state = "pending"
            return
        run = Run(path)
        if run.finished():
            self.state = "done"
        elif run.has_checkpoint():
            self.state = "partial" if self.state != "failed" else "failed"
        elif self.state not in ("failed",):
            self.state = "pending"

    def pending_evals(self) -> list[str]:
        return [s for s in self.evals if self.eval_state.get(s) != "done"]

    def complete(self) -> bool:
        return self.state == "done" and not self.pending_evals()


def gcnt_command() -> list[str]:
    """The ``gcnt`` command of this interpreter (works on a cluster node with the same venv)."""
    return [sys.executable, "-m", "gcnt.cli"]


def commands(spec: RunSpec) -> list[tuple[str, list[str]]]:
    """What is left to do for ``spec``: ("train", argv) then ("eval:SPEC", argv) per evaluation."""
    out: list[tuple[str, list[str]]] = []
    run_dir = Path(spec.run_dir)
    if spec.state != "done":
        if (run_dir / CHECKPOINT).is_file():
            out.append(("train", [*gcnt_command(), "train", "--resume", spec.run_dir]))
        else:
            out.append(("train", [*gcnt_command(), "train", spec.recipe, *spec.overrides]))
    for robots in spec.pending_evals():
        out.append((f"eval:{robots}", eval_command(spec, robots)))
    return out


def eval_command(spec: RunSpec, robots: str) -> list[str]:
    """``gcnt eval RUN --robots ROBOTS``, with ``--episodes`` and ``--deterministic`` or
    ``--stochastic`` only where the sweep sets them (else the run's recipe decides)."""
    argv = [*gcnt_command(), "eval", spec.run_dir, "--robots", robots]
    if spec.eval_episodes is not None:
        argv += ["--episodes", str(spec.eval_episodes)]
    if spec.eval_deterministic is not None:
        argv.append("--deterministic" if spec.eval_deterministic else "--stochastic")
    return argv


# ----------------------------------------------------------------------------- the grid


def _method_override(override: str) -> tuple[str, str] | None:
    """``METHOD:key=value`` -> (METHOD, ``key=value``); a plain override -> None."""
    head, sep, rest = override.partition(":")
    if sep and "=" in rest and "=" not in head and "." not in head:
        return head, rest
    return None


def _split_method_overrides(
    overrides: Sequence[str], methods: Sequence[str]
) -> dict[str, list[str]]:
    """``METHOD:key=value`` applies to that method only; plain ``key=value`` to all."""
    per: dict[str, list[str]] = {m: [] for m in methods}
    for o in overrides:
        if (split := _method_override(o)) is not None:
            head, rest = split
            if head not in per:
                raise SweepError(
                    f"override {o!r} names method {head!r}, which is not in the sweep "
                    f"({', '.join(methods)})"
                )
            per[head].append(rest)
        else:
            for m in methods:
                per[m].append(o)
    return per


def per_robot_runs(split: str | Sequence[str]) -> list[tuple[str, str]]:
    """(robot name, spec to train it alone) for each robot of ``split``: a robot spec as
    ``env.robots`` takes it (``Unimal:train``, ``CWHH++:test``, a robot name, an .xml file or
    folder), or several, comma-separated or as a list."""
    from gcnt.morphology import resolve_robots
    from gcnt.morphology.catalogues import robot_catalogue

    specs = [t.strip() for t in split.split(",")] if isinstance(split, str) else list(split)
    specs = [s for s in specs if s]
    if not specs:
        raise SweepError("--per-robot: give a robot split, e.g. Unimal:train")
    try:
        robots = resolve_robots(specs)
    except (ValueError, OSError) as e:
        raise SweepError(f"--per-robot {','.join(specs)}: {e}") from None
    # a catalogue robot by its name; a robot loaded from a file by that file
    return [(r.name, r.name if robot_catalogue(r.name) else r.source) for r in robots]


def robot_overrides(spec: str) -> list[str]:
    """The overrides that train one robot alone (JSON strings are YAML scalars: paths quoted)."""
    return [f"env.robots=[{json.dumps(spec)}]", "env.test_robots=[]"]


def _sets_robots(override: str) -> bool:
    split = _method_override(override)
    key = (split[1] if split else override).split("=", 1)[0].strip()
    return key in ("env.robots", "env.test_robots", "env")


def expand(
    recipes: Sequence[str | Path],
    sweep_dir: str | Path,
    *,
    methods: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    overrides: Sequence[str] = (),
    evals: Sequence[str] = (),
    eval_episodes: int | None = None,
    eval_deterministic: bool | None = None,
    group: str | None = None,
    per_robot: str | Sequence[str] | None = None,
) -> list[RunSpec]:
    """The runs of recipes x methods x [robots] x seeds (default: each recipe's own method and
    seed). With ``per_robot`` (a robot split, see :func:`per_robot_runs`), one run per robot of
    the split, each trained alone.

    Each combination is loaded and validated now, so that a bad recipe or override fails before
    anything runs (a :class:`SweepError` naming it).
    """
    from gcnt.recipes import RecipeError, read_recipe_file, recipe_from_dict

    sweep_dir = Path(sweep_dir).resolve()
    group = group or sweep_dir.name
    robots: list[tuple[str | None, list[str]]] = [(None, [])]
    if per_robot is not None:
        if bad := [o for o in overrides if _sets_robots(o)]:
            raise SweepError(
                f"--per-robot sets env.robots and env.test_robots of every run; drop {bad[0]!r}"
            )
        if "test" in evals:
            raise SweepError("--per-robot runs have no test robots: --eval test evaluates nothing")
        robots = [(name, robot_overrides(spec)) for name, spec in per_robot_runs(per_robot)]
    specs: list[RunSpec] = []
    seen: dict[str, str] = {}
    for recipe_path in recipes:
        recipe_path = Path(recipe_path)
        if not recipe_path.is_file():
            raise SweepError(f"{recipe_path}: no such recipe file")
        source = str(recipe_path)
        try:
            data = read_recipe_file(recipe_path)  # read once: a per-robot sweep loads it often
            base = recipe_from_dict(data, [*_plain(overrides), *robots[0][1]], source)
        except RecipeError as e:
            raise SweepError(str(e)) from None
        ms = list(methods or [base.network.name])
        per_method = _split_method_overrides(overrides, ms)
        for m in ms:
            for robot, robot_ovr in robots:
                for s in seeds if seeds is not None else [base.seed]:
                    given = [*per_method[m], *robot_ovr, f"network.name={m}", f"seed={s}"]
                    try:
                        r = recipe_from_dict(data, given, source)
                    except RecipeError as e:
                        raise SweepError(str(e)) from None
                    spec = _spec(recipe_path, r, m, robot, given, sweep_dir, group, seen)
                    spec.evals, spec.eval_episodes = list(evals), eval_episodes
                    spec.eval_deterministic = eval_deterministic
                    specs.append(spec)
    if not specs:
        raise SweepError("the sweep has no runs (no recipes?)")
    return specs


def _spec(
    recipe_path: Path,
    r: Recipe,
    method: str,
    robot: str | None,
    given: list[str],
    sweep_dir: Path,
    group: str,
    seen: dict[str, str],
) -> RunSpec:
    task, algo, seed = str(r.task or "custom"), str(r.algo), int(r.seed)
    shown = slug(r.label) if r.label else method
    run_id = f"{slug(task)}/{algo}-{shown}/{'' if robot is None else slug(robot) + '/'}seed{seed}"
    if run_id in seen:
        raise SweepError(
            f"{recipe_path} and {seen[run_id]} give the same run {run_id}: "
            "give the recipes different task names (task=...) or labels (label=...)"
        )
    seen[run_id] = str(recipe_path)
    run_dir = sweep_dir / run_id
    name = "-".join([task, algo, r.label or method, *([robot] if robot else []), f"seed{seed}"])
    return RunSpec(
        id=run_id,
        run_dir=str(run_dir),
        recipe=str(recipe_path.resolve()),
        task=task,
        algo=algo,
        method=method,
        seed=seed,
        overrides=[*given, f"run_dir={run_dir}", f"logger.group={group}", f"logger.name={name}"],
        robot=robot,
    )


def default_dir(
    recipes: Sequence[str | Path],
    overrides: Sequence[str] = (),
    per_robot: str | Sequence[str] | None = None,
) -> Path:
    """``sweeps/<task>`` (the recipes' tasks joined by ``-``)."""
    from gcnt.recipes import RecipeError, load_recipe

    given = _plain(overrides)
    if per_robot is not None:  # a single-robot recipe on its first robot
        given += robot_overrides(per_robot_runs(per_robot)[0][1])
    tasks = []
    for r in recipes:
        try:
            rec = load_recipe(r, given)
        except RecipeError as e:
            raise SweepError(str(e)) from None
        tasks.append(slug(str(rec.task or "x")))
    return Path("sweeps") / "-".join(dict.fromkeys(tasks))


def _plain(overrides: Sequence[str]) -> list[str]:
    """Overrides that apply to every method (``METHOD:key=value`` ones left out)."""
    return [o for o in overrides if _method_override(o) is None]


# ----------------------------------------------------------------------------- manifest


class Manifest:
    """``<sweep>/manifest.json``: the sweep's runs and their states (written atomically)."""

    def __init__(
        self, sweep_dir: str | Path, runs: list[RunSpec], meta: dict[str, Any] | None = None
    ):
        self.dir = Path(sweep_dir)
        self.runs = runs
        self.meta = dict(meta or {})

    @property
    def path(self) -> Path:
        return self.dir / MANIFEST

    @classmethod
    def load(cls, sweep_dir: str | Path) -> Manifest:
        path = Path(sweep_dir) / MANIFEST
        if not path.is_file():
            raise SweepError(f"{sweep_dir}: no {MANIFEST}; is this a sweep directory?")
        try:
            data = json.loads(path.read_text())
            runs = [RunSpec(**r) for r in data.pop("runs")]
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise SweepError(f"{path}: not a sweep manifest ({e})") from None
        return cls(sweep_dir, runs, data)

    def merge(self, runs: list[RunSpec]) -> None:
        """Add new runs; a run already listed keeps its state, and takes the new evaluations."""
        known = {r.id: r for r in self.runs}
        for r in runs:
            if r.id in known:
                old = known[r.id]
                old.evals = list(dict.fromkeys([*old.evals, *r.evals]))
                old.eval_episodes = r.eval_episodes
                old.eval_deterministic = r.eval_deterministic
            else:
                self.runs.append(r)

    def refresh(self) -> None:
        for r in self.runs:
            if r.state != "running":
                r.refresh()

    def save(self) -> Path:
        self.dir.mkdir(parents=True, exist_ok=True)
        self.meta["updated"] = now()
        data = {**self.meta, "runs": [asdict(r) for r in self.runs]}
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(data, indent=1))
        os.replace(tmp, self.path)
        return self.path

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for r in self.runs:
            out[r.state] = out.get(r.state, 0) + 1
        return out

    def table(self) -> str:
        width = max(len(r.id) for r in self.runs)
        lines = [f"{'run':<{width}}  {'state':<9}  {'steps':>9}  evaluations"]
        for r in self.runs:
            steps = Run(r.run_dir).last_env_steps() if Path(r.run_dir, RECIPE_FILE).is_file() else 0
            ev = ", ".join(f"{k}: {r.eval_state.get(k, 'pending')}" for k in r.evals) or "-"
            lines.append(f"{r.id:<{width}}  {r.state:<9}  {steps:>9}  {ev}")
        return "\n".join(lines)


class SweepLock:
    """One process drives a sweep directory at a time."""

    def __init__(self, sweep_dir: Path) -> None:
        self.path = sweep_dir / LOCK

    def __enter__(self) -> SweepLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists():
            try:
                pid = int(self.path.read_text().strip())
                os.kill(pid, 0)
            except (ValueError, ProcessLookupError):
                pass  # stale
            except PermissionError:
                raise SweepError(f"{self.path.parent}: another process drives this sweep") from None
            else:
                if pid != os.getpid():
                    raise SweepError(
                        f"{self.path.parent}: the sweep is being run by process {pid} "
                        f"(remove {self.path} if that is wrong)"
                    )
        self.path.write_text(str(os.getpid()))
        return self

    def __exit__(self, *exc: object) -> None:
        self.path.unlink(missing_ok=True)


# ----------------------------------------------------------------------------- running


def available_cores() -> list[int]:
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return list(range(os.cpu_count() or 1))


def pinned_env(threads: int, base: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ if base is None else base)
    for var in THREAD_VARS:
        env[var] = str(threads)
    return env


def slot_cores(jobs: int, cpus_per_run: int, cores: Sequence[int] | None = None) -> list[list[int]]:
    """The cores of each of ``jobs`` slots: disjoint blocks while there are enough cores,
    wrapping around (shared) otherwise."""
    cores = list(cores if cores is not None else available_cores())
    return [
        [cores[(s * cpus_per_run + i) % len(cores)] for i in range(cpus_per_run)]
        for s in range(jobs)
    ]


def default_jobs(cpus_per_run: int, cores: Sequence[int] | None = None) -> int:
    n = len(cores if cores is not None else available_cores())
    return max(1, n // max(1, cpus_per_run))


def _log_path(sweep_dir: Path, spec: RunSpec) -> Path:
    return sweep_dir / "logs" / f"{spec.id.replace('/', '__')}.log"


def _finish_step(spec: RunSpec, what: str, rc: int) -> None:
    if what == "train":
        spec.returncode = rc
        spec.refresh()
        if rc != 0:
            spec.state = "failed"
        elif spec.state != "done":  # exited cleanly but short of total_frames
            spec.state = "partial"
    else:
        spec.eval_state[what.split(":", 1)[1]] = "done" if rc == 0 else "failed"


def run_local(
    manifest: Manifest,
    *,
    jobs: int,
    cpus_per_run: int = 1,
    poll: float = 0.5,
    on_change: Callable[[RunSpec], None] | None = None,
) -> Manifest:
    """Run what is left of every run in a pool of ``jobs`` pinned slots; save the manifest on
    every change. Ctrl-C stops the children (their checkpoints stay for a later resume)."""
    todo = [r for r in manifest.runs if commands(r)]
    slots = slot_cores(jobs, cpus_per_run)
    free = list(range(jobs))
    active: dict[int, tuple[subprocess.Popen, RunSpec, list, Any, float]] = {}
    sweep_dir = manifest.dir

    def start(slot: int, spec: RunSpec, steps: list) -> None:
        what, argv = steps[0]
        logf = _log_path(sweep_dir, spec)
        logf.parent.mkdir(parents=True, exist_ok=True)
        fh = logf.open("a")
        fh.write(f"\n# {now()} slot {slot} cores {slots[slot]}: {' '.join(argv)}\n")
        fh.flush()
        cores = set(slots[slot])
        proc = subprocess.Popen(
            argv,
            stdout=fh,
            stderr=subprocess.STDOUT,
            env=pinned_env(len(cores)),
            preexec_fn=(lambda: os.sched_setaffinity(0, cores))
            if hasattr(os, "sched_setaffinity")
            else None,
        )
        spec.log = str(logf)
        if what == "train":
            spec.state, spec.started, spec.returncode = "running", now(), None
        active[slot] = (proc, spec, steps, fh, time.monotonic())
        manifest.save()
        if on_change:
            on_change(spec)

    try:
        while todo or active:
            while free and todo:
                spec = todo.pop(0)
                start(free.pop(0), spec, commands(spec))
            time.sleep(poll)
            for slot in list(active):
                proc, spec, steps, fh, t0 = active[slot]
                rc = proc.poll()
                if rc is None:
                    continue
                fh.close()
                del active[slot]
                what = steps[0][0]
                _finish_step(spec, what, rc)
                if what == "train":
                    spec.finished, spec.seconds = now(), round(time.monotonic() - t0, 1)
                rest = steps[1:] if (what != "train" or spec.state == "done") else []
                manifest.save()
                if on_change:
                    on_change(spec)
                if rest:
                    start(slot, spec, rest)
                else:
                    free.append(slot)
    except KeyboardInterrupt:
        for proc, *_ in active.values():
            proc.send_signal(signal.SIGTERM)
        for proc, spec, _, fh, _ in active.values():
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
            fh.close()
            spec.state = "running"
            spec.refresh()
        manifest.save()
        raise
    return manifest


# ----------------------------------------------------------------------------- submitit


def run_task(spec_dict: dict[str, Any], threads: int = 1) -> dict[str, Any]:
    """One sweep run inside a submitit job (Slurm array task): train, then evaluate.

    Returns the updated run record; the submitting process writes it into the manifest.
    """
    spec = RunSpec(**spec_dict)
    spec.refresh()
    env = pinned_env(threads)
    logf = Path(spec.log or "")
    for what, argv in commands(spec):
        t0 = time.monotonic()
        if spec.log:
            logf.parent.mkdir(parents=True, exist_ok=True)
            with logf.open("a") as fh:
                fh.write(f"\n# {now()} {' '.join(argv)}\n")
                fh.flush()
                rc = subprocess.run(argv, stdout=fh, stderr=subprocess.STDOUT, env=env).returncode
        else:
            rc = subprocess.run(argv, env=env).returncode
        _finish_step(spec, what, rc)
        if what == "train":
            spec.finished, spec.seconds = now(), round(time.monotonic() - t0, 1)
            if spec.state != "done":
                break
    return asdict(spec)


@dataclass
class ClusterOptions:
    """What submitit asks Slurm for, per run (one array task each)."""

    executor: str = "slurm"  # slurm | local | debug (submitit's on-this-machine executors)
    partition: str | None = None
    time_min: int = 24 * 60
    cpus_per_run: int = 1
    gpus_per_run: int = 0
    mem_gb: float | None = None
    array_parallelism: int = 64
    account: str | None = None
    qos: str | None = None
    constraint: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def run_submitit(manifest: Manifest, opts: ClusterOptions, *, wait: bool = True) -> Manifest:
    """Submit every unfinished run as one submitit job array; with ``wait``, collect the results
    into the manifest as the tasks end."""
    import submitit

    todo = [r for r in manifest.runs if commands(r)]
    if not todo:
        return manifest
    folder = manifest.dir / "submitit"
    cluster = None if opts.executor == "slurm" else opts.executor
    ex = submitit.AutoExecutor(folder=folder, cluster=cluster)
    params: dict[str, Any] = {
        "name": f"gcnt-{manifest.dir.name}",
        "timeout_min": opts.time_min,
        "cpus_per_task": opts.cpus_per_run,
        "slurm_array_parallelism": opts.array_parallelism,
    }
    if opts.gpus_per_run:
        params["gpus_per_node"] = opts.gpus_per_run
    if opts.mem_gb:
        params["mem_gb"] = opts.mem_gb
    for key in ("partition", "account", "qos", "constraint"):
        if value := getattr(opts, key):
            params[f"slurm_{key}"] = value
    params.update(opts.extra)
    ex.update_parameters(**params)
    for spec in todo:
        spec.log = str(_log_path(manifest.dir, spec))
    with ex.batch():
        jobs = [ex.submit(run_task, asdict(spec), opts.cpus_per_run) for spec in todo]
    for job, spec in zip(jobs, todo, strict=True):
        spec.job_id, spec.state, spec.started = str(job.job_id), "submitted", now()
    manifest.meta["executor"] = opts.executor
    manifest.save()
    if not wait:
        return manifest
    for job, spec in zip(jobs, todo, strict=True):
        try:
            result = job.result()
        except Exception as e:  # noqa: BLE001 - a failed task: record it, keep collecting
            log.error("run %s (job %s) failed: %s", spec.id, spec.job_id, e)
            spec.state = "failed"
        else:
            job_id = spec.job_id
            for k, v in result.items():
                setattr(spec, k, v)
            spec.job_id = job_id
        manifest.save()
    return manifest
