"""``gcnt sweep``: grid expansion, pinning, the manifest; a tiny real sweep run locally, resumed,
evaluated and read back from W&B's offline files; the submitit path with its debug executor."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from cli_helpers import TINY_SWEEP_OVERRIDES

from gcnt import sweep as S
from gcnt.analysis.runs import Run, find_runs
from gcnt.cli import main

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "recipes" / "quickstart.yaml"
TINY = TINY_SWEEP_OVERRIDES


def test_expand_gives_every_run_an_explicit_dir_and_the_sweep_group(tmp_path: Path) -> None:
    specs = S.expand(
        [QUICKSTART],
        tmp_path / "sw",
        methods=["gcnt", "swat"],
        seeds=[0, 1],
        overrides=[*TINY, "swat:network.kwargs={d_model: 9, layers: 1, ff: 16, heads: 3}"],
        evals=["test"],
    )
    assert [(s.method, s.seed) for s in specs] == [
        ("gcnt", 0),
        ("gcnt", 1),
        ("swat", 0),
        ("swat", 1),
    ]
    s = specs[-1]
    assert s.run_dir == str((tmp_path / "sw" / s.id).resolve())
    assert s.id.endswith("/td3-swat/seed1")
    assert f"run_dir={s.run_dir}" in s.overrides
    assert 'logger.group="sw/quickstart/td3-swat"' in s.overrides
    # a method-specific override reaches that method only, after the shared ones
    assert "network.kwargs={d_model: 9, layers: 1, ff: 16, heads: 3}" in s.overrides
    assert not any("d_model: 9" in o for o in specs[0].overrides)
    # the recipe file's own plugins are not the run's to import: the sweep command names them
    assert S.commands(s)[0][1][-len(s.overrides) - 1 :] == [*s.overrides, "plugins=[]"]
    with pytest.raises(S.SweepError, match="nope"):
        S.expand([QUICKSTART], tmp_path, overrides=["nope:seed=1"], methods=["gcnt"])
    with pytest.raises(S.SweepError, match="missing.yaml"):
        S.expand([tmp_path / "missing.yaml"], tmp_path)
    with pytest.raises(S.SweepError, match="unknown recipe key"):
        S.expand([QUICKSTART], tmp_path, overrides=["colector.total_frames=1"])


def test_slots_are_pinned_to_disjoint_cores() -> None:
    assert S.slot_cores(2, 1, [0, 1]) == [[0], [1]]
    assert S.slot_cores(2, 2, [0, 1, 2, 3]) == [[0, 1], [2, 3]]
    assert S.slot_cores(3, 1, [4, 5]) == [[4], [5], [4]]  # more slots than cores: shared
    assert S.default_jobs(1, [0, 1]) == 2 and S.default_jobs(4, [0, 1]) == 1
    env = S.pinned_env(3, {})
    assert all(env[v] == "3" for v in S.THREAD_VARS)


def test_bad_sweep_input_exits_2(tmp_path: Path) -> None:
    assert main(["sweep", str(tmp_path / "nope.yaml")]) == 2
    assert main(["sweep", str(tmp_path)]) == 2  # a directory without a manifest
    assert main(["sweep", str(QUICKSTART), "colector.total_frames=1", "--dir", str(tmp_path)]) == 2


def _leet(run_dir: Path, *flags: str) -> str:
    """``wandb leet inspect`` of a run's offline W&B files (no network)."""
    wandb = shutil.which("wandb") or str(Path(sys.executable).parent / "wandb")
    (offline,) = (run_dir / "wandb").glob("offline-run-*")
    return subprocess.run(
        [wandb, "leet", "inspect", *flags, "--json", str(offline)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout


@pytest.mark.slow
def test_tiny_local_sweep_runs_resumes_evaluates_and_logs_to_wandb(tmp_path: Path) -> None:
    sw = tmp_path / "sw"
    argv = ["sweep", str(QUICKSTART), "--seeds", "0,1", "--jobs", "2", "--dir", str(sw), *TINY]
    assert main([*argv, "--eval", "test", "--episodes", "2"]) == 0
    manifest = json.loads((sw / S.MANIFEST).read_text())
    assert [r["state"] for r in manifest["runs"]] == ["done", "done"]
    assert all(r["eval_state"] == {"test": "done"} for r in manifest["runs"])
    runs = find_runs([sw])
    assert [r.seed for r in runs] == [0, 1] and all(r.finished() for r in runs)
    assert all(r.path.parent.parent.parent == sw for r in runs)
    # the test evaluation ran through `gcnt eval` and is readable
    assert any("hopper_4" in e.robots for e in runs[0].evals())

    # W&B (offline): one group per task and method of the sweep; method, task, seed and
    # algorithm in the config; the training metrics arrived
    records = [json.loads(x) for x in _leet(runs[1].path).splitlines() if x.startswith("{")]
    run_rec = next(r["run"] for r in records if r["type"] == "run")
    assert run_rec["run_group"] == "sw/quickstart/td3-gcnt"
    config = json.loads(_leet(runs[1].path, "--summary"))["config"]
    assert config["seed"] == 1 and config["network"]["name"] == "gcnt"
    assert (config.get("task") or config.get("benchmark")) and config.get("algo", "td3") == "td3"
    history = [r["history"]["item"] for r in records if r["type"] == "history"]
    assert any("train_return/mean" in h for h in history)

    # again: nothing to do (the logs do not grow)
    logs = {p: p.stat().st_size for p in (sw / "logs").iterdir()}
    assert main(argv) == 0
    assert {p: p.stat().st_size for p in (sw / "logs").iterdir()} == logs

    # a longer budget makes run 0 unfinished: the sweep resumes it from its checkpoint
    recipe_file = runs[0].path / "recipe.yaml"
    recipe = yaml.safe_load(recipe_file.read_text())
    recipe["collector"]["total_frames"] = 400
    recipe_file.write_text(yaml.safe_dump(recipe))
    assert not Run(runs[0].path).finished()
    assert main(["sweep", str(sw)]) == 0
    assert Run(runs[0].path).last_env_steps() >= 400
    log = Path(S.Manifest.load(sw).runs[0].log).read_text()
    assert "train --resume" in log
    assert main(["sweep", str(sw), "--status"]) == 0


@pytest.mark.slow
def test_submitit_debug_executor(tmp_path: Path) -> None:
    pytest.importorskip("submitit")
    sw = tmp_path / "sl"
    argv = ["sweep", str(QUICKSTART), "--executor", "debug", "--dir", str(sw), *TINY]
    assert main([*argv, "logger.backend=none"]) == 0
    (run,) = S.Manifest.load(sw).runs
    assert run.state == "done" and run.job_id
    assert Run(run.run_dir).finished()
    assert (sw / "submitit").is_dir()


def _spec(tmp_path: Path, **kw) -> S.RunSpec:
    run_dir = tmp_path / "sw" / "run"  # a sweep's runs lie inside it
    base = dict(id="t/td3-gcnt/seed0", run_dir=str(run_dir), recipe=str(QUICKSTART), task="t")
    base.update(algo="td3", method="gcnt", seed=0, overrides=[f"run_dir={run_dir}"])
    return S.RunSpec(**{**base, **kw})


def test_commands_continue_a_run_from_any_point(tmp_path: Path) -> None:
    spec = _spec(tmp_path)
    never = S.commands(spec)[0][1]
    assert "--resume" not in never and never[-2:] == [f"run_dir={spec.run_dir}", "plugins=[]"]
    run = Path(spec.run_dir)
    (run / "checkpoints").mkdir(parents=True)
    shutil.copy(QUICKSTART, run / "recipe.yaml")  # stopped before its first checkpoint
    assert S.commands(spec)[0][1][-3:] == ["train", "--resume", spec.run_dir]
    (run / "checkpoints" / "last.pt").write_bytes(b"")
    assert S.commands(spec)[0][1][-3:] == ["train", "--resume", spec.run_dir]
    spec.state = "done"
    assert S.commands(spec) == []


@pytest.mark.parametrize(
    ("before", "slurm", "record", "after"),
    [
        ("queued", "PENDING", None, "queued"),
        ("queued", "PENDING", {"state": "requeued"}, "requeued"),  # waits again after it ran
        ("queued", "RUNNING", {"state": "running"}, "running"),
        ("running", "REQUEUED", {"state": "running"}, "requeued"),
        ("running", "CANCELLED by 0", {"state": "stopped"}, "cancelled"),
        ("running", "FAILED", None, "failed"),
        ("running", "COMPLETED", {"state": "failed", "returncode": 1}, "failed"),
        ("running", None, {"state": "stopped"}, "cancelled"),  # Slurm forgot the job
        ("queued", None, None, "cancelled"),  # gone without running
        ("running", "TIMEOUT", {"state": "running"}, "pending"),  # no checkpoint: from step 0
    ],
)
def test_a_slurm_run_state_comes_from_slurm_then_its_record(
    tmp_path: Path, before, slurm, record, after
) -> None:
    spec = _spec(tmp_path, state=before, job_id="7_0")
    spec.refresh(slurm, record)
    assert spec.state == after
    if record and "returncode" in record:
        assert spec.returncode == record["returncode"]


def test_slurm_states_never_guess_when_squeue_fails(tmp_path: Path, monkeypatch) -> None:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    squeue = bin_dir / "squeue"
    squeue.write_text("#!/bin/sh\necho '7_0|RUNNING'\necho '7_1|PENDING'\necho '8|RUNNING'\n")
    squeue.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}:/usr/bin:/bin")
    assert S.slurm_states(["7_0", "7_1"]) == {"7_0": "RUNNING", "7_1": "PENDING"}
    squeue.write_text("#!/bin/sh\necho 'slurm_load_jobs error' >&2\nexit 1\n")
    with pytest.raises(S.SweepError, match="squeue failed"):
        S.slurm_states(["7_0"])


def test_a_task_at_the_time_limit_stops_its_trainer_and_resubmits_itself(tmp_path: Path) -> None:
    """submitit's checkpoint(): SIGUSR2 to `gcnt train` (here a stand-in that exits 75 on it),
    wait, record "requeued", return the same task for submitit to requeue."""
    pytest.importorskip("submitit")
    import signal

    sweep = tmp_path / "sw"
    spec = _spec(tmp_path, job_id="7_0")
    task = S.SweepTask(grace_s=20)
    stand_in = (
        "import signal, sys; "
        "signal.signal(signal.SIGUSR2, lambda *a: sys.exit(75)); print('up', flush=True); "
        "signal.pause()"  # until the signal: nothing waits out a fixed sleep
    )
    task._proc = subprocess.Popen([sys.executable, "-c", stand_in], stdout=subprocess.PIPE)
    assert task._proc.stdout.readline().strip() == b"up"
    S.write_record(sweep, spec, "running", attempt=1)
    args = (dataclasses.asdict(spec), 1, str(sweep))
    again = task.checkpoint(*args)
    assert task._proc.returncode == 75
    assert isinstance(again.function, S.SweepTask) and again.args == args
    assert S.read_record(sweep, spec)["state"] == "requeued"
    assert signal.getsignal(signal.SIGUSR2) is not None  # the caller's handlers are untouched


def test_submitit_logs_go_to_the_sweep_not_the_terminal(tmp_path: Path, capsys) -> None:
    import logging

    path = S.submitit_log(tmp_path)
    logging.getLogger("submitit").warning("Bypassing sacct error")
    assert "Bypassing" not in capsys.readouterr().err
    for h in logging.getLogger("submitit").handlers:
        h.flush()
    assert "Bypassing sacct error" in path.read_text()


def test_a_begun_run_without_a_checkpoint_is_started_not_pending(tmp_path: Path) -> None:
    spec = _spec(tmp_path)
    assert spec.files_state() == "pending"
    run = Path(spec.run_dir)
    run.mkdir(parents=True)
    (run / "recipe.yaml").write_text(QUICKSTART.read_text())
    spec.refresh()
    assert spec.state == "started"
    assert "--resume" in S.commands(spec)[0][1]  # it continues, from step 0


def test_a_moved_or_copied_sweep_works_where_it_is(tmp_path: Path, capsys) -> None:
    """Paths inside a sweep are stored relative to it: after ``mv`` (or a copy) its runs, logs
    and ``run_dir=`` overrides are where the sweep is now, and the move is said once."""
    first = tmp_path / "first"
    assert main(["sweep", str(QUICKSTART), "--dir", str(first), "--dry-run", *TINY]) == 0
    stored = json.loads((first / S.MANIFEST).read_text())
    assert stored["location"] == str(first)
    assert not any(Path(r["run_dir"]).is_absolute() for r in stored["runs"])
    moved = tmp_path / "moved"
    shutil.move(first, moved)
    copied = tmp_path / "copied"
    shutil.copytree(moved, copied)
    for where in (moved, copied):
        capsys.readouterr()
        runs = S.Manifest.load(where).runs
        assert "has been moved or copied" in capsys.readouterr().err
        for r in runs:
            assert Path(r.run_dir).is_relative_to(where)
            (o,) = [o for o in r.overrides if o.startswith("run_dir=")]
            assert o == f"run_dir={r.run_dir}"
    # a manifest written with absolute paths (before they were stored relative) moves too
    data = json.loads((copied / S.MANIFEST).read_text())
    for r in data["runs"]:
        r["run_dir"] = str(first / r["run_dir"])
    data["location"] = str(first)
    (copied / S.MANIFEST).write_text(json.dumps(data))
    assert all(Path(r.run_dir).is_relative_to(copied) for r in S.Manifest.load(copied).runs)


def test_every_value_of_the_grid_is_checked_when_the_sweep_is_set_up(tmp_path, capsys):
    """Methods, per-method sizes, robots and the robots evaluated after training: a mistake is
    one line before any run starts (no manifest written), not a failure per run."""
    from cli_helpers import error_line

    sw = tmp_path / "sw"
    argv = ["sweep", str(QUICKSTART), "--dir", str(sw), "--dry-run", *TINY]
    line = error_line(capsys, [*argv, "--methods", "gcnt,swta"])
    assert "quickstart.yaml (method swta): network: unknown network 'swta'" in line
    assert "did you mean 'swat'?" in line
    line = error_line(capsys, [*argv, "--methods", "gcnt,swat", "swat:network.kwargs.ff=0"])
    assert "(method swat): network: SWATConfig.ff must be a positive int" in line
    line = error_line(capsys, [*argv, "env.test_robots=[hopper_3]"])
    assert "env.robots and env.test_robots both list hopper_3" in line
    line = error_line(capsys, [*argv, "--eval", "hopper_44"])
    assert "hopper_44" in line and "did you mean 'hopper_4'" in line
    line = error_line(capsys, [*argv, "env.test_robots=[]", "--eval", "test"])
    assert "--eval test: the recipe has no test robots" in line
    assert not sw.exists()
    assert main([*argv, "--methods", "gcnt,swat", "--eval", "test"]) == 0


_STAND_IN = """
import os, signal, sys, time
from pathlib import Path
here = Path(sys.argv[1])
def stop(*_):
    time.sleep(1)  # a checkpoint being written
    (here / "stopped").write_text("x")
    sys.exit(75)
signal.signal(signal.SIGTERM, stop)
(here / "started").write_text(str(os.getpid()))
signal.pause()  # until the SIGTERM
"""

_DRIVER = """
import sys
from pathlib import Path
import gcnt.sweep.local as L
from gcnt.sweep.manifest import Manifest
from gcnt.sweep.spec import RunSpec
here = Path(sys.argv[1])
L.commands = lambda spec: [("train", [sys.executable, "-c", sys.argv[2], str(here)])]
spec = RunSpec(id="t/m/seed0", run_dir=str(here / "run"), recipe="r.yaml", task="t", algo="ppo",
               method="m", seed=0, overrides=[])
try:
    L.run_local(Manifest(here, [spec], {}), jobs=1, poll=0.1)
except KeyboardInterrupt as e:
    print(e, flush=True)
    sys.exit(143)
"""


def test_sigterm_to_a_local_sweep_stops_its_children_first(tmp_path: Path) -> None:
    import os
    import signal
    import time

    proc = subprocess.Popen(
        [sys.executable, "-c", _DRIVER, str(tmp_path), _STAND_IN],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    started = tmp_path / "started"
    try:
        t0 = time.monotonic()
        while not started.exists() and proc.poll() is None and time.monotonic() - t0 < 120:
            time.sleep(0.1)
        child = int(started.read_text())
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 143, err
        assert out.strip() == "stopped by SIGTERM"
        assert (tmp_path / "stopped").exists()  # the child stopped (and checkpointed) first
        with pytest.raises(ProcessLookupError):
            os.kill(child, 0)
        (spec,) = S.Manifest.load(tmp_path).runs
        assert spec.state == "pending"  # not "running": the next sweep starts it again
    finally:
        proc.kill()
        if started.exists():
            try:
                os.kill(int(started.read_text()), signal.SIGKILL)
            except ProcessLookupError:
                pass


def test_status_of_a_driven_pool_sweep_is_the_manifest_own(tmp_path: Path, capsys) -> None:
    """While its driver lives, a pool sweep's run is ``running`` from its start (its process
    holds no run lock yet while it builds) and ``done`` only when the driver says so."""
    import os

    running = _spec(tmp_path, state="running")
    manifest = S.Manifest(tmp_path / "sw", [running], {"cluster": {"executor": "pool"}})
    manifest.save()
    (tmp_path / "sw" / ".sweep.lock").write_text(str(os.getpid()))
    capsys.readouterr()
    assert main(["sweep", str(tmp_path / "sw"), "--status"]) == 0
    assert " running" in capsys.readouterr().out
    (tmp_path / "sw" / ".sweep.lock").unlink()  # no driver: worked out from the files
    assert main(["sweep", str(tmp_path / "sw"), "--status"]) == 0
    assert " pending" in capsys.readouterr().out
