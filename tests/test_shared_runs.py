"""A run handed to someone else: it keeps its robots (content-addressed copies in the run
directory), records its plugins by identity and never imports code it names, and loads from
Python (``gcnt.load_policy``, ``gcnt.load_run``). Runs written before robots were stored still
evaluate, resume and plot."""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
from pathlib import Path

import pytest
import yaml
from cli_helpers import ROOT, tiny_td3_recipe

import gcnt
from gcnt.cli import main as gcnt_main
from gcnt.morphology import catalogues
from gcnt.run.directory import RunDir
from gcnt.run.record import robot_sha256

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


def _run_on_robot_file(tmp_path: Path) -> tuple[Path, Path]:
    """A tiny run trained on a robot file of its own (``mine/myhopper.xml``): (run, folder)."""
    mine = tmp_path / "mine"
    mine.mkdir()
    robot = mine / "myhopper.xml"
    robot.write_text(HOPPER.read_text())
    recipe = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=[])
    run = tmp_path / "run"
    assert gcnt_main(["train", str(recipe), f"run_dir={run}", f"env.robots=[{robot}]"]) == 0
    return run, mine


def test_a_run_on_a_robot_file_evaluates_after_the_file_is_gone(tmp_path, capsys):
    run, mine = _run_on_robot_file(tmp_path)
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


def _payload(path: Path, marker: Path) -> Path:
    path.write_text(f"open({str(marker)!r}, 'a').write('ran {path.name}\\n')\n")
    return path


def test_a_received_run_or_sweep_runs_no_code_it_names(tmp_path, monkeypatch, capsys):
    """A run and a sweep naming payloads (by absolute path, by a path relative to the run, by a
    module name that would import) in every place they record plugins: no command runs any."""
    marker = tmp_path / "RAN"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    absolute = _payload(elsewhere / "payload_abs.py", marker)
    _payload(elsewhere / "payload_mod.py", marker)
    monkeypatch.syspath_prepend(str(elsewhere))  # the module name would import
    run = _old_run(tmp_path)
    _payload(run / "payload_rel.py", marker)
    named = [str(absolute), "payload_rel.py", "payload_mod"]
    data = yaml.safe_load((run / "recipe.yaml").read_text())
    data["plugins"] = named
    data["init_from"] = None
    data["resolved"] = {**data.get("resolved", {}), "plugins": [{"name": n} for n in named]}
    (run / "recipe.yaml").write_text(yaml.safe_dump(data))
    monkeypatch.chdir(run)
    out = tmp_path / "out"
    commands = [
        ["eval", str(run), "--robots", "train", "--episodes", "1"],
        ["train", "--resume", str(run), "collector.total_frames=45"],
        ["curves", str(run), "--out", str(out)],
        ["zeroshot", str(run), "--out", str(out)],
        ["variants", str(run), "--out", str(out)],
        ["embed", str(run), "--robots", "hopper_3", "walker_2_main", "--out", str(out)],
        ["strobe", str(run), "--robot", "hopper_3", "--steps", "5", "--out", str(out)],
    ]
    clean = {k: v for k, v in data.items() if k not in ("plugins", "resolved", "run_dir")}
    (tmp_path / "clean.yaml").write_text(yaml.safe_dump(clean))
    commands.append(
        ["train", str(tmp_path / "clean.yaml"), "--init-from", str(run), f"run_dir={out}/ft"]
    )
    # a received sweep: its manifest's runs name the payloads (an override) and so does the
    # recipe it trains from
    sweep = tmp_path / "sw"
    assert gcnt_main(["sweep", str(tmp_path / "clean.yaml"), "--dry-run", "--dir", str(sweep)]) == 0
    (sweep / "recipe.yaml").write_text(yaml.safe_dump({**clean, "plugins": named}))
    manifest = json.loads((sweep / "manifest.json").read_text())
    for r in manifest["runs"]:
        r["recipe"] = str(sweep / "recipe.yaml")
        r["overrides"].append(f"plugins={json.dumps(named)}")
    (sweep / "manifest.json").write_text(json.dumps(manifest))
    commands += [["sweep", str(sweep), "--status"], ["sweep", str(sweep), "--jobs", "1"]]
    for argv in commands:
        capsys.readouterr()
        rc = gcnt_main(argv)
        err = capsys.readouterr().err
        assert not marker.exists(), (argv, marker.read_text())
        # zeroshot and variants read the run, then find no evaluation of theirs to show
        assert rc == (2 if argv[0] in ("zeroshot", "variants") else 0), (argv, err[-2000:])
    assert json.loads((sweep / "manifest.json").read_text())["runs"][0]["state"] == "done"
    assert not marker.exists()


_BOX_OBJ = (
    "".join(
        f"v {x} {y} {z}\n"
        for z in (-0.05, 0.05)
        for x, y in ((-0.05, -0.05), (0.05, -0.05), (0.05, 0.05), (-0.05, 0.05))
    )
    + "f 1 2 3\nf 1 3 4\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\n"
)
_BOX_OBJ += "f 4 1 5\nf 4 5 8\n"


def test_a_stored_robot_keeps_the_asset_files_it_references(tmp_path):
    """A robot file whose mesh lives in a folder of its own (``meshdir``): the run stores the
    mesh beside the MJCF, named by its hash, and the stored copy compiles once the robot's folder
    is gone."""
    import re

    from gcnt.morphology.robot import load_robot
    from gcnt.run.record import store_robots

    folder = tmp_path / "mine"
    (folder / "meshes").mkdir(parents=True)
    (folder / "meshes" / "box.obj").write_text(_BOX_OBJ)
    text = HOPPER.read_text().replace(
        "<worldbody>", '<asset><mesh name="box" file="box.obj"/></asset>\n<worldbody>', 1
    )
    text = re.sub(
        r'(<body name="torso"[^>]*>)',
        r'\1<geom type="mesh" mesh="box" contype="0" conaffinity="0" density="0"/>',
        text,
        count=1,
    )
    text = text.replace("<compiler", '<compiler meshdir="meshes"', 1)
    (folder / "meshy.xml").write_text(text)
    robot = load_robot(folder / "meshy.xml")
    run = tmp_path / "run"
    store_robots(run, [robot])
    sha = robot_sha256(robot)
    mesh = hashlib.sha256(_BOX_OBJ.encode()).hexdigest()
    assert (run / "robots" / "assets" / f"{mesh}.obj").read_text() == _BOX_OBJ
    shutil.rmtree(folder)
    catalogues.pin_robots("meshy", [("meshy", run / "robots" / f"{sha}.xml", "hopper", "smpenv")])
    (again,) = catalogues.resolve_robots(["meshy"])
    assert again.name == "meshy" and again.compile().nmesh == 1
    assert robot_sha256(again) == sha


def _count_lookups(monkeypatch) -> tuple[list[list[str]], list[str]]:
    """Record every ``resolve_robots`` call (its specs) and every spec looked up in the
    catalogues (read into robots), wherever the call comes from."""
    calls: list[list[str]] = []
    lookups: list[str] = []
    real_resolve, real_lookup = catalogues.resolve_robots, catalogues._lookup

    def counted(specs, **kw):
        calls.append(list(specs))
        return real_resolve(specs, **kw)

    def looked_up(spec):
        lookups.append(spec)
        return real_lookup(spec)

    monkeypatch.setattr(catalogues, "resolve_robots", counted)
    monkeypatch.setattr(catalogues, "_lookup", looked_up)
    return calls, lookups


def test_a_train_start_resolves_each_robot_list_once(tmp_path, monkeypatch):
    """One ``gcnt train`` (checks, env, record, the final evaluation of training and test
    robots) resolves its training list and its test list once each, and looks up each robot
    spec of the run once (before the run's record: each spec three times)."""
    calls, lookups = _count_lookups(monkeypatch)
    recipe = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=["hopper_4", "walker_3_main"])
    assert gcnt_main(["train", str(recipe), f"run_dir={tmp_path / 'run'}"]) == 0
    assert sorted(calls) == [["hopper_3"], ["hopper_4", "walker_3_main"]]
    assert sorted(lookups) == ["hopper_3", "hopper_4", "walker_3_main"]


def test_the_seeds_of_one_train_command_look_up_each_robot_spec_once(tmp_path, monkeypatch):
    calls, lookups = _count_lookups(monkeypatch)
    recipe = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=["hopper_4"])
    argv = [
        "train",
        str(recipe),
        f"run_dir={tmp_path / 'runs'}",
        "td3.schedule=mixed",
        "--seeds",
        "0,1",
    ]
    assert gcnt_main(argv) == 0
    assert sorted(calls) == [["hopper_3"], ["hopper_3"], ["hopper_4"], ["hopper_4"]]
    assert sorted(lookups) == ["hopper_3", "hopper_4"]


def test_an_eval_looks_up_each_robot_spec_once(tmp_path, monkeypatch):
    recipe = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=["hopper_4", "walker_3_main"])
    run = tmp_path / "run"
    assert gcnt_main(["train", str(recipe), f"run_dir={run}"]) == 0
    _, lookups = _count_lookups(monkeypatch)
    assert gcnt_main(["eval", str(run), "--episodes", "1"]) == 0
    assert sorted(lookups) == ["hopper_3", "hopper_4", "walker_3_main"]
    lookups.clear()
    assert gcnt_main(["eval", str(run), "--episodes", "1", "--robots", "hopper_5"]) == 0
    assert sorted(lookups) == ["hopper_3", "hopper_4", "hopper_5", "walker_3_main"]


def test_the_record_a_run_writes_reads_back_equal(tmp_path):
    """The run's record (benchmark, world, robots with their hashes, method and network sizes,
    algorithm settings, plugins, device, seed) as ``recipe.yaml`` holds it reads back equal to
    the record the run was trained from."""
    from gcnt.recipes import load_recipe
    from gcnt.run.resolved import RunRecord, resolve_run

    recipe_file = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=["hopper_4"])
    run = tmp_path / "run"
    assert gcnt_main(["train", str(recipe_file), f"run_dir={run}"]) == 0
    section = yaml.safe_load((run / "recipe.yaml").read_text())["resolved"]
    read = RunRecord.from_resolved(section)
    made = resolve_run(load_recipe(recipe_file, [f"run_dir={run}"]))
    assert read == made
    assert read.benchmark == "smpenv" and read.method == "gcnt" and read.algo == "td3"
    assert read.network["d_model"] == 16 and read.settings["batch_size"] == 8
    assert read.robots["train"] == ["hopper_3"] and read.robots["test"] == ["hopper_4"]
    assert read.robots["index"]["hopper_3"]["sha256"] == robot_sha256(made.train_robots[0])
    assert RunRecord.from_resolved(RunDir(run).load_recipe().resolved) == made
    assert gcnt.load_run(run).record == made


def test_a_run_written_before_the_record_has_none_and_still_evaluates(tmp_path):
    from gcnt.run.resolved import RunRecord

    run = _old_run(tmp_path)
    section = yaml.safe_load((run / "recipe.yaml").read_text()).get("resolved") or {}
    assert RunRecord.from_resolved(section) is None
    assert gcnt_main(["eval", str(run), "--robots", "train", "--episodes", "1"]) == 0


def test_eval_of_a_test_list_that_names_no_robots_is_one_line(tmp_path, capsys):
    """``Hopper++:test`` is a split without robots: evaluating it is refused in one line (it
    was a traceback from the padding of an empty robot list)."""
    from cli_helpers import error_line

    recipe = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=["Hopper++:test"])
    run = tmp_path / "run"
    assert gcnt_main(["train", str(recipe), f"run_dir={run}"]) == 0
    line = error_line(capsys, ["eval", str(run)])
    assert f"{run}: no robots to evaluate (Hopper++:test name none)" in line


def test_a_malformed_override_imports_nothing_the_recipe_names(tmp_path):
    """A received sweep's manifest can record an override that does not parse (``seed.x=1``)
    before the ``plugins=[]`` gcnt sweep adds: the recipe's ``plugins:`` must not be imported
    on the way to refusing it."""
    from gcnt.recipes import RecipeError, load_recipe

    marker = tmp_path / "RAN"
    payload = _payload(tmp_path / "payload.py", marker)
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(f"base: {ROOT / 'recipes/quickstart.yaml'}\nplugins: [{payload}]\n")
    for bad in ("seed.x=1", "nokey", "td3.lr=[1"):
        with pytest.raises(RecipeError):
            load_recipe(recipe, [bad, "plugins=[]"])
        assert not marker.exists(), bad


@pytest.mark.parametrize("where", ["run_dir", "override", "log", "linked_parent"])
def test_a_received_sweep_naming_a_place_outside_itself_is_refused(tmp_path, capsys, where):
    """Its manifest's run directory, ``run_dir=`` override or log outside the sweep (also
    through a link inside it): one line naming the run and the place, exit 2, nothing written
    there."""
    clean = tmp_path / "clean.yaml"
    clean.write_text(f"base: {ROOT / 'recipes/quickstart.yaml'}\n")
    sweep = tmp_path / "sw"
    assert gcnt_main(["sweep", str(clean), "--dry-run", "--dir", str(sweep)]) == 0
    outside = tmp_path / "outside"
    outside.mkdir()
    manifest = json.loads((sweep / "manifest.json").read_text())
    run = manifest["runs"][0]
    if where == "run_dir":
        run["run_dir"] = str(outside / "run")
    elif where == "override":
        run["overrides"].append(f"run_dir={outside / 'run'}")
    elif where == "log":
        run["log"] = str(outside / "run.log")
    else:  # the run's parent folder, inside the sweep, is a link out of it
        parent = sweep / Path(run["run_dir"]).parent
        parent.parent.mkdir(parents=True, exist_ok=True)
        parent.symlink_to(outside, target_is_directory=True)
    (sweep / "manifest.json").write_text(json.dumps(manifest))
    capsys.readouterr()
    assert gcnt_main(["sweep", str(sweep), "--jobs", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "outside the sweep directory" in err and len(err.splitlines()) == 1
    assert list(outside.iterdir()) == []


@pytest.mark.parametrize("attack", ["swapped", "linked", "dotdot", "robots_link"])
def test_a_stored_robot_copy_that_is_not_the_recorded_one_is_refused(tmp_path, capsys, attack):
    """A received run's stored robot must be what it recorded: a copy swapped for another
    robot's file, a copy that is a link out, a recorded sha256 that climbs out of robots/, or a
    robots/ folder that is a link: one line naming it, exit 2, nothing evaluated."""
    run, mine = _run_on_robot_file(tmp_path)
    shutil.rmtree(mine)
    catalogues._PINNED.clear()
    data = yaml.safe_load((run / "recipe.yaml").read_text())
    sha = data["resolved"]["robots"]["index"]["myhopper"]["sha256"]
    stored = run / "robots" / f"{sha}.xml"
    other = (ROOT / "src/gcnt/data/morphologies/smpenv/hopper_5.xml").read_text()
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    if attack == "swapped":  # hopper_5's MJCF under hopper_3's hash
        stored.write_text(other)
    elif attack == "linked":
        (outside / "x.xml").write_text(stored.read_text())
        stored.unlink()
        stored.symlink_to(outside / "x.xml")
    elif attack == "dotdot":
        (outside / "x.xml").write_text(stored.read_text())
        data["resolved"]["robots"]["index"]["myhopper"]["sha256"] = str(outside / "x")
        (run / "recipe.yaml").write_text(yaml.safe_dump(data))
    else:
        shutil.move(run / "robots", outside / "robots")
        (run / "robots").symlink_to(outside / "robots", target_is_directory=True)
    capsys.readouterr()
    assert gcnt_main(["eval", str(run), "--robots", "train", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "myhopper" in err, err
    assert not list((run / "eval").glob("*train*"))


def test_an_alias_bomb_in_a_received_runs_recipe_is_one_line_at_once(tmp_path, capsys):
    """Every reader of a run's ``recipe.yaml`` (analysis, evaluation, the Python API) refuses a
    document whose aliases expand past the cap, before building it."""
    import time

    import gcnt

    run = _old_run(tmp_path)
    bomb = "a: &a [x, x, x, x, x, x, x, x, x, x]\n"
    for i in range(1, 9):
        bomb += f"{chr(97 + i)}: &{chr(97 + i)} [" + ", ".join([f"*{chr(96 + i)}"] * 10) + "]\n"
    (run / "recipe.yaml").write_text(bomb + (run / "recipe.yaml").read_text())
    for argv in (["curves", str(run), "--out", str(tmp_path / "o")],
                 ["eval", str(run), "--robots", "train", "--episodes", "1"]):  # fmt: skip
        t0 = time.monotonic()
        assert gcnt_main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert "aliases expand" in err and len(err.splitlines()) == 1, err
        assert time.monotonic() - t0 < 30
    with pytest.raises(Exception, match="aliases expand"):
        gcnt.load_run(run)


def test_the_analysis_commands_and_the_api_read_robots_from_the_record(tmp_path, monkeypatch):
    """``gcnt curves``, ``gcnt zeroshot`` and ``gcnt.load_run`` read a run's robots from its
    record (no robot looked up); ``gcnt.load_policy`` builds the policy's robots, each looked up
    once."""
    recipe = tiny_td3_recipe(tmp_path / "r.yaml", test_robots=["hopper_4", "walker_3_main"])
    run = tmp_path / "run"
    assert gcnt_main(["train", str(recipe), f"run_dir={run}"]) == 0
    calls, lookups = _count_lookups(monkeypatch)
    for argv in (["curves", str(run)], ["zeroshot", str(run)]):
        assert gcnt_main([*argv, "--out", str(tmp_path / argv[0])]) == 0
        assert calls == lookups == [], argv
    gcnt.load_run(run)
    assert calls == lookups == []
    gcnt.load_policy(run)
    assert sorted(lookups) == ["hopper_3", "hopper_4", "walker_3_main"]
