"""Run directories a careless or hostile user crafted: the analysis commands refuse a malformed
``recipe.yaml`` in one line naming the file and key, as ``gcnt eval`` does, ``init_from``
records that lead back to their own run are a cycle, and a link out of the run directory is
refused before any work for every folder gcnt writes into."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml
from cli_helpers import error_line

from gcnt.run.directory import WRITTEN


def _copy(trained: Path, tmp_path: Path, name: str = "run") -> Path:
    out = tmp_path / name
    shutil.copytree(trained, out)
    return out


def _edit_recipe(run: Path, edit) -> None:
    data = yaml.safe_load((run / "recipe.yaml").read_text())
    edit(data)
    (run / "recipe.yaml").write_text(yaml.safe_dump(data))


@pytest.mark.parametrize(
    "key, value, said",
    [
        ("seed", "abc", "seed must be a whole number, not 'abc'"),
        ("seed", [1], "seed must be a whole number, not [1]"),
        ("seed", float("inf"), "seed must be a whole number, not inf"),
        ("env.robots", 5, "env.robots must be a list of robot specs, not 5"),
        ("resolved.init_from", {"run": 12345}, "resolved.init_from.run must be a run directory"),
    ],
)
def test_a_malformed_run_recipe_is_one_line_naming_file_and_key(
    trained, tmp_path, capsys, key, value, said
):
    run = _copy(trained, tmp_path)

    def edit(data):
        *path, last = key.split(".")
        node = data
        for p in path:
            node = node.setdefault(p, {})
        node[last] = value

    _edit_recipe(run, edit)
    for command in ("curves", "zeroshot"):
        line = error_line(capsys, [command, str(run)])
        assert f"{run / 'recipe.yaml'}: {said}" in line, line


def test_a_deeply_nested_run_recipe_is_one_line(trained, tmp_path, capsys):
    run = _copy(trained, tmp_path)
    (run / "recipe.yaml").write_text("seed: " + "[" * 50_000 + "]" * 50_000 + "\n")
    line = error_line(capsys, ["curves", str(run)])
    assert f"{run / 'recipe.yaml'}: nested deeper than 100 levels" in line, line


def test_init_from_records_that_lead_back_are_a_cycle(trained, tmp_path, capsys):
    a, b = _copy(trained, tmp_path, "a"), _copy(trained, tmp_path, "b")
    for run, source in ((a, b), (b, a)):
        _edit_recipe(
            run, lambda d, s=source: d.setdefault("resolved", {}).update(init_from={"run": str(s)})
        )
    line = error_line(capsys, ["curves", str(a)])
    assert "resolved.init_from.run leads back to this run" in line, line
    own = _copy(trained, tmp_path, "own")  # a record naming its own run
    _edit_recipe(own, lambda d: d.setdefault("resolved", {}).update(init_from={"run": str(own)}))
    line = error_line(capsys, ["curves", str(own)])
    assert "leads back to this run" in line, line


@pytest.mark.parametrize("name", WRITTEN)
def test_a_link_out_of_the_run_directory_is_refused_before_any_work(
    trained, tmp_path, capsys, name
):
    """A crafted run whose ``checkpoints`` (or any folder gcnt writes into) points at another
    run's: resuming or evaluating it is refused, and the other run is untouched."""
    victim = _copy(trained, tmp_path, "victim")
    run = _copy(trained, tmp_path, "crafted")
    target = run / name
    if target.is_dir():
        shutil.rmtree(target)
    else:
        target.unlink(missing_ok=True)
    (victim / name).parent.mkdir(parents=True, exist_ok=True)  # a nested folder's parent
    (victim / name).mkdir(exist_ok=True) if "." not in name else (victim / name).touch()
    target.parent.mkdir(parents=True, exist_ok=True)
    target.symlink_to(victim / name)
    before = {p: p.stat().st_mtime_ns for p in victim.rglob("*") if p.is_file()}
    for argv in (
        ["train", "--resume", str(run), "collector.total_frames=60"],
        ["eval", str(run), "--episodes", "1"],
    ):
        line = error_line(capsys, argv)
        assert f"{target}: a link out of the run directory" in line, line
    assert {p: p.stat().st_mtime_ns for p in victim.rglob("*") if p.is_file()} == before


def test_a_run_recipes_compile_cache_dir_is_never_used(trained, tmp_path, monkeypatch, caplog):
    """torch's compile cache holds code that torch loads and runs: the folder a received run's
    recipe names (``compile.cache_dir``) is neither made nor used when the run is resumed or
    loaded (one info line); a folder given on the command line is."""
    import logging
    import os

    import torch

    from gcnt.api import load_policy
    from gcnt.cli import main as gcnt
    from gcnt.run.directory import RunDir

    run = _copy(trained, tmp_path)
    planted = tmp_path / "planted"
    _edit_recipe(run, lambda d: d["compile"].update(compile=True, cache_dir=str(planted)))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.delenv("TORCHINDUCTOR_CACHE_DIR", raising=False)
    monkeypatch.setattr(torch, "compile", lambda fn, **kw: fn)  # where it caches, not compiling
    with caplog.at_level(logging.INFO, logger="gcnt"):
        assert RunDir(run).load_recipe(anywhere=True).compile.cache_dir is None
    assert f"its compile.cache_dir ({planted}) is not used" in caplog.text
    mine = RunDir(run).load_recipe([f"compile.cache_dir={tmp_path / 'mine'}"])
    assert mine.compile.cache_dir == str(tmp_path / "mine")  # the command's own: used

    steps = RunDir(run).load_checkpoint()["env_steps"]
    assert gcnt(["train", "--resume", str(run), f"collector.total_frames={steps + 20}"]) == 0
    assert RunDir(run).load_checkpoint()["env_steps"] > steps
    assert os.environ["TORCHINDUCTOR_CACHE_DIR"] == str((tmp_path / "xdg/gcnt/inductor").resolve())
    assert yaml.safe_load((run / "recipe.yaml").read_text())["compile"]["cache_dir"] is None
    _edit_recipe(run, lambda d: d["compile"].update(cache_dir=str(planted)))
    load_policy(run)
    assert not planted.exists()
