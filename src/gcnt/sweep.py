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

States: ``pending`` (not started), ``queued`` (a Slurm job waits for its turn), ``running`` (a
process trains it: the run directory's lock is held, or Slurm runs its job), ``requeued`` (its
Slurm job hit the time limit or was preempted, checkpointed and waits to continue), ``partial`` (a
checkpoint, nobody training it), ``cancelled`` (its job was stopped from outside, e.g.
``scancel``), ``done`` (trained; evaluations listed separately), ``failed`` (the last attempt
exited with an error: see its log). A sweep never starts or submits a run that is queued, running
or requeued; every other unfinished run continues with ``gcnt train --resume`` (from step 0 where
it has no checkpoint yet).

On Slurm the manifest stores the executor and its options (``gcnt sweep DIR`` continues on the
same cluster), each job writes its own record (``<sweep>/records/``: start, end, exit code,
evaluations; Slurm's accounting may be off), and the state shown comes from ``squeue`` (or
``sacct``, where accounting exists) while Slurm knows the job. A job stopped by the time limit or
a preemption checkpoints and requeues itself (:class:`SweepTask`, submitit's checkpointing).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import getpass
import json
import logging
import os
import re
import shutil
import signal
import socket
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


#: states where a process or a Slurm job has the run: never started a second time
ACTIVE = ("queued", "running", "requeued")
#: Slurm's job states (``squeue --states=all``, ``sacct``) by what they mean for a run
SLURM_RUNNING = ("RUNNING", "COMPLETING", "CONFIGURING", "STAGE_OUT", "SIGNALING", "SUSPENDED")
SLURM_WAITING = ("PENDING", "RESV_DEL_HOLD", "SPECIAL_EXIT", "STOPPED")
SLURM_REQUEUED = ("REQUEUED", "REQUEUE_FED", "REQUEUE_HOLD", "RESIZING")
SLURM_FAILED = ("FAILED", "NODE_FAIL", "BOOT_FAIL", "OUT_OF_MEMORY", "DEADLINE")
RECORDS = "records"


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

    def files_state(self) -> str:
        """What the run directory shows: ``done``, ``partial`` (a checkpoint), ``started``
        (begun, no checkpoint yet: it continues from step 0) or ``pending`` (never begun)."""
        path = Path(self.run_dir)
        if not (path / RECIPE_FILE).is_file():
            return "pending"
        run = Run(path)
        if run.finished():
            return "done"
        return "partial" if run.has_checkpoint() else "started"

    def refresh(self, slurm: str | None = None, record: dict[str, Any] | None = None) -> None:
        """Set the state from what knows it: Slurm's state of the run's job (``slurm``, from
        :func:`slurm_states`), then the run directory's lock (a process trains it), then the
        job's own record (:func:`read_record`) and the run directory."""
        if record:
            self.take_record(record)
        files = self.files_state()
        if slurm is not None:
            word = slurm.split()[0].rstrip("+")  # "CANCELLED by 0", "RUNNING"
            if word in SLURM_RUNNING:
                self.state = "running"
                return
            if word in SLURM_WAITING:
                # waiting again after it ran (submitit's requeue, scontrol requeue): requeued
                self.state = "requeued" if record or self.state == "requeued" else "queued"
                return
            if word in SLURM_REQUEUED:
                self.state = "requeued"
                return
        from gcnt.rl.run_lock import holder

        if files != "done" and holder(self.run_dir) is not None:
            self.state = "running"
            return
        rec_state = (record or {}).get("state")
        word = (slurm or "").split(" ")[0].rstrip("+")
        if files == "done":
            self.state = "done"
        elif word == "CANCELLED":
            self.state = "cancelled"
        elif rec_state == "failed" or word in SLURM_FAILED:
            self.state = "failed"
        elif word in ("TIMEOUT", "PREEMPTED"):  # ended without requeue: continue it next time
            self.state = files
        elif (
            self.job_id
            and self.state in (*ACTIVE, "cancelled")
            and rec_state in (None, *ACTIVE, "stopped")
        ):
            # the job ended (Slurm no longer lists it) short of the end and without a final
            # record of its own: stopped from outside (scancel, or killed)
            self.state = "cancelled"
        elif self.state == "failed" and rec_state is None:
            pass  # the last attempt failed: see its log
        else:
            self.state = files

    def take_record(self, record: dict[str, Any]) -> None:
        """Times, exit code, evaluations and job id from the job's own record."""
        for key in ("started", "finished", "returncode", "seconds", "job_id"):
            if record.get(key) is not None:
                setattr(self, key, record[key])
        self.eval_state.update(record.get("eval_state") or {})

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
        # once the run directory holds its recipe, --resume continues it: from its checkpoint,
        # or from step 0 when it was stopped before the first one
        if (run_dir / RECIPE_FILE).is_file() or (run_dir / CHECKPOINT).is_file():
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
        """The manifest of ``sweep_dir``, its paths made absolute where the directory is now:
        paths inside the sweep are stored relative to it, so a sweep that was moved or copied
        works where it is (and says so once)."""
        path = Path(sweep_dir) / MANIFEST
        if not path.is_file():
            raise SweepError(f"{sweep_dir}: no {MANIFEST}; is this a sweep directory?")
        try:
            data = json.loads(path.read_text())
            runs = [RunSpec(**r) for r in data.pop("runs")]
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise SweepError(f"{path}: not a sweep manifest ({e})") from None
        here = Path(sweep_dir).absolute()
        was = data.get("location")
        if was and Path(was) != here:
            log.warning(
                "%s: this sweep was written at %s and has been moved or copied; its runs are "
                "continued where it is now", here, was,
            )  # fmt: skip
        for r in runs:
            _relocate(r, lambda p: _here(p, here, Path(was) if was else None))
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

    @property
    def executor(self) -> str:
        """Where the sweep's runs go: ``pool`` (this machine's pool), or a submitit executor."""
        cluster = self.meta.get("cluster") or {"executor": self.meta.get("executor", "pool")}
        return cluster.get("executor", "pool")

    def refresh(self) -> None:
        """Every run's state from Slurm (for a Slurm sweep), the run's lock, its job record and
        its directory (see :meth:`RunSpec.refresh`)."""
        jobs = [r.job_id for r in self.runs if r.job_id]
        slurm = slurm_states(jobs) if jobs and self.executor == "slurm" else {}
        for r in self.runs:
            r.refresh(slurm.get(r.job_id or ""), read_record(self.dir, r))

    def save(self) -> Path:
        self.dir.mkdir(parents=True, exist_ok=True)
        self.meta["updated"] = now()
        here = self.dir.absolute()
        self.meta["location"] = str(here)
        stored = []
        for r in self.runs:
            copy = RunSpec(**asdict(r))
            _relocate(copy, lambda p: _inside(p, here))
            stored.append(asdict(copy))
        data = {**self.meta, "runs": stored}
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
        jobs = any(r.job_id for r in self.runs)
        job_col = f"  {'job':<12}" if jobs else ""
        lines = [f"{'run':<{width}}  {'state':<9}  {'steps':>9}{job_col}  evaluations"]
        for r in self.runs:
            steps = Run(r.run_dir).last_env_steps() if Path(r.run_dir, RECIPE_FILE).is_file() else 0
            ev = ", ".join(f"{k}: {r.eval_state.get(k, 'pending')}" for k in r.evals) or "-"
            job = f"  {r.job_id or '-':<12}" if jobs else ""
            lines.append(f"{r.id:<{width}}  {r.state:<9}  {steps:>9}{job}  {ev}")
        return "\n".join(lines)


def _inside(path: str, base: Path) -> str:
    """``path`` (absolute, or relative to the working folder) relative to ``base`` where it lies
    inside it, else absolute."""
    p = Path(path).absolute()
    try:
        return str(p.relative_to(base))
    except ValueError:
        return str(p)


def _here(path: str, base: Path, was: Path | None) -> str:
    """A stored path made absolute: relative ones against ``base`` (the sweep directory now),
    absolute ones inside ``was`` (where the sweep was saved, for manifests that stored absolute
    paths) moved along with the sweep."""
    p = Path(path)
    if not p.is_absolute():
        # manifests without a location stored paths relative to the working folder
        return str(base / p) if was is not None else path
    if was is not None and was != base:
        try:
            return str(base / p.relative_to(was))
        except ValueError:
            pass
    return path


def _relocate(spec: RunSpec, move: Callable[[str], str]) -> None:
    """Apply ``move`` to the paths of ``spec`` that name places in the sweep: its run
    directory (also in its ``run_dir=`` override) and its log."""
    spec.run_dir = move(spec.run_dir)
    if spec.log:
        spec.log = move(spec.log)
    spec.overrides = [
        f"run_dir={move(o[len('run_dir=') :])}" if o.startswith("run_dir=") else o
        for o in spec.overrides
    ]


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
    from gcnt.rl.stop import EXIT_STOPPED

    if what == "train":
        spec.returncode = rc
        files = spec.files_state()
        if rc == EXIT_STOPPED:  # stopped on request, its checkpoint written: not a failure
            spec.state = files
        elif rc != 0:
            spec.state = "failed"
        else:  # "partial": exited cleanly but short of total_frames
            spec.state = "done" if files == "done" else "partial"
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
    every change. A run another process trains (its lock is held) is left alone. Ctrl-C stops
    the children, which checkpoint first (``gcnt train`` on SIGINT/SIGTERM)."""
    from gcnt.rl.run_lock import holder

    todo = [r for r in manifest.runs if r.state not in ACTIVE and commands(r)]
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
                if (who := holder(spec.run_dir)) is not None:  # another process trains it
                    log.warning("%s: trained by %s; not started", spec.id, who)
                    spec.state = "running"
                    continue
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
            spec.state = spec.files_state()
        manifest.save()
        raise
    return manifest


# ----------------------------------------------------------------------------- job records


def record_path(sweep_dir: str | Path, spec: RunSpec) -> Path:
    return Path(sweep_dir) / RECORDS / f"{spec.id.replace('/', '__')}.json"


def read_record(sweep_dir: str | Path, spec: RunSpec) -> dict[str, Any] | None:
    """What the run's last job wrote about itself (None: no job ran it yet)."""
    try:
        data = json.loads(record_path(sweep_dir, spec).read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return data if isinstance(data, dict) else None


def write_record(sweep_dir: str | Path, spec: RunSpec, state: str, **extra: Any) -> None:
    """The job's record of its run (atomic: the sweep may read it at any time)."""
    path = record_path(sweep_dir, spec)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {
        "state": state,
        "job_id": spec.job_id,
        "started": spec.started,
        "finished": spec.finished,
        "returncode": spec.returncode,
        "seconds": spec.seconds,
        "eval_state": spec.eval_state,
        "host": socket.gethostname(),
        "updated": now(),
        **extra,
    }
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


# ----------------------------------------------------------------------------- Slurm's state


def slurm_states(job_ids: Sequence[str]) -> dict[str, str]:
    """Slurm's state of each job (array tasks as ``123_4``): ``squeue`` knows the jobs in the
    queue and those that ended within the last ``MinJobAge`` seconds; ``sacct`` the older ones,
    where accounting is on. A job neither knows is left out (its record and run directory
    tell)."""
    wanted = {j for j in job_ids if j}
    out: dict[str, str] = {}
    if not wanted or shutil.which("squeue") is None:
        return out
    user = os.environ.get("USER") or getpass.getuser()
    squeue = _slurm_query(["squeue", "-h", "-r", "--states=all", "-u", user, "-o", "%i|%T"])
    if squeue is None:  # never guess: a job taken for gone would be submitted twice
        raise SweepError("squeue failed (is the Slurm controller reachable?); nothing submitted")
    for line in squeue:
        job, _, state = line.partition("|")
        if job in wanted:
            out[job] = state
    rest = sorted(wanted - out.keys())
    if rest and shutil.which("sacct"):
        sacct = ["sacct", "-n", "-P", "-X", "-o", "JobID,State", "-j", ",".join(rest)]
        for line in _slurm_query(sacct) or []:  # none: accounting is off
            job, _, state = line.partition("|")
            if job in wanted:
                out[job] = state
    return out


def _slurm_query(argv: list[str]) -> list[str] | None:
    """The output lines of a Slurm query; None when it fails (accounting off, no controller)."""
    try:
        done = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.splitlines() if done.returncode == 0 else None


# ----------------------------------------------------------------------------- submitit

#: submitit requeues a job stopped by its time limit at most this many times (its default, 3,
#: would end a 10M-step run after four 24-hour slots); preemptions are not counted
MAX_TIMEOUTS = 1000


class SweepTask:
    """One sweep run as a submitit job (Slurm array task): train (``gcnt train``, resumed where
    the run directory has begun), then evaluate; returns the run's record for the manifest.

    Slurm warns a job before its time limit with SIGUSR2 (submitit's ``--signal``); submitit then
    calls :meth:`checkpoint`, which asks ``gcnt train`` to stop (it checkpoints and exits 75),
    waits for it, and returns the same task for submitit to requeue: the next attempt resumes the
    run from that checkpoint. On SIGTERM (``scancel``) ``gcnt train`` checkpoints and stops too;
    the job is not requeued and the run's record says ``stopped``.
    """

    def __init__(self, grace_s: float = 60.0) -> None:
        #: how long :meth:`checkpoint` waits for the training process to write its checkpoint
        self.grace_s = grace_s
        self._proc: subprocess.Popen | None = None

    def __getstate__(self) -> dict[str, Any]:
        return {"grace_s": self.grace_s}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state)

    def __call__(
        self, spec_dict: dict[str, Any], threads: int = 1, sweep_dir: str | None = None
    ) -> dict[str, Any]:
        spec = RunSpec(**spec_dict)
        spec.job_id = _job_id() or spec.job_id
        sweep = Path(sweep_dir) if sweep_dir else Path(spec.run_dir).parent
        env = pinned_env(threads)
        logf = Path(spec.log) if spec.log else None
        previous = read_record(sweep, spec) or {}
        spec.started = previous.get("started") or now()
        spec.state = spec.files_state()
        attempt = int(previous.get("attempt", 0)) + 1
        state = "done"
        for what, argv in commands(spec):
            write_record(sweep, spec, "running", attempt=attempt, step=what)
            t0 = time.monotonic()
            rc = self._run(argv, env, logf)
            _finish_step(spec, what, rc)
            if what == "train":
                spec.finished, spec.seconds = now(), round(time.monotonic() - t0, 1)
                if spec.state != "done":
                    from gcnt.rl.stop import EXIT_STOPPED

                    stopped = rc == EXIT_STOPPED or rc < 0
                    state = "stopped" if stopped else spec.state
                    break
        if state == "done" and "failed" in spec.eval_state.values():
            state = "failed"
        write_record(sweep, spec, state, attempt=attempt)
        return asdict(spec)

    def _run(self, argv: list[str], env: dict[str, str], logf: Path | None) -> int:
        """Run one step, waiting by polling: a blocking wait would keep :meth:`checkpoint`
        (called from submitit's signal handler in this thread) from seeing the process end."""
        out = None
        if logf is not None:
            logf.parent.mkdir(parents=True, exist_ok=True)
            out = logf.open("a")
            out.write(f"\n# {now()} {' '.join(argv)}\n")
            out.flush()
        try:
            # SIGUSR2 ignored until gcnt train installs its handler: the default would kill a
            # process still starting; checkpoint() repeats the signal until it is heard
            self._proc = subprocess.Popen(
                argv,
                stdout=out,
                stderr=subprocess.STDOUT if out else None,
                env=env,
                preexec_fn=lambda: signal.signal(signal.SIGUSR2, signal.SIG_IGN),
            )
            while (rc := self._proc.poll()) is None:
                time.sleep(0.5)
            return rc
        finally:
            if out is not None:
                out.close()

    def checkpoint(self, *args: Any, **kwargs: Any):
        """Called by submitit on SIGUSR2 (time limit near, or preemption): stop ``gcnt train``
        with its checkpoint, then the same task again, for submitit to requeue."""
        from submitit.helpers import DelayedSubmission

        proc, t0 = self._proc, time.monotonic()
        while proc is not None and proc.poll() is None and time.monotonic() - t0 < self.grace_s:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGUSR2)  # gcnt train checkpoints and exits
            for _ in range(10):
                if proc.poll() is not None:
                    break
                time.sleep(0.5)
        if proc is not None and proc.poll() is None:
            proc.kill()  # out of time: the run resumes from its last scheduled checkpoint
            proc.wait()
        spec = RunSpec(**(args[0] if args else kwargs["spec_dict"]))
        sweep = args[2] if len(args) > 2 else kwargs.get("sweep_dir")
        if sweep:
            record = read_record(sweep, spec) or {}
            spec.started, spec.job_id = record.get("started"), _job_id()
            write_record(sweep, spec, "requeued", attempt=record.get("attempt", 1))
        return DelayedSubmission(SweepTask(self.grace_s), *args, **kwargs)


def _job_id() -> str | None:
    """This Slurm job's id as squeue shows it (``123_4`` for an array task)."""
    array, task = os.environ.get("SLURM_ARRAY_JOB_ID"), os.environ.get("SLURM_ARRAY_TASK_ID")
    if array and task:
        return f"{array}_{task}"
    return os.environ.get("SLURM_JOB_ID")


def run_task(spec_dict: dict[str, Any], threads: int = 1) -> dict[str, Any]:
    """One sweep run in this process (train, then evaluate): :class:`SweepTask` without a
    scheduler."""
    return SweepTask()(spec_dict, threads)


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
    #: seconds before the time limit at which Slurm sends SIGUSR2 (submitit's default, 90)
    signal_delay_s: int = 90
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ClusterOptions:
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in data.items() if k in known})


def submitit_log(sweep_dir: Path) -> Path:
    """Route submitit's log lines (its sacct fallbacks, job states, tracebacks of jobs) to
    ``<sweep>/submitit/submitit.log`` instead of the terminal."""
    path = sweep_dir / "submitit" / "submitit.log"
    path.parent.mkdir(parents=True, exist_ok=True)
    logger = logging.getLogger("submitit")
    for h in list(logger.handlers):
        if not (isinstance(h, logging.FileHandler) and Path(h.baseFilename) == path.resolve()):
            logger.removeHandler(h)
            if isinstance(h, logging.FileHandler):
                h.close()
    if not logger.handlers:
        handler = logging.FileHandler(path)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
        logger.addHandler(handler)
    logger.propagate = False
    return path


def run_submitit(
    manifest: Manifest,
    opts: ClusterOptions,
    *,
    wait: bool = True,
    poll: float = 5.0,
    on_change: Callable[[RunSpec], None] | None = None,
) -> Manifest:
    """Submit every unfinished run that no job has (queued, running or requeued ones are left
    alone) as one submitit job array; with ``wait``, follow the runs' states until none is
    active. The executor and its options are stored in the manifest."""
    import submitit

    manifest.meta["cluster"] = asdict(opts)
    manifest.refresh()
    todo = [r for r in manifest.runs if r.state not in ACTIVE and commands(r)]
    if todo:
        submitit_log(manifest.dir)
        folder = manifest.dir / "submitit"
        cluster = None if opts.executor == "slurm" else opts.executor
        kwargs = {"slurm_max_num_timeout": MAX_TIMEOUTS} if opts.executor == "slurm" else {}
        ex = submitit.AutoExecutor(folder=folder, cluster=cluster, **kwargs)
        params: dict[str, Any] = {
            "name": f"gcnt-{manifest.dir.name}",
            "timeout_min": opts.time_min,
            "cpus_per_task": opts.cpus_per_run,
            "slurm_array_parallelism": opts.array_parallelism,
            "slurm_signal_delay_s": opts.signal_delay_s,
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
            record_path(manifest.dir, spec).unlink(missing_ok=True)  # a fresh job, a fresh record
        task = SweepTask(grace_s=max(10, opts.signal_delay_s - 30))
        with ex.batch():
            jobs = [
                ex.submit(task, asdict(spec), opts.cpus_per_run, str(manifest.dir)) for spec in todo
            ]
        for job, spec in zip(jobs, todo, strict=True):
            spec.job_id, spec.state = str(job.job_id), "queued"
            spec.started = spec.finished = spec.returncode = spec.seconds = None
            if on_change:
                on_change(spec)
    manifest.save()
    if opts.executor != "slurm":
        # submitit's local executors: wait on the jobs themselves (no squeue to ask)
        for job in jobs if todo else []:
            if wait:
                with contextlib.suppress(Exception):  # a failed job: its record and log tell
                    job.result()
        manifest.refresh()
        manifest.save()
        return manifest
    while wait and any(r.state in ACTIVE for r in manifest.runs):
        time.sleep(poll)
        before = {r.id: r.state for r in manifest.runs}
        manifest.refresh()
        manifest.save()
        for r in manifest.runs:
            if on_change and r.state != before[r.id]:
                on_change(r)
    return manifest
