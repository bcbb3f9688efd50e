"""One writer per run directory (``gcnt.run.lock``) and stopping on a signal with a checkpoint
(``gcnt.rl.stop``): a second ``gcnt train`` on a run in progress stops at once in one line naming
the holder; a dead holder leaves no lock; SIGTERM / SIGUSR2 checkpoint, exit 75, and the run
resumes from there."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_helpers import holding, wait_for_metrics

from gcnt.cli import main as gcnt
from gcnt.rl.stop import EXIT_STOPPED
from gcnt.run.directory import RunDir
from gcnt.run.lock import RunBusyError, holder, run_lock

ROOT = Path(__file__).parents[1]

#: a tiny TD3 run that would train for long: stopped by a signal long before its end, and
#: before its first scheduled checkpoint
LONG_RECIPE = """\
base: {root}/recipes/smpenv/_td3.yaml
task: tiny
env: {{robots: [hopper_3], max_episode_steps: 15}}
collector: {{total_frames: 1000000}}
td3: {{init_random_frames: 20, steps_per_batch: 5, batch_size: 8, buffer_size_per_robot: 2000,
      updates_per_step: 0.25, schedule: mixed}}
network: {{kwargs: {{d_model: 16, layers: 1, ff: 16, heads: 2}}}}
logger: {{backend: none, progress: false, log_interval: 20}}
eval: {{episodes: 1, interval: 0}}
checkpoint_interval: 1000000
compile: {{compile: false}}  # what is tested is the stop, not compiling (auto would compile)
"""


def test_a_second_writer_is_refused_and_a_dead_holder_leaves_no_lock(tmp_path: Path) -> None:
    run = tmp_path / "run"
    with holding("gcnt.run.lock:run_lock", run) as proc:
        who = holder(run)
        assert who is not None and who.pid == proc.pid and who.host == socket.gethostname()
        with pytest.raises(RunBusyError, match=rf"{run} is being trained by process {proc.pid} on"):
            with run_lock(run):
                pass
        proc.kill()  # no clean-up code runs: the kernel drops the lock
        proc.wait()
    assert holder(run) is None
    with run_lock(run):
        # asking about a lock this process holds must not release it (POSIX locks drop on any
        # close of the file by their process)
        assert holder(run).pid == os.getpid()
        probe = subprocess.run(
            [sys.executable, "-c", "import sys; from gcnt.run.lock import holder; "
             "print(holder(sys.argv[1]).pid)", str(run)],  # fmt: skip
            capture_output=True, text=True, check=True,
        )  # fmt: skip
        assert probe.stdout.strip() == str(os.getpid())
    assert holder(run) is None


def test_a_stale_holder_record_without_locking_is_taken_over(tmp_path: Path, monkeypatch) -> None:
    """Where the file system cannot lock, a holder on this host whose pid is gone is stale."""
    import errno
    import fcntl

    def no_locks(*_args):
        raise OSError(errno.ENOLCK, "no locks available")

    run = tmp_path / "run"
    run.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (run / ".lock").write_text(f"{socket.gethostname()} {dead.pid} 2026-01-01T00:00:00\n")
    monkeypatch.setattr(fcntl, "lockf", no_locks)
    assert holder(run) is None
    (run / ".lock").write_text("other-node 1 2026-01-01T00:00:00\n")
    with pytest.raises(RunBusyError, match="process 1 on other-node"):
        with run_lock(run):
            pass


def _start_training(tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, Path]:
    recipe = tmp_path / "long.yaml"
    recipe.write_text(LONG_RECIPE.format(root=ROOT))
    run = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "gcnt.cli", "train", str(recipe), f"run_dir={run}", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    return proc, run


@pytest.mark.slow
def test_sigterm_checkpoints_exits_75_and_a_second_writer_stops_at_once(
    tmp_path: Path, capsys
) -> None:
    proc, run = _start_training(tmp_path)
    try:
        wait_for_metrics([run / "metrics.jsonl"], proc)
        assert not RunDir(run).has_checkpoint()  # the first scheduled one is far away
        # a second writer: one line naming the holder, before any work
        capsys.readouterr()
        t0 = time.monotonic()
        assert gcnt(["train", "--resume", str(run)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert time.monotonic() - t0 < 5
        assert len(err) == 1 and f"is being trained by process {proc.pid}" in err[0], err
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == EXIT_STOPPED, stderr
    assert "Traceback" not in stderr
    (line,) = [x for x in stderr.splitlines() if x.startswith("gcnt train:")]
    assert "stopped by SIGTERM" in line and f"gcnt train --resume {run}" in line
    steps = RunDir(run).load_checkpoint()["env_steps"]
    assert 0 < steps < 1_000_000
    assert holder(run) is None
    assert gcnt(["train", "--resume", str(run), f"collector.total_frames={steps + 10}"]) == 0
    assert RunDir(run).load_checkpoint()["env_steps"] >= steps + 10


@pytest.mark.slow
def test_sigusr2_checkpoints_every_stacked_seed(tmp_path: Path) -> None:
    proc, run = _start_training(tmp_path, "--seeds", "0,1")
    seeds = [run / "seed0", run / "seed1"]
    try:
        wait_for_metrics([s / "metrics.jsonl" for s in seeds], proc)
        assert all(holder(s).pid == proc.pid for s in seeds)
        proc.send_signal(signal.SIGUSR2)
        _, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == EXIT_STOPPED, stderr
    assert "stopped by SIGUSR2" in stderr and "Traceback" not in stderr
    steps = [RunDir(s).load_checkpoint()["env_steps"] for s in seeds]
    assert steps[0] == steps[1] > 0
    assert all(holder(s) is None for s in seeds)


def test_a_stop_during_the_final_evaluation_is_said(monkeypatch, tmp_path: Path) -> None:
    """A stop signal that arrives while the final evaluation runs does not cut it short (the
    run finished training and is checkpointed): it is said, not silently deferred."""
    from gcnt.rl import loop

    said: list[str] = []
    monkeypatch.setattr(loop, "_evaluate", lambda *a: {"hopper_3": {}})
    monkeypatch.setattr(loop.stop, "requested", lambda: "SIGTERM")
    monkeypatch.setattr(loop.log, "warning", lambda msg, *a: said.append(msg % a))
    run = RunDir(tmp_path / "run")
    assert loop.finish(None, run, None, None, 100) == {"hopper_3": {}}
    assert len(said) == 1 and "SIGTERM arrived during the final evaluation" in said[0]
    said.clear()
    loop.finish(None, run, None, None, 100, evaluate_now=False)
    assert not said


def test_a_run_that_fails_before_logging_anything_leaves_no_directory(
    monkeypatch, tmp_path: Path, capsys
) -> None:
    """A failure found after the run directory was made (a robot the physics refuses at its
    first step, a full disk) removes what the failed start made, so that the same command runs
    again once the cause is fixed; a run that logged something is kept."""
    from cli_helpers import tiny_td3_recipe

    from gcnt.rl import loop

    recipe = tiny_td3_recipe(tmp_path / "tiny.yaml")
    run = tmp_path / "run"
    real = loop.train

    def fails_at_once(recipe, run_dir, **kw):
        raise ValueError("robot 'x': the physics refused it at its first step")

    monkeypatch.setattr(loop, "train", fails_at_once)
    with pytest.raises(ValueError, match="first step"):
        gcnt(["train", str(recipe), f"run_dir={run}"])
    assert not run.exists()
    monkeypatch.setattr(loop, "train", real)
    assert gcnt(["train", str(recipe), f"run_dir={run}"]) == 0  # the same command, again
    assert RunDir(run).has_checkpoint()


def test_a_full_disk_when_a_run_starts_is_one_line_and_leaves_nothing(
    monkeypatch, tmp_path: Path, capsys
) -> None:
    import errno

    from cli_helpers import error_line, tiny_td3_recipe

    recipe = tiny_td3_recipe(tmp_path / "tiny.yaml")
    run = tmp_path / "run"

    def full(self, recipe):
        self.path.mkdir(parents=True, exist_ok=True)
        raise OSError(errno.ENOSPC, "No space left on device", str(self.path / "recipe.yaml"))

    monkeypatch.setattr(RunDir, "create", full)
    line = error_line(capsys, ["train", str(recipe), f"run_dir={run}"])
    assert "recipe.yaml: cannot write (No space left on device); free space" in line
    assert not run.exists()
