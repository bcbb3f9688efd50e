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
import yaml
from cli_helpers import wait_for_metrics
from test_ppo import tiny_recipe

from gcnt.cli import main as gcnt
from gcnt.rl.run_dir import RunDir
from gcnt.rl.stop import EXIT_STOPPED


@pytest.mark.slow
def test_sigterm_stops_a_multi_process_collector_cleanly_and_the_run_resumes(tmp_path: Path):
    d = tiny_recipe(tmp_path / "unused", "unimal", collector="multi", workers=2).to_dict()
    d.pop("run_dir", None)
    d["collector"]["total_frames"] = 10_000_000  # runs until stopped
    d["checkpoint_interval"] = 10_000_000  # the only checkpoint is the stop's own
    recipe = tmp_path / "multi.yaml"
    recipe.write_text(yaml.safe_dump(d))
    run = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "gcnt.cli", "train", str(recipe), f"run_dir={run}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_for_metrics([run / "metrics.jsonl"], proc)
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
