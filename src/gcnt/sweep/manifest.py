"""``<sweep>/manifest.json`` (:class:`Manifest`), written atomically with paths inside the sweep
stored relative to it, with the code, packages and command of each session that ran the sweep
(``provenance``), and the sweep's lock (:class:`SweepLock`: one ``gcnt sweep`` per sweep)."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from gcnt.files import (
    KiB,
    MiB,
    NotRegularFileError,
    check_replaceable,
    read_json,
    read_text,
    write_text,
)
from gcnt.run.data import RECIPE_FILE, Run
from gcnt.sweep.spec import RunSpec
from gcnt.sweep.status import SweepError, now, read_record, slurm_states

log = logging.getLogger(__name__)


MANIFEST = "manifest.json"


LOCK = ".sweep.lock"
#: the largest manifest read
MAX_MANIFEST_BYTES = 256 * MiB


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
        data = read_json(path, MAX_MANIFEST_BYTES, "a sweep manifest is JSON", SweepError)
        try:
            runs = [RunSpec(**r) for r in data.pop("runs")]
        except (AttributeError, KeyError, TypeError) as e:
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
            _check_inside(r, here, path)
        return cls(sweep_dir, runs, data)

    def record_session(self) -> None:
        """Add this process's session (code, packages, machine, command:
        :func:`gcnt.run.provenance.collect`) to the manifest's ``provenance`` (saved with it)."""
        from gcnt.run import provenance

        kept = self.meta.get("provenance")
        sessions = kept.get("sessions") if isinstance(kept, dict) else None
        sessions = sessions if isinstance(sessions, list) else []
        self.meta["provenance"] = {"sessions": [*sessions, provenance.collect()]}

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
        write_text(self.path, json.dumps(data, indent=1))
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


def _check_inside(spec: RunSpec, sweep: Path, manifest: Path) -> None:
    """A received sweep trains, resumes and logs inside itself only: every place a run of its
    manifest names (its run directory, its ``run_dir=`` override, its log) must lie inside the
    sweep directory once links are followed, else a SweepError naming the run and the place."""
    root = sweep.resolve()
    named = [
        spec.run_dir,
        *(o[len("run_dir=") :] for o in spec.overrides if o.startswith("run_dir=")),
    ]
    if spec.log:
        named.append(spec.log)
    for place in named:
        try:
            inside = Path(place).resolve().is_relative_to(root)
        except (OSError, RuntimeError):  # a link loop
            inside = False
        if not inside:
            raise SweepError(
                f"{manifest}: run {spec.id} names {place}, outside the sweep directory {root} "
                "(a sweep trains and logs inside itself only)"
            )


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

    def driver(self) -> int | None:
        """The pid of the live process on this host that drives the sweep now (None: none)."""
        if not self.path.exists():
            return None
        try:
            pid = int(read_text(self.path, KiB, "a sweep lock holds a process id", SweepError))
            os.kill(pid, 0)
        except (ValueError, ProcessLookupError, OverflowError):
            return None
        except PermissionError:
            return pid
        return pid

    def __enter__(self) -> SweepLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            check_replaceable(self.path)  # a link or a FIFO is refused, not read or replaced
        except NotRegularFileError as e:
            raise SweepError(
                f"{e}; it should hold the pid of the process driving the sweep"
            ) from None
        if self.path.exists():
            try:
                pid = int(read_text(self.path, KiB, "a sweep lock holds a process id", SweepError))
                os.kill(pid, 0)
            except (ValueError, ProcessLookupError, OverflowError):
                pass  # stale
            except PermissionError:
                raise SweepError(f"{self.path.parent}: another process drives this sweep") from None
            else:
                if pid != os.getpid():
                    raise SweepError(
                        f"{self.path.parent}: the sweep is being run by process {pid} "
                        f"(remove {self.path} if that is wrong)"
                    )
        write_text(self.path, str(os.getpid()))
        return self

    def __exit__(self, *exc: object) -> None:
        self.path.unlink(missing_ok=True)
