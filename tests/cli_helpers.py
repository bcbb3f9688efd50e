"""What the command-line tests share: a tiny TD3 recipe that trains in a few seconds, the
quick-start overrides of a tiny sweep run, and the check that a mistake is exactly one error
line (exit code 2, no traceback). The module-scoped ``recipe_file`` and ``trained`` fixtures
built on them are in ``conftest.py``."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from gcnt.cli import main as gcnt

ROOT = Path(__file__).parents[1]

TINY_TD3 = """\
base: {root}/recipes/smpenv/_td3.yaml
task: tiny
env: {{robots: [hopper_3], test_robots: [{test_robots}], max_episode_steps: 15}}
collector: {{total_frames: 40}}
td3: {{init_random_frames: 20, steps_per_batch: 5, batch_size: 8, buffer_size_per_robot: 2000,
      updates_per_step: 0.25}}
network: {{kwargs: {{d_model: 16, layers: 1, ff: 16, heads: 2}}}}
compile: {{twin_processes: false}}  # tests/test_twin_processes.py tests the helper process
logger: {{backend: none, progress: {progress}, log_interval: 20}}
eval: {{episodes: 1, interval: 0{eval_robots}}}
checkpoint_interval: 20
"""


#: overrides of the quick start for a sweep run of seconds on hopper_3: 200 random steps, then
#: 100 with updates, a checkpoint every 100
TINY_SWEEP_OVERRIDES = [
    "collector.total_frames=300",
    "td3.init_random_frames=200",
    "checkpoint_interval=100",
    "env.robots=[hopper_3]",
    "env.test_robots=[hopper_4]",
    "env.max_episode_steps=50",
    "eval.episodes=1",
    "logger.log_interval=100",
    "logger.progress=false",
    "network.kwargs={d_model: 8, layers: 1, ff: 16, heads: 2}",
]


def tiny_td3_recipe(
    path: Path,
    *,
    test_robots: Sequence[str] = ("hopper_4",),
    progress: bool = False,
    eval_robots: Sequence[str] | None = None,
) -> Path:
    """Write, at ``path``, a recipe that trains a tiny GCNT on hopper_3 for 40 steps
    (checkpoints every 20)."""
    path.write_text(
        TINY_TD3.format(
            root=ROOT,
            test_robots=", ".join(test_robots),
            progress=str(progress).lower(),
            eval_robots="" if eval_robots is None else f", robots: [{', '.join(eval_robots)}]",
        )
    )
    return path


def error_line(capsys, argv: list[str]) -> str:
    """Run gcnt; it must exit 2 with exactly one error line and no traceback."""
    capsys.readouterr()
    assert gcnt(argv) == 2, argv
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith("gcnt ")]
    assert len(lines) == 1 and ": error: " in lines[0], err
    return lines[0]


def wait_for_metrics(paths: list[Path], proc: subprocess.Popen, timeout: float = 600) -> None:
    """Wait until a training process started with :class:`subprocess.Popen` has logged a metrics
    row in every one of ``paths`` (it must not exit first)."""
    t0 = time.monotonic()
    while not all(p.is_file() and p.stat().st_size for p in paths):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout, "training did not start"
        time.sleep(0.2)


@contextlib.contextmanager
def holding(lock: str, path: Path) -> Iterator[subprocess.Popen]:
    """Another process holding ``lock`` (``"module:function"``, a context manager taking a path)
    on ``path`` while the block runs: it has the lock when the block starts and lets go when its
    stdin closes at the end (a killed one, at once), so no stand-in outlives the test by a fixed
    sleep."""
    module, name = lock.split(":")
    code = (
        f"import sys; from pathlib import Path; from {module} import {name}\n"
        f"with {name}(Path(sys.argv[1])):\n"
        "    print('held', flush=True); sys.stdin.read()\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "held\n"
        yield proc
    finally:
        proc.communicate("", timeout=60)


def dying_worker_env(*args, **kwargs) -> None:
    """A PPO collector worker's env maker that kills its own process as it starts up (as the
    OOM killer would): set in place of ``gcnt.rl.ppo.learner.make_worker_env``."""
    import signal

    os.kill(os.getpid(), signal.SIGKILL)
