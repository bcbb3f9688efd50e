"""Provenance: ``gcnt.run.provenance.collect`` on a git repository (and where git cannot tell), the
``provenance.json`` of a tiny real run and the session each resume adds, the W&B run a resumed
(and moved) run continues with its tags, the sweep manifest's sessions, the W&B group and tags
of a sweep run and its log's one "done" line, and the captions of ``gcnt curves`` and ``gcnt
tables``."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

import gcnt
from gcnt import sweep as S
from gcnt.cli import main
from gcnt.run import provenance as P
from gcnt.run.directory import RunDir

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "recipes" / "quickstart.yaml"

needs_git = pytest.mark.skipif(shutil.which("git") is None, reason="no git binary")


def _git(repo: Path, *args: str) -> str:
    identity = ["-c", "user.name=t", "-c", "user.email=t@example.org", "-c", "commit.gpgsign=false"]
    return subprocess.run(
        ["git", *identity, "-C", str(repo), *args], capture_output=True, text=True, check=True
    ).stdout.strip()


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    """A git repository with one commit of ``a.txt``."""
    repo = tmp_path / "repo"
    repo.mkdir()
    _git(repo, "init", "-q")
    (repo / "a.txt").write_text("a\n")
    _git(repo, "add", "a.txt")
    _git(repo, "commit", "-q", "-m", "first")
    return repo


@needs_git
def test_collect_records_the_commit_and_changes_to_tracked_files(repo: Path) -> None:
    s = P.collect(["gcnt", "train", "x.yaml"], repo=repo)
    assert s["git_commit"] == _git(repo, "rev-parse", "HEAD") and s["git_dirty"] is False
    assert s["git_note"] is None and s["gcnt_version"] == gcnt.__version__
    assert s["command"] == ["gcnt", "train", "x.yaml"]
    assert set(s["packages"]) == set(P.PACKAGES) and s["packages"]["numpy"]
    assert s["python"] == ".".join(map(str, sys.version_info[:3]))
    assert s["platform"] and s["started"]
    # what is handed on with a run: the host as a hash, no folder of this machine
    assert s["host"] == P.host_hash() and socket.gethostname() not in s["host"]
    assert not {"hostname", "cwd", "executable"} & set(s)
    json.dumps(s)  # plain JSON
    (repo / "new.txt").write_text("untracked\n")
    assert P.git_state(repo)["dirty"] is False  # untracked files are not changes
    (repo / "a.txt").write_text("changed\n")
    assert P.git_state(repo)["dirty"] is True


@needs_git
def test_where_git_cannot_tell_the_commit_is_none_with_the_reason(
    tmp_path: Path, repo: Path, monkeypatch
) -> None:
    monkeypatch.setattr(P, "GIT_CACHE_S", -1.0)  # every query asks git
    plain = tmp_path / "plain"
    plain.mkdir()
    state = P.git_state(plain)
    assert state["commit"] is None and "not a git repository" in state["note"]
    # an installed package found inside some other checkout (a virtual environment in a
    # project) that does not track it: not that checkout's commit
    for where in (repo / "venv" / "gcnt", plain / "gcnt"):
        where.mkdir(parents=True)
        (where / "__init__.py").write_text("")
        monkeypatch.setattr(gcnt, "__file__", str(where / "__init__.py"))
        state = P.git_state()
        assert state["commit"] is None and "not in a git checkout" in state["note"], state
    # the package tracked by a checkout: that checkout's commit
    _git(repo, "add", "venv/gcnt/__init__.py")
    _git(repo, "commit", "-q", "-m", "package")
    monkeypatch.setattr(gcnt, "__file__", str(repo / "venv" / "gcnt" / "__init__.py"))
    assert P.git_state()["commit"] == _git(repo, "rev-parse", "HEAD")
    monkeypatch.setenv("PATH", str(tmp_path / "no-bin"))
    state = P.collect(["x"], repo=repo)  # a session is still recorded
    assert state["git_commit"] is None and state["git_note"] == "git is not installed"


@needs_git
def test_an_installed_package_names_the_commit_its_build_recorded(
    tmp_path: Path, repo: Path, monkeypatch
) -> None:
    """A package outside any checkout reads the commit its build wrote (setup.py); a damaged
    record is unknown with the reason; a checkout's own git state wins over a stray record."""
    monkeypatch.setattr(P, "GIT_CACHE_S", -1.0)  # every query asks git
    record = {"commit": "abc1234" + "0" * 33, "dirty": True}
    installed = tmp_path / "site" / "gcnt"
    tracked = repo / "src" / "gcnt"
    for where in (installed, tracked):
        where.mkdir(parents=True)
        (where / "__init__.py").write_text("")
        (where / P.BUILD_FILE).write_text(json.dumps(record))
    monkeypatch.setattr(gcnt, "__file__", str(installed / "__init__.py"))
    state = P.git_state()
    assert (state["commit"], state["dirty"]) == (record["commit"], True)
    assert state["note"] == "recorded by the build of gcnt"
    assert P.this_code("tables").endswith("at commit abc1234-dirty")
    for bad in ("{not json", json.dumps({"commit": "", "dirty": False}), "[]"):
        (installed / P.BUILD_FILE).write_text(bad)
        state = P.git_state()
        assert state["commit"] is None and "not in a git checkout" in state["note"], state
        assert P.BUILD_FILE in state["note"]
    _git(repo, "add", "src/gcnt/__init__.py")
    _git(repo, "commit", "-q", "-m", "package")
    monkeypatch.setattr(gcnt, "__file__", str(tracked / "__init__.py"))
    state = P.git_state()
    assert (state["commit"], state["note"]) == (_git(repo, "rev-parse", "HEAD"), None)


def test_the_runs_one_process_starts_together_ask_git_once(monkeypatch) -> None:
    asked = []
    monkeypatch.setattr(P, "_git_state", lambda repo: asked.append(repo) or P._unknown("x"))
    monkeypatch.setattr(P, "_package_git", {})
    for _ in range(3):  # e.g. gcnt train --seeds 0,1,2 creating three run directories
        assert P.collect(["x"])["git_note"] == "x"
    assert asked == [None]


def _sessions(run: Path) -> list[dict]:
    return json.loads((run / "provenance.json").read_text())["sessions"]


def _wandb_runs(run: Path) -> list[dict]:
    """The run record (id, group, tags, config) of each W&B session folder of ``run``, oldest
    first, read with ``wandb leet inspect`` (no network)."""
    wandb = shutil.which("wandb") or str(Path(sys.executable).parent / "wandb")
    out = []
    for folder in sorted((run / "wandb").glob("offline-run-*")):
        lines = subprocess.run(
            [wandb, "leet", "inspect", "--json", str(folder)],
            capture_output=True,
            text=True,
            timeout=120,
            check=True,
        ).stdout.splitlines()
        records = [json.loads(x) for x in lines if x.startswith("{")]
        out.append(next(r["run"] for r in records if r["type"] == "run"))
    return out


@pytest.mark.slow
def test_a_run_records_each_session_and_continues_its_wandb_run_when_moved(
    tmp_path: Path, recipe_file: Path, monkeypatch
) -> None:
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_CONFIG_DIR", str(tmp_path / "wandb-config"))
    run = tmp_path / "run"
    argv = ["train", str(recipe_file), f"run_dir={run}", "logger.backend=wandb", "logger.tags=[a]"]
    assert main(argv) == 0
    (first,) = _sessions(run)
    assert first["command"] == ["gcnt", *argv]
    here = P.git_state()  # this checkout's commit, or None where the package is installed
    assert (first["git_commit"], first["git_dirty"]) == (here["commit"], here["dirty"])
    assert first["gcnt_version"] == gcnt.__version__ and first["packages"]["torch"]
    assert first["cuda"] is not None  # torch is loaded in a run: its CUDA build (None on CPU)

    # moved, then resumed with a longer budget: a second session, the same W&B run
    moved = tmp_path / "moved"
    run.rename(moved)
    assert main(["train", "--resume", str(moved), "collector.total_frames=60"]) == 0
    sessions = _sessions(moved)
    assert len(sessions) == 2 and sessions[1]["command"][:3] == ["gcnt", "train", "--resume"]
    assert sessions[0] == first
    # W&B writes one folder per session: both carry the one run id, group and tags
    records = _wandb_runs(moved)
    assert len(records) == 2 and len({r["run_id"] for r in records}) == 1
    for r in records:
        assert r["run_group"] == "tiny-td3-gcnt" and set(r["tags"]) == {"a", "seed:0"}
    assert records[1]["config"]["update"]["code"]["git_commit"] == here["commit"]


def test_a_tag_wandb_refuses_is_one_line(capsys, recipe_file: Path, tmp_path: Path) -> None:
    from cli_helpers import error_line

    line = error_line(
        capsys,
        ["train", str(recipe_file), f"run_dir={tmp_path / 'r'}", "logger.backend=wandb",
         f"logger.tags=[{'x' * 65}]"],
    )  # fmt: skip
    assert "logger.tags" in line and "65 characters" in line
    assert not (tmp_path / "r").exists()


def test_a_damaged_provenance_file_is_kept_aside_and_a_new_list_begun(tmp_path: Path) -> None:
    (tmp_path / "provenance.json").write_text("{not json")
    RunDir(tmp_path).record_session()
    assert len(_sessions(tmp_path)) == 1
    assert (tmp_path / "provenance.json.unreadable").read_text() == "{not json"


def _run_with(root: Path, name: str, sessions: list[tuple[str, bool]] | None) -> Path:
    """A run directory logging a training return, with sessions at (commit, dirty)."""
    path = root / name
    path.mkdir(parents=True)
    recipe = {"task": "T", "algo": "td3", "seed": len(list(root.iterdir())),
              "network": {"name": "gcnt"}, "collector": {"total_frames": 20}}  # fmt: skip
    (path / "recipe.yaml").write_text(json.dumps(recipe))
    run = RunDir(path)
    for step in (10, 20):
        run.log_metrics({"env_steps": step, "train_return/mean": float(step)})
    if sessions is not None:
        for commit, dirty in sessions:
            P.add_session(path, {"gcnt_version": "0.1.0", "git_commit": commit, "git_dirty": dirty})
    return path


def test_the_curves_caption_names_the_commits_of_the_runs(tmp_path: Path, capsys) -> None:
    abc, def_ = "abc1234" + "0" * 33, "def5678" + "0" * 33
    runs = tmp_path / "runs"
    for i in range(3):
        _run_with(runs, f"clean{i}", [(abc, False)])
    _run_with(runs, "dirty", [(def_, True)])
    _run_with(runs, "resumed", [(abc, False), (def_, False)])
    _run_with(runs, "installed", [(None, None)])
    _run_with(runs, "old", None)
    expected = (
        "runs from gcnt 0.1.0 at commit abc1234 (3 runs), abc1234+def5678 (1 run), "
        "def5678-dirty (1 run), unknown (1 run); provenance not recorded (1 run)"
    )  # the most runs first
    assert P.caption(sorted(runs.iterdir())) == expected
    out = tmp_path / "fig"
    assert main(["curves", str(runs), "--out", str(out)]) == 0
    assert expected in capsys.readouterr().out
    assert (out / "curves.caption.txt").read_text() == expected + "\n"


def test_the_tables_caption_names_the_code_that_computed_them(tmp_path: Path, capsys) -> None:
    assert main(["tables", "--presets", "smpenv", "--out", str(tmp_path)]) == 0
    here = P.git_state()
    label = P.code_label({"git_commit": here["commit"], "git_dirty": here["dirty"]})
    expected = f"tables from gcnt {gcnt.__version__} at commit {label}"
    assert expected in capsys.readouterr().out
    assert (tmp_path / "params.caption.txt").read_text() == expected + "\n"
    assert (tmp_path / "params.md").read_text().rstrip().endswith(f"_{expected}_")


def test_sweep_runs_are_grouped_per_task_and_method_and_tagged_with_the_sweep(
    tmp_path: Path,
) -> None:
    from cli_helpers import TINY_SWEEP_OVERRIDES

    specs = S.expand(
        [QUICKSTART], tmp_path / "sw", methods=["gcnt", "swat"], seeds=[0, 1],
        overrides=[*TINY_SWEEP_OVERRIDES, "logger.tags=[mine]"],
    )  # fmt: skip
    for s in specs:
        assert f'logger.group="sw/quickstart/td3-{s.method}"' in s.overrides
        assert 'logger.tags=["mine", "sweep:sw"]' in s.overrides


@pytest.mark.slow
def test_a_sweep_records_its_sessions_reports_done_once_and_tags_its_runs(
    tmp_path: Path, capsys, monkeypatch
) -> None:
    from cli_helpers import TINY_SWEEP_OVERRIDES

    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_CONFIG_DIR", str(tmp_path / "wandb-config"))
    sw = tmp_path / "sw"
    argv = ["sweep", str(QUICKSTART), "--seeds", "1", "--jobs", "1", "--dir", str(sw),
            *TINY_SWEEP_OVERRIDES, "--eval", "test", "--episodes", "1"]  # fmt: skip
    assert main(argv) == 0
    out = capsys.readouterr().out
    # one line per change of state (``<time>  <run>: <state>``): running, training done, then
    # its evaluation done
    changes = [line.split("  ", 1)[1] for line in out.splitlines() if line[:4].isdigit()]
    assert changes == [
        "quickstart/td3-gcnt/seed1: running",
        "quickstart/td3-gcnt/seed1: done",
        "quickstart/td3-gcnt/seed1: done; eval test: done",
    ]
    (first,) = json.loads((sw / S.MANIFEST).read_text())["provenance"]["sessions"]
    assert first["command"] == ["gcnt", *argv]
    assert first["git_commit"] == P.git_state()["commit"]
    (record,) = _wandb_runs(sw / "quickstart" / "td3-gcnt" / "seed1")
    assert record["run_group"] == "sw/quickstart/td3-gcnt"
    assert set(record["tags"]) == {"sweep:sw", "seed:1"}
    # continued (nothing left to do): a second session
    assert main(["sweep", str(sw)]) == 0
    assert len(json.loads((sw / S.MANIFEST).read_text())["provenance"]["sessions"]) == 2
