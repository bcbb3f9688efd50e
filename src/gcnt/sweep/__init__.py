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

States: ``pending`` (never started), ``queued`` (a Slurm job waits for its turn), ``running`` (a
process trains it: the run directory's lock is held, or Slurm runs its job), ``requeued`` (its
Slurm job hit the time limit or was preempted, checkpointed and waits to continue), ``started``
(begun, no checkpoint yet, nobody training it), ``partial`` (a checkpoint, nobody training it), ``cancelled`` (its job was stopped from outside, e.g.
``scancel``), ``done`` (trained; evaluations listed separately), ``failed`` (the last attempt
exited with an error: see its log). A sweep never starts or submits a run that is queued, running
or requeued; every other unfinished run continues with ``gcnt train --resume`` (from step 0 where
it has no checkpoint yet).

On Slurm the manifest stores the executor and its options (``gcnt sweep DIR`` continues on the
same cluster), each job writes its own record (``<sweep>/records/``: start, end, exit code,
evaluations; Slurm's accounting may be off), and the state shown comes from ``squeue`` (or
``sacct``, where accounting exists) while Slurm knows the job. A job stopped by the time limit or
a preemption checkpoints and requeues itself (:class:`SweepTask`, submitit's checkpointing).

The package, one module per concern, each readable on its own:

* :mod:`gcnt.sweep.status`: the states, Slurm's job states, ``squeue``/``sacct``, job records;
* :mod:`gcnt.sweep.spec`: one run (:class:`RunSpec`), its state and its commands;
* :mod:`gcnt.sweep.grid`: the grid of runs a sweep expands into;
* :mod:`gcnt.sweep.manifest`: the manifest (relocatable) and the sweep's lock;
* :mod:`gcnt.sweep.local`: the local pool of pinned slots;
* :mod:`gcnt.sweep.slurm`: Slurm through submitit, with requeue.
"""

from __future__ import annotations

from gcnt.sweep.grid import default_dir, expand, per_robot_runs, robot_overrides
from gcnt.sweep.local import (
    THREAD_VARS,
    available_cores,
    default_jobs,
    pinned_env,
    run_local,
    slot_cores,
)
from gcnt.sweep.manifest import LOCK, MANIFEST, Manifest, SweepLock
from gcnt.sweep.slurm import (
    MAX_TIMEOUTS,
    ClusterOptions,
    SweepTask,
    run_submitit,
    run_task,
    submitit_log,
)
from gcnt.sweep.spec import RunSpec, commands, eval_command, gcnt_command
from gcnt.sweep.status import (
    ACTIVE,
    RECORDS,
    SLURM_FAILED,
    SLURM_REQUEUED,
    SLURM_RUNNING,
    SLURM_WAITING,
    SweepError,
    now,
    read_record,
    record_path,
    slug,
    slurm_states,
    write_record,
)

__all__ = [
    "ACTIVE",
    "ClusterOptions",
    "LOCK",
    "MANIFEST",
    "MAX_TIMEOUTS",
    "Manifest",
    "RECORDS",
    "RunSpec",
    "SLURM_FAILED",
    "SLURM_REQUEUED",
    "SLURM_RUNNING",
    "SLURM_WAITING",
    "SweepError",
    "SweepLock",
    "SweepTask",
    "THREAD_VARS",
    "available_cores",
    "commands",
    "default_dir",
    "default_jobs",
    "eval_command",
    "expand",
    "gcnt_command",
    "now",
    "per_robot_runs",
    "pinned_env",
    "read_record",
    "record_path",
    "robot_overrides",
    "run_local",
    "run_submitit",
    "run_task",
    "slot_cores",
    "slug",
    "slurm_states",
    "submitit_log",
    "write_record",
]
