"""PPO with torchrl's multi-process collector (``ppo.collector: multi``) as a process: SIGTERM
stops it after the current batch with a checkpoint, its worker processes end with it (no
semaphore or shared memory left behind, which Python's resource tracker reports at exit), and the
run resumes from that checkpoint."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml
from cli_helpers import wait_for_metrics
from test_ppo import tiny_recipe

from gcnt.cli import main as gcnt
from gcnt.rl.stop import EXIT_STOPPED
from gcnt.run.directory import RunDir


def _start(tmp_path: Path, benchmark: str, **edit) -> tuple[subprocess.Popen, Path]:
    """``gcnt train`` of a tiny multi-collector PPO recipe (``edit``: recipe sections updated),
    started as a process; its run directory."""
    d = tiny_recipe(tmp_path / "unused", benchmark, collector="multi", workers=2).to_dict()
    d.pop("run_dir", None)
    for key, value in edit.items():
        d[key] = {**d[key], **value} if isinstance(value, dict) else value
    path = tmp_path / "multi.yaml"
    path.write_text(yaml.safe_dump(d))
    run = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "gcnt.cli", "train", str(path), f"run_dir={run}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    return proc, run


def _endless_run(tmp_path: Path, benchmark: str = "smpenv") -> tuple[subprocess.Popen, Path]:
    """:func:`_start` of a run that goes on until stopped, once it has logged a row (the only
    checkpoint is the stop's own)."""
    proc, run = _start(
        tmp_path,
        benchmark,
        collector={"total_frames": 10_000_000},
        checkpoint_interval=10_000_000,
    )
    try:
        wait_for_metrics([run / "metrics.jsonl"], proc)
    except BaseException:
        proc.kill()
        raise
    return proc, run


@pytest.mark.slow
def test_sigterm_stops_a_multi_process_collector_cleanly_and_the_run_resumes(tmp_path: Path):
    proc, run = _endless_run(tmp_path, benchmark="unimal")
    d = yaml.safe_load((tmp_path / "multi.yaml").read_text())
    try:
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == EXIT_STOPPED, stderr
    assert "Traceback" not in stderr
    assert "leaked" not in stderr, stderr  # resource_tracker: leaked semaphore / shared_memory
    steps = RunDir(run).load_checkpoint()["env_steps"]
    assert steps > 0
    more = steps + d["ppo"]["num_envs"] * d["ppo"]["steps_per_env"]
    assert gcnt(["train", "--resume", str(run), f"collector.total_frames={more}"]) == 0
    assert RunDir(run).load_checkpoint()["env_steps"] >= more


def _first_rows(tmp_path: Path, name: str, **ppo) -> list[dict]:
    from gcnt.rl.loop import train

    recipe = tiny_recipe(tmp_path / name, collector="multi", workers=2, **ppo)
    recipe.collector.total_frames = 80  # one iteration
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    train(recipe, run)
    return [
        {k: v for k, v in r.items() if "loss" in k or "return" in k} for r in run.read_metrics()
    ]


@pytest.mark.slow
def test_the_multi_process_collector_repeats_a_run_for_its_seed(tmp_path: Path):
    """Two runs of one recipe and seed on two worker processes log the same first row: each
    worker's resets, robot draws and action noise come from the seed."""
    first = _first_rows(tmp_path, "a")
    assert first and "train_return/mean" in first[0]
    assert _first_rows(tmp_path, "b") == first


def test_a_killed_runs_probabilities_file_is_removed_by_the_next(tmp_path: Path):
    import os

    from gcnt.rl.ppo.robot_sampler import PROBS_PREFIX, shared_probs

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    folder = "/dev/shm" if os.path.isdir("/dev/shm") else None
    import tempfile

    stale = Path(folder or tempfile.gettempdir()) / f"{PROBS_PREFIX}{gone.stdout.strip()}-x.f64"
    stale.write_bytes(b"\0" * 16)  # what a run killed with SIGKILL leaves
    try:
        probs = shared_probs(2)
        assert not stale.exists()
        assert Path(probs.filename).name.startswith(f"{PROBS_PREFIX}{os.getpid()}-")
    finally:
        stale.unlink(missing_ok=True)


@pytest.mark.slow
def test_a_killed_worker_ends_the_run_in_one_line(tmp_path: Path):
    import os

    proc, run = _endless_run(tmp_path)
    try:
        children = subprocess.run(
            ["pgrep", "-P", str(proc.pid)], capture_output=True, text=True
        ).stdout.split()
        workers = [c for c in children if "spawn_main" in Path(f"/proc/{c}/cmdline").read_text()]
        os.kill(int(workers[0]), signal.SIGKILL)  # as the OOM killer does
        _, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
    lines = [x for x in stderr.splitlines() if x.startswith("gcnt train: error:")]
    assert proc.returncode == 2 and "Traceback" not in stderr, stderr[-3000:]
    assert len(lines) == 1 and "killed by SIGKILL" in lines[0], stderr[-3000:]
    assert f"gcnt train --resume {run}" in lines[0]


def test_the_multi_collectors_first_iteration_is_normalised(tmp_path: Path):
    """The workers normalise with the statistics of the iteration's start: before the first,
    a reset of the training env has joined them (no iteration runs on the prior alone)."""
    from gcnt.rl.loop import prepare

    recipe = tiny_recipe(tmp_path / "run", collector="multi", workers=2)
    prepared = prepare(recipe)
    try:
        norm = prepared.algo.learner.obs_norm
        assert float(norm.count.max()) < 1.0  # the prior only
        prepared.algo.collect_settings(0)
        assert round(float(norm.count.max())) == recipe.ppo.num_envs  # one reset of every env
        seen = norm.count.clone()
        prepared.algo.collect_settings(0)  # a second call (a resume) adds nothing
        assert torch.equal(norm.count, seen)
    finally:
        prepared.env.close()


@pytest.mark.slow
def test_a_worker_that_dies_as_it_starts_up_ends_the_run_in_one_line(tmp_path: Path):
    """No torchrl traceback, and the process ends: nothing waits at exit for the half-built
    collector's workers or threads."""
    import os

    d = tiny_recipe(tmp_path / "unused", collector="multi", workers=2).to_dict()
    d.pop("run_dir", None)
    path = tmp_path / "multi.yaml"
    path.write_text(yaml.safe_dump(d))
    run = tmp_path / "run"
    code = (
        "import sys\n"
        "import cli_helpers, gcnt.rl.ppo.learner as learner\n"
        "from gcnt.cli import main\n"
        "learner.make_worker_env = cli_helpers.dying_worker_env\n"
        "sys.exit(main(['train', sys.argv[1], 'run_dir=' + sys.argv[2]]))\n"
    )
    tests = str(Path(__file__).parent)
    proc = subprocess.run(
        [sys.executable, "-c", code, str(path), str(run)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([tests, *sys.path])},
    )
    lines = [x for x in proc.stderr.splitlines() if x.startswith("gcnt train: error:")]
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert len(lines) == 1 and "killed by SIGKILL" in lines[0], proc.stderr[-3000:]
    assert "while starting up" in lines[0] and "run the same command again" in lines[0]
    assert not run.exists()  # nothing of value was made


def _workers(proc: subprocess.Popen) -> list[int]:
    children = subprocess.run(
        ["pgrep", "-P", str(proc.pid)], capture_output=True, text=True
    ).stdout.split()
    out = []
    for c in children:
        try:
            if "spawn_main" in Path(f"/proc/{c}/cmdline").read_text():
                out.append(int(c))
        except OSError:  # gone meanwhile
            continue
    return out


@pytest.mark.slow
def test_a_worker_killed_the_moment_it_exists_ends_the_run_in_one_line(tmp_path: Path):
    """Killed as soon as its process exists, before it read its start-up data (with four UNIMAL
    robots 87 KiB, more than the pipe they are written into holds), a worker left
    multiprocessing's launch of it waiting forever: the run stayed alive without a line. The
    start-up watch ends it in one line within seconds."""
    import os
    import time

    proc, run = _start(tmp_path, "unimal", env={"robots": [f"unimal_000{i}" for i in range(4)]})
    try:
        deadline = time.monotonic() + 300
        while not (workers := _workers(proc)):  # the first worker's process exists
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no worker started"
        os.kill(workers[0], signal.SIGKILL)
        killed = time.monotonic()
        _, stderr = proc.communicate(timeout=120)
        took = time.monotonic() - killed
    finally:
        proc.kill()
    lines = [x for x in stderr.splitlines() if x.startswith("gcnt train: error:")]
    assert proc.returncode == 2 and "Traceback" not in stderr, stderr[-3000:]
    assert len(lines) == 1 and "collector worker 0 ended (killed by SIGKILL)" in lines[0], lines
    assert "while starting up" in lines[0] and "run the same command again" in lines[0]
    assert took < 30, took  # about 3 s on 2 cores
    assert not run.exists()  # nothing of value was made


@pytest.mark.slow
def test_a_stopped_worker_ends_the_run_in_one_line(tmp_path: Path):
    """A worker stopped by SIGSTOP (it never answers) ends the run once it has been stopped for
    STOPPED_WORKER_S, in one line naming --resume; no worker is left behind."""
    import os

    proc, run = _endless_run(tmp_path)
    try:
        workers = _workers(proc)
        os.kill(workers[0], signal.SIGSTOP)
        _, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
    lines = [x for x in stderr.splitlines() if x.startswith("gcnt train: error:")]
    assert proc.returncode == 2 and "Traceback" not in stderr, stderr[-3000:]
    assert len(lines) == 1 and "collector worker" in lines[0], stderr[-3000:]
    assert "has been stopped" in lines[0] and f"gcnt train --resume {run}" in lines[0]
    assert not any(Path(f"/proc/{w}").exists() for w in workers)


@pytest.mark.slow
def test_sigterm_while_a_worker_is_stopped_still_checkpoints(tmp_path: Path):
    import os

    proc, run = _endless_run(tmp_path)
    try:
        os.kill(_workers(proc)[0], signal.SIGSTOP)
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == EXIT_STOPPED, stderr[-3000:]
    assert "stopped by SIGTERM: checkpoint of" in stderr and "Traceback" not in stderr
    assert RunDir(run).has_checkpoint()


def test_worker_envs_must_split_the_iterations_frames(tmp_path: Path):
    with pytest.raises(ValueError, match="must be a multiple of workers x worker_envs"):
        tiny_recipe(tmp_path / "r", collector="multi", workers=2, worker_envs=3)


@pytest.mark.slow
def test_each_worker_steps_worker_envs_envs(tmp_path: Path):
    """ppo.worker_envs: each worker steps that many envs (here the whole num_envs), fewer steps
    each; an iteration holds the same frames, as workers x worker_envs trajectories. The update
    keeps the process's torch threads (torchrl's collector would lower them by the workers)."""
    from gcnt.rl.loop import train

    recipe = tiny_recipe(tmp_path / "w", collector="multi", workers=2, worker_envs=4)
    recipe.collector.total_frames = 80  # one iteration: 2 workers x 4 envs x 10 steps
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    seen = []
    from gcnt.rl.ppo import learner as ppo_learner

    original = ppo_learner.PPOLearner.learn

    def spy(self, data):
        seen.append((tuple(data.shape), torch.get_num_threads()))
        return original(self, data)

    ppo_learner.PPOLearner.learn = spy
    threads = torch.get_num_threads()
    torch.set_num_threads(3)  # more than the 2 workers, on any machine
    try:
        train(recipe, run)
    finally:
        ppo_learner.PPOLearner.learn = original
        torch.set_num_threads(threads)
    assert seen == [((8, 10), 3)]
    assert run.read_metrics()


def test_a_stopped_workers_error_is_raised_again_when_the_waiting_code_swallows_it(
    tmp_path: Path, monkeypatch
):
    """torchrl's wait for a worker's acknowledgement catches every Exception and logs it: the
    watch keeps raising until its error leaves the watched block."""
    import os
    import time
    from types import SimpleNamespace

    from gcnt.rl import worker_watch as watch

    monkeypatch.setattr(watch, "STOPPED_WORKER_S", 0.2)
    sleeper = subprocess.Popen(["sleep", "60"])
    try:
        os.kill(sleeper.pid, signal.SIGSTOP)
        collector = SimpleNamespace(procs=[SimpleNamespace(pid=sleeper.pid, exitcode=None)])
        swallowed = []
        with pytest.raises(watch.WorkerDiedError, match="has been stopped"):
            with watch.worker_watch(collector, RunDir(tmp_path / "run"), every=0.05):
                deadline = time.monotonic() + 30
                while time.monotonic() < deadline:
                    try:
                        while time.monotonic() < deadline:
                            time.sleep(0.01)
                    except Exception as e:  # as torchrl's ack wait does
                        swallowed.append(e)
                        if len(swallowed) >= 2:  # now the waiting code lets it through
                            raise
        assert len(swallowed) == 2
    finally:
        sleeper.kill()
        sleeper.wait()
