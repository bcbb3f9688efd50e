"""What a sweep knows of its runs' states: the states, Slurm's job states by what they mean
for a run, ``squeue`` / ``sacct`` queries, and the record each job writes of itself
(``<sweep>/records/``)."""

from __future__ import annotations

import datetime as _dt
import getpass
import json
import os
import re
import shutil
import socket
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

from gcnt.files import MiB, read_json, write_text


class RecordedRun(Protocol):
    """What a run's record is written from (:class:`gcnt.sweep.spec.RunSpec` has it): the state
    module reads these fields and knows nothing else of a run spec."""

    id: str
    job_id: str | None
    started: str | None
    finished: str | None
    returncode: int | None
    seconds: float | None
    eval_state: dict[str, str]


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


def record_path(sweep_dir: str | Path, spec: RecordedRun) -> Path:
    return Path(sweep_dir) / RECORDS / f"{spec.id.replace('/', '__')}.json"


def read_record(sweep_dir: str | Path, spec: RecordedRun) -> dict[str, Any] | None:
    """What the run's last job wrote about itself (None: no job ran it yet)."""
    path = record_path(sweep_dir, spec)
    if not path.exists():
        return None
    try:
        data = read_json(path, MiB, "a run's record is JSON", SweepError)
    except SweepError:
        return None
    return data if isinstance(data, dict) else None


def write_record(sweep_dir: str | Path, spec: RecordedRun, state: str, **extra: Any) -> None:
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
    write_text(path, json.dumps(data, indent=1))


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
