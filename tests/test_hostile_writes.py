"""Links, FIFOs and devices put where gcnt writes (a run's lock and temporary files, a figure's
caption, a sweep's lock and logs, a morphologies folder's import lock, the ``--json`` a user
names): gcnt never writes through them or replaces them; a refusal is one line naming the
file, and what a link points to keeps its content. A lock or log that is a hard link (another
name of someone else's file) is refused as well: gcnt writes into those files themselves."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import ROOT, TINY_SWEEP_OVERRIDES, error_line

from gcnt.cli import main as gcnt
from gcnt.files import (
    NotRegularFileError,
    append_text,
    open_lock,
    save_torch,
    write_output,
    write_text,
)

VICTIM_TEXT = "someone else's file\n"


def _victim(tmp_path: Path) -> Path:
    victim = tmp_path / "outside" / "victim.txt"
    victim.parent.mkdir(exist_ok=True)
    victim.write_text(VICTIM_TEXT)
    return victim


def _copy(trained: Path, tmp_path: Path) -> Path:
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    return run


def _make(path: Path, kind: str, victim: Path) -> None:
    """At ``path``: a symbolic link to ``victim`` (``link``), another name of it
    (``hardlink``), or a FIFO."""
    if kind == "link":
        path.symlink_to(victim)
    elif kind == "hardlink":
        path.hardlink_to(victim)
    else:
        os.mkfifo(path)


# --- the writer itself


@pytest.mark.parametrize("kind", ["link", "fifo", "folder"])
def test_a_write_onto_what_is_not_a_regular_file_is_refused(tmp_path, kind):
    victim = _victim(tmp_path)
    target = tmp_path / "out.json"
    if kind == "link":
        target.symlink_to(victim)
    elif kind == "fifo":
        os.mkfifo(target)
    else:
        target.mkdir()
    for write in (lambda p: write_text(p, "new"), lambda p: save_torch({"a": 1}, p)):
        with pytest.raises(NotRegularFileError, match="not a regular file"):
            write(target)
    assert victim.read_text() == VICTIM_TEXT
    assert target.is_symlink() == (kind == "link")
    # no temporary file left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json", "outside"]


def test_a_write_replaces_a_regular_file_and_leaves_no_temporary_file(tmp_path):
    target = tmp_path / "recipe.yaml"
    target.write_text("old")
    os.symlink(_victim(tmp_path), tmp_path / "recipe.tmp")  # the name writes once used
    write_text(target, "new")
    assert target.read_text() == "new" and not target.is_symlink()
    assert (tmp_path / "outside" / "victim.txt").read_text() == VICTIM_TEXT
    assert sorted(p.name for p in tmp_path.iterdir()) == ["outside", "recipe.tmp", "recipe.yaml"]


@pytest.mark.parametrize("kind", ["link", "fifo", "devnull", "hardlink"])
def test_a_lock_or_log_that_is_not_a_regular_file_is_refused_untouched(tmp_path, kind):
    victim = _victim(tmp_path)
    path = tmp_path / ".lock"
    if kind == "link":
        path.symlink_to(victim)
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "hardlink":
        path.hardlink_to(victim)
    else:
        path.symlink_to("/dev/null")
    said = r"\.lock: a (symbolic link|FIFO|hard link \(a file with 2 names\))"
    with pytest.raises(NotRegularFileError, match=said):
        open_lock(path)
    with pytest.raises(NotRegularFileError):
        append_text(path, "a line\n")
    assert victim.read_text() == VICTIM_TEXT


@contextlib.contextmanager
def _read_fifo(fifo: Path):
    """A reader of ``fifo`` while the block runs (what was written must fit the pipe's
    buffer); yields what it read, once the block ends. (A FIFO stands in for a device such as
    ``/dev/null``: a regression that replaced it breaks nothing outside the test.)"""
    fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    got: list[bytes] = []
    try:
        yield got
        got.append(os.read(fd, 1 << 16))
    finally:
        os.close(fd)


def test_an_output_the_user_names_is_written_into_a_device_never_replaced(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(NotRegularFileError, match="a FIFO that nobody reads"):
        write_output(fifo, b"results")
    with _read_fifo(fifo) as got:
        write_output(fifo, b"results")
    assert got == [b"results"] and fifo.is_fifo()
    mine = tmp_path / "mine.json"
    mine.write_text("old")
    (tmp_path / "link.json").symlink_to(mine)  # a link the user named: written through
    write_output(tmp_path / "link.json", b"new")
    assert (tmp_path / "link.json").is_symlink() and mine.read_text() == "new"


# --- runs


@pytest.mark.parametrize("kind", ["link", "fifo", "devnull", "hardlink"])
def test_a_lock_file_that_is_not_regular_is_one_line_and_empties_nothing(
    trained, tmp_path, capsys, kind
):
    run = _copy(trained, tmp_path)
    victim = _victim(tmp_path)
    lock = run / ".lock"
    lock.unlink(missing_ok=True)
    if kind == "link":
        lock.symlink_to(victim)
    elif kind == "fifo":
        os.mkfifo(lock)
    elif kind == "hardlink":  # the holder record would be written into the victim
        lock.hardlink_to(victim)
    else:
        lock.symlink_to("/dev/null")
    line = error_line(capsys, ["train", "--resume", str(run), "collector.total_frames=60"])
    assert f"{lock}: a " in line and "the run's lock file" in line, line
    assert victim.read_text() == VICTIM_TEXT


def test_links_at_the_old_temporary_names_are_never_written_through(trained, tmp_path, capsys):
    """Links at ``recipe.tmp``, ``provenance.tmp``, ``metrics.tmp``, ``checkpoints/last.tmp``
    and ``eval/<name>.tmp``: a resume and an eval leave their targets as they were, and the
    run's own files are regular files."""
    run = _copy(trained, tmp_path)
    shutil.rmtree(run / "eval", ignore_errors=True)  # the periodic evaluations of training
    assert gcnt(["eval", str(run), "--episodes", "1"]) == 0
    (written,) = (run / "eval").glob("*.json")
    victims = {}
    for name in (
        "recipe.tmp",
        "provenance.tmp",
        "metrics.tmp",
        "checkpoints/last.tmp",
        f"eval/{written.stem}.tmp",
    ):
        victim = tmp_path / "outside" / name.replace("/", "_")
        victim.parent.mkdir(exist_ok=True)
        victim.write_text(VICTIM_TEXT)
        (run / name).symlink_to(victim)
        victims[name] = victim
    assert gcnt(["train", "--resume", str(run), "collector.total_frames=60"]) == 0
    assert gcnt(["eval", str(run), "--episodes", "1"]) == 0
    for name, victim in victims.items():
        assert victim.read_text() == VICTIM_TEXT, name
    for name in ("recipe.yaml", "provenance.json", "metrics.jsonl", "checkpoints/last.pt"):
        assert (run / name).is_file() and not (run / name).is_symlink(), name
    assert not (run / "eval" / written.name).is_symlink()


def test_eval_json_to_a_device_is_written_into_and_to_a_folder_refused(trained, tmp_path, capsys):
    run = _copy(trained, tmp_path)
    fifo = tmp_path / "results.fifo"
    os.mkfifo(fifo)
    with _read_fifo(fifo) as got:
        assert gcnt(["eval", str(run), "--episodes", "1", "--json", str(fifo)]) == 0
    assert fifo.is_fifo() and b'"robots"' in got[0]
    folder = tmp_path / "results"
    folder.mkdir()
    line = error_line(capsys, ["eval", str(run), "--episodes", "1", "--json", str(folder)])
    assert f"{folder}: a folder, not a regular file" in line, line
    assert folder.is_dir() and not any(folder.iterdir())


def test_links_at_a_figure_caption_or_csv_are_refused_untouched(trained, tmp_path, capsys):
    runs = tmp_path / "runs"
    shutil.copytree(trained, runs / "run")
    figures = runs / "figures"
    figures.mkdir()
    victim = _victim(tmp_path)
    for name in ("curves.caption.txt", "curves.csv"):
        (figures / name).symlink_to(victim)
    line = error_line(capsys, ["curves", str(runs)])
    assert "not a regular file" in line and str(figures) in line, line
    assert victim.read_text() == VICTIM_TEXT
    assert all((figures / n).is_symlink() for n in ("curves.caption.txt", "curves.csv"))


# --- sweeps and imports


def _dry_sweep(tmp_path: Path) -> Path:
    sw = tmp_path / "sw"
    argv = ["sweep", str(ROOT / "recipes" / "quickstart.yaml"), "--dir", str(sw), "--dry-run"]
    assert gcnt([*argv, *TINY_SWEEP_OVERRIDES]) == 0
    return sw


def _sweep_in_a_process(sw: Path) -> subprocess.CompletedProcess:
    """``gcnt sweep SW`` in a process of its own, so that a hang fails the test."""
    return subprocess.run(
        [sys.executable, "-m", "gcnt.cli", "sweep", str(sw)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )


@pytest.mark.parametrize("kind", ["link", "fifo"])  # (it is replaced, never written into)
def test_a_sweep_lock_that_is_not_a_regular_file_is_one_line(tmp_path, kind):
    sw = _dry_sweep(tmp_path)
    victim = _victim(tmp_path)
    lock = sw / ".sweep.lock"
    _make(lock, kind, victim)
    out = _sweep_in_a_process(sw)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr[-2000:]
    assert f"{lock}: a " in out.stderr, out.stderr
    assert victim.read_text() == VICTIM_TEXT


def test_a_fifo_as_a_run_log_is_one_line_before_any_run_starts(tmp_path):
    from gcnt.sweep import Manifest
    from gcnt.sweep.local import run_log_path

    sw = _dry_sweep(tmp_path)
    (spec,) = Manifest.load(sw).runs
    log = run_log_path(sw, spec)
    log.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(log)
    out = _sweep_in_a_process(sw)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr[-2000:]
    assert f"{log}: a FIFO" in out.stderr, out.stderr
    assert not Path(spec.run_dir).exists()


@pytest.mark.parametrize("kind", ["link", "fifo", "hardlink"])
def test_an_import_lock_that_is_not_a_regular_file_is_one_line(tmp_path, capsys, kind):
    victim = _victim(tmp_path)
    morph = tmp_path / "morph"
    morph.mkdir()
    lock = morph / ".import.lock"
    _make(lock, kind, victim)
    line = error_line(capsys, ["import-unimal", str(tmp_path / "nowhere"), "--out", str(morph)])
    assert f"{lock}: a " in line and "import lock" in line, line
    assert victim.read_text() == VICTIM_TEXT


# --- starts that race


def test_a_start_refused_by_a_racing_one_leaves_the_winner_directory(
    recipe_file, tmp_path, capsys, monkeypatch
):
    """Two starts into one new run_dir: the one that made the directory and holds its lock
    keeps it; the other, refused, removes nothing it did not make."""
    from cli_helpers import holding

    import gcnt.rl.loop as loop

    run = tmp_path / "new-run"
    real_prepare = loop.prepare
    with contextlib.ExitStack() as stack:

        def prepare_while_another_starts(*args, **kwargs):
            # while this start builds its networks, another claims the directory
            stack.enter_context(holding("gcnt.run.lock:run_lock", run))
            return real_prepare(*args, **kwargs)

        monkeypatch.setattr(loop, "prepare", prepare_while_another_starts)
        line = error_line(capsys, ["train", str(recipe_file), f"run_dir={run}"])
        assert f"{run} is being trained by process" in line, line
        assert run.is_dir() and (run / ".lock").is_file()  # the winner's, still there


@pytest.mark.parametrize("where", ["robots", "checkpoints/buffers", "checkpoints/last.pt"])
def test_a_link_at_a_folder_or_the_checkpoint_inside_a_run_is_refused_before_training(
    tmp_path, capsys, where
):
    """A folder gcnt writes into (the stored robots, the replay's folder) or the checkpoint
    itself as a link out of the run: ``train --resume`` refuses it in one line before any
    training (nothing trained is lost, nothing written outside)."""
    from cli_helpers import tiny_td3_recipe

    recipe = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=[])
    run = tmp_path / "run"
    assert gcnt(["train", str(recipe), f"run_dir={run}", "td3.checkpoint_buffers=true"]) == 0
    outside = tmp_path / "outside"
    outside.mkdir()
    target = run / where
    if target.exists():
        moved = outside / target.name
        shutil.move(target, moved)
        target.symlink_to(moved, target_is_directory=moved.is_dir())
    else:
        target.symlink_to(outside, target_is_directory=True)
    before = sorted(p.name for p in outside.rglob("*"))
    metrics = (run / "metrics.jsonl").read_text()
    capsys.readouterr()
    assert gcnt(["train", "--resume", str(run), "collector.total_frames=80"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "link" in err and where.split("/")[-1] in err, err
    assert sorted(p.name for p in outside.rglob("*")) == before
    assert (run / "metrics.jsonl").read_text() == metrics
