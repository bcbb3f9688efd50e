"""Files that are not what they claim, where gcnt reads a run directory or a robot folder: a
FIFO (which would block a plain open forever, stop signals included), a device behind a symlink,
a huge sparse file. Each is refused in one line naming the file, before anything is read."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from cli_helpers import error_line

from gcnt.files import MiB, read_regular
from gcnt.morphology.robot import RobotFileError, load_robot
from gcnt.run.directory import CheckpointError, RunDir
from gcnt.run.metrics import MetricsFileError, read_metrics


def _fifo(path):
    os.mkfifo(path)
    return path


def test_read_regular_refuses_fifos_devices_directories_and_huge_files(tmp_path):
    huge = tmp_path / "huge.xml"
    with open(huge, "wb") as f:  # sparse: 3 GiB claimed, nothing written
        f.truncate(3 << 30)
    dev = tmp_path / "zero.xml"
    dev.symlink_to("/dev/zero")
    cases = [
        (_fifo(tmp_path / "fifo.xml"), "not a regular file"),
        (dev, "not a regular file"),
        (tmp_path, "a directory"),
        (huge, "3.0 GiB, larger than 1.0 MiB"),
        (tmp_path / "missing.xml", r"cannot read \(No such file or directory\)"),
    ]
    for path, message in cases:
        with pytest.raises(ValueError, match=message) as e:
            read_regular(path, MiB, "what it should be", ValueError)
        assert str(e.value).startswith(f"{path}: ") and str(e.value).endswith("what it should be")
    ok = tmp_path / "ok.txt"
    ok.write_bytes(b"x" * 10)
    assert read_regular(ok, 10, "", ValueError) == b"x" * 10


def test_a_robot_file_that_is_a_fifo_or_a_device_is_refused_before_reading(tmp_path):
    with pytest.raises(RobotFileError, match="fifo.xml: not a regular file; a robot file is MJCF"):
        load_robot(_fifo(tmp_path / "fifo.xml"))
    dev = tmp_path / "zero.xml"
    dev.symlink_to("/dev/zero")
    with pytest.raises(RobotFileError, match="zero.xml: not a regular file"):
        load_robot(dev)


def test_a_fifo_checkpoint_or_metrics_log_is_refused_not_waited_on(trained, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    ckpt = run / "checkpoints" / "last.pt"
    ckpt.unlink()
    _fifo(ckpt)
    with pytest.raises(CheckpointError, match="last.pt: not a regular file"):
        RunDir(run).load_checkpoint()
    line = error_line(capsys, ["eval", str(run), "--robots", "train", "--episodes", "1"])
    assert "not a regular file" in line
    metrics = run / "metrics.jsonl"
    metrics.unlink()
    _fifo(metrics)
    with pytest.raises(MetricsFileError, match="metrics.jsonl: not a regular file"):
        read_metrics(metrics)


def test_an_eval_link_out_of_the_run_directory_is_refused(trained, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.rmtree(run / "eval", ignore_errors=True)
    (run / "eval").symlink_to(elsewhere)
    line = error_line(capsys, ["eval", str(run), "--robots", "train", "--episodes", "1"])
    assert "a link out of the run directory" in line
    assert not any(elsewhere.iterdir())


def test_a_huge_sparse_metrics_log_is_one_line_not_a_memory_error(tmp_path, capsys):
    """A run's ``metrics.jsonl`` made a 1 GiB file of zeros (sparse: no disk used): read a line
    at a time, its first line is refused past the line cap, by ``gcnt curves`` and
    ``gcnt.load_run``, without reading the rest."""
    import time

    import gcnt
    from gcnt.cli import main

    run = tmp_path / "run"
    shutil.copytree(Path(__file__).parent / "data" / "td3_run_b52e8ec", run)
    with open(run / "metrics.jsonl", "wb") as f:
        f.truncate(1 << 30)
    t0 = time.monotonic()
    with pytest.raises(MetricsFileError, match="line 1: longer than"):
        read_metrics(run / "metrics.jsonl")
    assert main(["curves", str(run), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "longer than" in err and len(err.splitlines()) == 1
    with pytest.raises(Exception, match="longer than"):
        gcnt.load_run(run).metrics()
    assert time.monotonic() - t0 < 60
