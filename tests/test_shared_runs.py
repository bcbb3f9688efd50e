"""A run handed to someone else: it keeps its robots (content-addressed copies in the run
directory), records its plugins by identity and never imports code it names, and loads from
Python (``gcnt.load_policy``, ``gcnt.load_run``). Runs written before robots were stored still
evaluate, resume and plot."""

from __future__ import annotations

import hashlib
import logging
import shutil
from pathlib import Path

import pytest
import yaml
from cli_helpers import ROOT, tiny_td3_recipe

import gcnt
from gcnt.cli import main as gcnt_main
from gcnt.morphology import catalogues
from gcnt.rl.run_dir import RunDir
from gcnt.run_record import robot_sha256

OLD_RUN = ROOT / "tests" / "data" / "td3_run_b52e8ec"
HOPPER = ROOT / "src" / "gcnt" / "data" / "morphologies" / "smpenv" / "hopper_3.xml"


@pytest.fixture(autouse=True)
def _unpinned(monkeypatch):
    # gcnt's own log lines reach caplog too (the CLI stops them at its handler otherwise)
    monkeypatch.setattr(logging.getLogger("gcnt"), "propagate", True)
    yield
    catalogues._PINNED.clear()
    catalogues._load_pinned.cache_clear()


def _old_run(tmp_path: Path) -> Path:
    run = tmp_path / "old"
    shutil.copytree(OLD_RUN, run)
    return run


def test_a_run_on_a_robot_file_evaluates_after_the_file_is_gone(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    robot = mine / "myhopper.xml"
    robot.write_text(HOPPER.read_text())
    recipe = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=[])
    run = tmp_path / "run"
    argv = ["train", str(recipe), f"run_dir={run}", f"env.robots=[{robot}]"]
    assert gcnt_main(argv) == 0
    record = yaml.safe_load((run / "recipe.yaml").read_text())["resolved"]["robots"]
    assert record["train"] == ["myhopper"]
    sha = record["index"]["myhopper"]["sha256"]
    stored = run / "robots" / f"{sha}.xml"
    assert hashlib.sha256(stored.read_bytes()).hexdigest() == sha
    assert record["index"]["myhopper"]["registered"] is False
    shutil.rmtree(mine)
    catalogues._PINNED.clear()
    capsys.readouterr()
    assert gcnt_main(["eval", str(run), "--robots", "train", "--episodes", "1"]) == 0
    assert "myhopper" in capsys.readouterr().out
    assert gcnt_main(["train", "--resume", str(run), "collector.total_frames=60"]) == 0
    assert RunDir(run).load_checkpoint()["env_steps"] == 60


def test_a_run_on_an_imported_set_evaluates_after_the_folder_and_variable_are_gone(
    tmp_path, monkeypatch, capsys
):
    """A robot set of the user's own (GCNT_MORPHOLOGIES): here a catalogue folder with one robot,
    as ``gcnt import-unimal`` writes one."""
    from test_unimal_import import MADE_AS, _robot_xml, _zip

    download = tmp_path / "download" / "unimals_100"
    for folder, names in MADE_AS.items():
        for sub in ("xml", "metadata", "unimal_init"):
            (download / folder / sub).mkdir(parents=True)
        for name, made_as in names.items():
            (download / folder / "xml" / f"{name}.xml").write_text(_robot_xml(made_as))
            (download / folder / "metadata" / f"{name}.json").write_text("{}")
            (download / folder / "unimal_init" / f"{name}.pkl").write_bytes(b"not read")
    morph = tmp_path / "morphologies"
    morph.mkdir()
    monkeypatch.setenv("GCNT_MORPHOLOGIES", str(morph))
    catalogues.refresh_catalogues()
    try:
        assert gcnt_main(["import-unimal", str(_zip(download, tmp_path / "u.zip"))]) == 0
        robot = next(iter(MADE_AS["train"]))
        run = tmp_path / "run"
        argv = ["train", "quickstart", f"run_dir={run}", "env.benchmark=unimal"]
        argv += [f"env.robots=[{robot}]", "env.test_robots=[]", "collector.total_frames=40"]
        argv += ["td3.init_random_frames=20", "td3.batch_size=8", "env.max_episode_steps=10"]
        argv += ["network.kwargs={d_model: 8, layers: 1, ff: 8, heads: 2}", "network.preset=smpenv"]
        argv += ["logger.backend=none", "eval.episodes=1", "checkpoint_interval=40"]
        assert gcnt_main(argv) == 0
    finally:
        monkeypatch.delenv("GCNT_MORPHOLOGIES")
        shutil.rmtree(morph)
        catalogues.refresh_catalogues()
    catalogues._PINNED.clear()
    with pytest.raises(catalogues.UnknownRobotError):
        catalogues.load_named(robot)
    capsys.readouterr()
    assert gcnt_main(["eval", str(run), "--robots", "train", "--episodes", "1"]) == 0
    assert robot in capsys.readouterr().out


def test_a_registered_robot_of_another_content_is_used_with_a_warning_naming_both(tmp_path, caplog):
    run = tmp_path / "run"
    recipe = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=[])
    assert gcnt_main(["train", str(recipe), f"run_dir={run}"]) == 0
    data = yaml.safe_load((run / "recipe.yaml").read_text())
    entry = data["resolved"]["robots"]["index"]["hopper_3"]
    assert entry["registered"] is True
    assert entry["sha256"] == robot_sha256(catalogues.load_named("hopper_3"))
    entry["sha256"] = "0" * 64  # as if trained on another hopper_3
    (run / "recipe.yaml").write_text(yaml.safe_dump(data))
    with caplog.at_level(logging.WARNING, logger="gcnt"):
        logging.getLogger("gcnt").propagate = True
        RunDir(run).load_recipe(anywhere=True)
    (line,) = [r.getMessage() for r in caplog.records if "hopper_3" in r.getMessage()]
    assert (
        "0000000000000000" in line
        and entry_hash(line) == robot_sha256(catalogues.load_named("hopper_3"))[:16]
    )


def entry_hash(line: str) -> str:
    """The registered robot's hash in the warning (the last one it names)."""
    return line.split("sha256 ")[-1].split(",")[0].split()[0]


def test_load_policy_acts_on_a_reset_of_a_new_env(tmp_path):
    import torch

    from gcnt.keys import ACTION

    run = _old_run(tmp_path)
    record = gcnt.load_run(run)
    assert record.recipe["algo"] == "td3" and record.metrics and record.evaluations
    env = gcnt.make_env(run, ["hopper_3", "walker_2_main"])
    policy = gcnt.load_policy(run, robots=["hopper_3", "walker_2_main"])
    td = env.reset()
    first = policy(td.clone())[ACTION]
    again = policy(td.clone())[ACTION]
    assert first.shape[0] == 2 and torch.equal(first, again)  # deterministic
    assert torch.isfinite(first).all() and first.abs().max() <= 1
    env.step(policy(td))
    env.close()
    with pytest.raises(ValueError, match="last checkpoint only"):
        gcnt.load_policy(run, checkpoint="step10")


def test_a_run_that_predates_stored_robots_evaluates_resumes_and_plots(tmp_path, capsys):
    run = _old_run(tmp_path)
    capsys.readouterr()
    assert gcnt_main(["eval", str(run), "--robots", "train", "--episodes", "1"]) == 0
    assert capsys.readouterr().err.count("predates stored robots") == 1
    assert gcnt_main(["train", "--resume", str(run), "collector.total_frames=45"]) == 0
    assert "robots" in yaml.safe_load((run / "recipe.yaml").read_text())["resolved"]
    assert (run / "robots").is_dir()  # the resumed run now keeps its robots
    assert gcnt_main(["curves", str(run), "--out", str(tmp_path / "fig")]) == 0
