"""One run of a sweep (:class:`RunSpec`): what the manifest records of it, how its state is
read (Slurm, the run directory's lock, its record, its files) and the ``gcnt`` commands left to
run for it."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gcnt.run.data import CHECKPOINT, RECIPE_FILE, Run
from gcnt.sweep.status import ACTIVE, SLURM_FAILED, SLURM_REQUEUED, SLURM_RUNNING, SLURM_WAITING


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
        from gcnt.run.lock import holder

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


def gcnt_command(named: list[str] | None = None) -> list[str]:
    """The ``gcnt`` command of this interpreter (works on a cluster node with the same venv),
    with this command's plugins (``--plugin``, GCNT_PLUGINS, a given recipe's): a sweep's runs
    import what the command that runs them names, never what a manifest or recipe records
    (``named``: those plugins, where the command runs elsewhere: a Slurm job)."""
    from gcnt import plugins

    named = plugins.session() if named is None else named
    return [sys.executable, "-m", "gcnt.cli", *(w for p in named for w in ("--plugin", p))]


#: the last override of a sweep's ``gcnt train RECIPE``: the recipe file's own ``plugins:`` are
#: not imported by the run (the sweep's command names them: :func:`gcnt_command`)
NO_RECIPE_PLUGINS = "plugins=[]"


def commands(spec: RunSpec, plugins: list[str] | None = None) -> list[tuple[str, list[str]]]:
    """What is left to do for ``spec``: ("train", argv) then ("eval:SPEC", argv) per evaluation
    (``plugins``: what the commands name, default this command's: :func:`gcnt_command`)."""
    out: list[tuple[str, list[str]]] = []
    run_dir = Path(spec.run_dir)
    if spec.state != "done":
        # once the run directory holds its recipe, --resume continues it: from its checkpoint,
        # or from step 0 when it was stopped before the first one
        if (run_dir / RECIPE_FILE).is_file() or (run_dir / CHECKPOINT).is_file():
            out.append(("train", [*gcnt_command(plugins), "train", "--resume", spec.run_dir]))
        else:
            out.append(
                (
                    "train",
                    [
                        *gcnt_command(plugins),
                        "train",
                        spec.recipe,
                        *spec.overrides,
                        NO_RECIPE_PLUGINS,
                    ],
                )
            )
    for robots in spec.pending_evals():
        out.append((f"eval:{robots}", eval_command(spec, robots, plugins)))
    return out


def eval_command(spec: RunSpec, robots: str, plugins: list[str] | None = None) -> list[str]:
    """``gcnt eval RUN --robots ROBOTS``, with ``--episodes`` and ``--deterministic`` or
    ``--stochastic`` only where the sweep sets them (else the run's recipe decides)."""
    argv = [*gcnt_command(plugins), "eval", spec.run_dir, "--robots", robots]
    if spec.eval_episodes is not None:
        argv += ["--episodes", str(spec.eval_episodes)]
    if spec.eval_deterministic is not None:
        argv.append("--deterministic" if spec.eval_deterministic else "--stochastic")
    return argv
