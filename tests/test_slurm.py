"""``gcnt sweep --slurm`` against a real single-node Slurm cluster (Debian's slurm-wlm and munge,
started by tests/slurm/start_cluster.sh): a sweep completes and a second sweep submits nothing
twice; a run killed and cancelled before its first checkpoint completes when the sweep is run
again; a job that reaches its time limit checkpoints, requeues itself and finishes.

The cluster needs root (apt-get, the daemons); elsewhere these tests skip, saying why. Select or
leave them out with ``-m slurm`` / ``-m "not slurm"``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import pytest
import yaml
from cli_helpers import TINY_SWEEP_OVERRIDES

from gcnt import sweep as S
from gcnt.analysis.runs import Run
from gcnt.cli import main
from gcnt.files import write_text
from gcnt.run.directory import RunDir
from gcnt.run.lock import holder

pytestmark = [pytest.mark.slurm, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "recipes" / "quickstart.yaml"
#: a run of seconds (200 random steps, then 100 with updates), no checkpoint before its end
TINY = [
    *(o for o in TINY_SWEEP_OVERRIDES if not o.startswith("checkpoint_interval=")),
    "checkpoint_interval=100000",
    "logger.backend=none",
]


@pytest.fixture(scope="module")
def slurm(tmp_path_factory):
    """A running single-node cluster; SLURM_CONF set for this process and its jobs."""
    if not sys.platform.startswith("linux"):
        pytest.skip("the Slurm tests start Linux daemons")
    if os.geteuid() != 0:
        pytest.skip("the Slurm tests need root (apt-get install slurm-wlm munge, the daemons)")
    state = Path("/tmp/gcnt-slurm-test")  # its ports are fixed: one such cluster at a time
    start = subprocess.run(
        ["bash", str(ROOT / "tests" / "slurm" / "start_cluster.sh"), str(state)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    if start.returncode == 3:
        pytest.skip(start.stderr.strip().splitlines()[-1])
    assert start.returncode == 0, start.stderr
    conf = start.stdout.strip().splitlines()[-1].split("=", 1)[1]
    old = os.environ.get("SLURM_CONF")
    os.environ["SLURM_CONF"] = conf
    yield state
    subprocess.run(["bash", str(ROOT / "tests" / "slurm" / "stop_cluster.sh"), str(state)])
    if old is None:
        os.environ.pop("SLURM_CONF", None)
    else:
        os.environ["SLURM_CONF"] = old


def _jobs(name: str) -> list[tuple[str, str]]:
    """(job id, state) of every job of this sweep Slurm still lists."""
    out = subprocess.run(
        ["squeue", "-h", "-r", "--states=all", "-n", f"gcnt-{name}", "-o", "%i|%T"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return [tuple(line.split("|")) for line in out.splitlines()]


def _sweep_dir(tmp_path: Path, name: str) -> Path:
    """A sweep directory whose name (and so its Slurm job name) no earlier session used."""
    return tmp_path / f"{name}-{tmp_path.parent.name}"


def _manifest(sw: Path) -> list[dict]:
    """The manifest's runs, paths made absolute where the sweep is (as gcnt reads them)."""
    return [asdict(r) for r in S.Manifest.load(sw).runs]


def _wait(what, timeout: float = 240, every: float = 0.5):
    t0 = time.monotonic()
    while not (value := what()):
        assert time.monotonic() - t0 < timeout, f"timed out waiting for {what.__doc__}"
        time.sleep(every)
    return value


def test_a_sweep_completes_and_a_second_one_submits_nothing_twice(slurm, tmp_path, capsys):
    sw = _sweep_dir(tmp_path, "twice")
    argv = ["sweep", str(QUICKSTART), "--seeds", "0,1", "--slurm", "--time", "15", "--dir", str(sw)]
    assert main([*argv, *TINY, "--no-wait"]) == 0
    first = sorted(_jobs(sw.name))
    assert len(first) == 2
    # the same command again while the jobs wait or run: nothing new goes to Slurm
    assert main([*argv, *TINY, "--no-wait"]) == 0
    assert sorted(j for j, _ in _jobs(sw.name)) == [j for j, _ in first]
    assert main(["sweep", str(sw), "--status"]) == 0
    table = capsys.readouterr().out
    assert any(s in table for s in ("queued", "running")), table
    # `gcnt sweep DIR` follows the jobs on Slurm (not on this machine's pool) until they end
    assert main(["sweep", str(sw)]) == 0
    out = capsys.readouterr().out
    assert "on slurm" in out and "Bypassing" not in out
    runs = _manifest(sw)
    assert [r["state"] for r in runs] == ["done", "done"]
    assert all(r["returncode"] == 0 and r["started"] and r["finished"] for r in runs)
    assert all(Run(r["run_dir"]).finished() for r in runs)
    assert main(["sweep", str(sw)]) == 0  # finished: nothing submitted
    assert sorted(j for j, _ in _jobs(sw.name)) == [j for j, _ in first]


def test_a_run_killed_before_its_first_checkpoint_completes_when_the_sweep_runs_again(
    slurm, tmp_path, capsys
):
    sw = _sweep_dir(tmp_path, "killed")
    argv = ["sweep", str(QUICKSTART), "--slurm", "--time", "15", "--dir", str(sw), *TINY]
    assert main([*argv, "--no-wait"]) == 0
    (spec,) = _manifest(sw)
    run = Path(spec["run_dir"])

    def trainer():
        """gcnt train to have logged"""
        return (run / "metrics.jsonl").is_file() and holder(run)

    who = _wait(trainer)
    # killed as by the OOM killer, then the job cancelled: a recipe, metrics, no checkpoint
    os.kill(who.pid, 9)
    subprocess.run(["scancel", spec["job_id"]], check=True)

    def over():
        """the job to end"""
        return all(s not in S.SLURM_RUNNING for _, s in _jobs(sw.name))

    _wait(over)
    assert (run / "recipe.yaml").is_file() and not RunDir(run).has_checkpoint()
    assert main(["sweep", str(sw), "--status"]) == 0
    assert "cancelled" in capsys.readouterr().out
    assert main(["sweep", str(sw)]) == 0  # resubmitted (with --resume), trained from step 0
    (spec,) = _manifest(sw)
    assert spec["state"] == "done" and Run(run).finished()
    assert "train --resume" in Path(spec["log"]).read_text()
    assert (run / "metrics.restart1.jsonl").is_file()


def test_a_job_at_its_time_limit_checkpoints_requeues_and_finishes(slurm, tmp_path, capsys):
    sw = _sweep_dir(tmp_path, "limit")
    # a run far longer than its 3-minute slot; Slurm warns it 60 s before the limit
    long = [o for o in TINY if not o.startswith("collector.total_frames")]
    argv = ["sweep", str(QUICKSTART), "--slurm", "--time", "3", "--signal-delay", "60"]
    argv += ["--dir", str(sw), *long, "collector.total_frames=10000000", "--no-wait"]
    argv += ["compile.compile=false"]  # the time limit is tested, not compiling
    assert main(argv) == 0
    (spec,) = _manifest(sw)
    run = Path(spec["run_dir"])

    def requeued():
        """the job to checkpoint and requeue itself"""
        record = S.read_record(sw, S.RunSpec(**spec)) or {}
        return record.get("state") == "requeued" and any(
            s in ("PENDING", "REQUEUED") for _, s in _jobs(sw.name)
        )

    _wait(requeued, timeout=400, every=1)
    job = f"JobId={spec['job_id']}"
    # held while the test edits its recipe: on a loaded machine Slurm's hold on a requeued job
    # (its BeginTime) may lapse before the edit, and the job would read a half-written file
    subprocess.run(["scontrol", "hold", job], check=False, capture_output=True)
    steps = RunDir(run).load_checkpoint()["env_steps"]
    assert steps > 0  # written on Slurm's warning, not by the schedule (interval 100000)
    log = Path(spec["log"]).read_text()
    assert "stopped by SIGUSR2" in log and "Traceback" not in log
    assert main(["sweep", str(sw), "--status"]) == 0
    assert "requeued" in capsys.readouterr().out
    # the test's own shortcuts: the run ends soon after it resumes, in a longer slot, and
    # Slurm's hold on a requeued job (about two minutes of BeginTime) is lifted
    recipe = yaml.safe_load((run / "recipe.yaml").read_text())
    recipe["collector"]["total_frames"] = max(steps, recipe["td3"]["init_random_frames"]) + 100
    write_text(run / "recipe.yaml", yaml.safe_dump(recipe))
    subprocess.run(["scontrol", "update", job, "TimeLimit=10", "StartTime=now"], check=True)
    subprocess.run(["scontrol", "release", job], check=False, capture_output=True)
    # follows the requeued job; submits nothing new
    assert main(["sweep", str(sw)]) == 0, Path(spec["log"]).read_text()[-4000:]
    (spec,) = _manifest(sw)
    assert spec["state"] == "done" and Run(run).finished()
    assert len(_jobs(sw.name)) == 1
    log = Path(spec["log"]).read_text()
    commands = [line for line in log.splitlines() if line.startswith("# ")]
    assert len(commands) == 2 and "train --resume" in commands[1]
    assert (S.read_record(sw, S.RunSpec(**spec)) or {}).get("attempt") == 2


def test_a_plugins_method_benchmark_and_algorithm_train_and_evaluate_on_slurm(slurm, tmp_path):
    """A plugin named once on the sweep's command line reaches its Slurm jobs: their training
    and their evaluation processes import it (the runs record it)."""
    from plugin_helpers import write_plugin

    plugin = write_plugin(tmp_path / "mine")
    sw = _sweep_dir(tmp_path, "plugin")
    argv = ["--plugin", str(plugin), "sweep", str(plugin.parent / "recipe.yaml"), "--slurm"]
    argv += ["--time", "15", "--dir", str(sw), "--eval", "test", "--episodes", "1"]
    assert main(argv) == 0
    (spec,) = _manifest(sw)
    assert spec["state"] == "done" and spec["eval_state"] == {"test": "done"}
    recorded = yaml.safe_load((Path(spec["run_dir"]) / "recipe.yaml").read_text())
    # recorded by its file's name (never the author's folder): the identity is its sha256
    assert recorded["plugins"] == [plugin.name] and recorded["network"]["name"] == "plugnet"
    assert list((Path(spec["run_dir"]) / "eval").glob("test-*.json"))
