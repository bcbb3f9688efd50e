"""Slurm through submitit: one job array, one run per task; a task that hits the time limit or is
preempted checkpoints and requeues itself (:class:`SweepTask`)."""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from gcnt.files import open_append
from gcnt.sweep.local import finish_step, pinned_env, run_log_path
from gcnt.sweep.manifest import Manifest
from gcnt.sweep.spec import RunSpec, commands
from gcnt.sweep.status import ACTIVE, now, read_record, record_path, write_record

#: submitit requeues a job stopped by its time limit at most this many times (its default, 3,
#: would end a 10M-step run after four 24-hour slots); preemptions are not counted
MAX_TIMEOUTS = 1000


def _session_plugins() -> list[str]:
    from gcnt import plugins

    return plugins.session()


class SweepTask:
    """One sweep run as a submitit job (Slurm array task): train (``gcnt train``, resumed where
    the run directory has begun), then evaluate; returns the run's record for the manifest.

    Slurm warns a job before its time limit with SIGUSR2 (submitit's ``--signal``); submitit then
    calls :meth:`checkpoint`, which asks ``gcnt train`` to stop (it checkpoints and exits 75),
    waits for it, and returns the same task for submitit to requeue: the next attempt resumes the
    run from that checkpoint. On SIGTERM (``scancel``) ``gcnt train`` checkpoints and stops too;
    the job is not requeued and the run's record says ``stopped``.
    """

    def __init__(self, grace_s: float = 60.0, plugins: list[str] | None = None) -> None:
        #: how long :meth:`checkpoint` waits for the training process to write its checkpoint
        self.grace_s = grace_s
        #: the plugins of the command that submitted the sweep, which its runs import
        self.plugins = _session_plugins() if plugins is None else list(plugins)
        self._proc: subprocess.Popen | None = None

    def __getstate__(self) -> dict[str, Any]:
        return {"grace_s": self.grace_s, "plugins": self.plugins}

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
        for what, argv in commands(spec, self.plugins):
            write_record(sweep, spec, "running", attempt=attempt, step=what)
            t0 = time.monotonic()
            rc = self._run(argv, env, logf)
            finish_step(spec, what, rc)
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
            out = open_append(logf)
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
        return DelayedSubmission(SweepTask(self.grace_s, self.plugins), *args, **kwargs)


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


class _LogFile(logging.FileHandler):
    """A log file opened as every log of gcnt is (:func:`gcnt.files.open_append`)."""

    def _open(self):
        return open_append(self.baseFilename)


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
        handler = _LogFile(path, delay=True)
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
    from gcnt.extras import require

    submitit = require("submitit", f"gcnt sweep --executor {opts.executor}")

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
            spec.log = str(run_log_path(manifest.dir, spec))
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
