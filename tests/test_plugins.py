"""Plugins: a method, a benchmark and an algorithm defined in a temporary folder, named once
(``--plugin``, the recipe key ``plugins``, GCNT_PLUGINS, an installed package's entry point),
reach every command and every process gcnt starts: training, evaluation, resume and fine-tuning
in fresh processes that were not told about the plugin, a sweep's runs, PPO's collector workers,
and the analysis commands. A plugin that cannot be imported is one error line naming it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from cli_helpers import error_line
from plugin_helpers import write_plugin

from gcnt.cli import main as gcnt
from gcnt.recipes import load_recipe
from gcnt.rl.run_dir import RunDir

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "recipes" / "quickstart.yaml"


def _forget(module: str, folder: Path) -> None:
    """Undo what importing a plugin module registered (later tests see gcnt's own registries)."""
    from gcnt import plugins
    from gcnt.analysis.names import METHOD_NAMES
    from gcnt.envs import benchmark
    from gcnt.nn.registry import NETWORKS
    from gcnt.recipes import ALGORITHM_SECTIONS
    from gcnt.rl import algorithm

    for name in ("plugnet", "envnet", "epnet"):
        NETWORKS.pop(name, None)
        METHOD_NAMES.pop(name, None)
    benchmark._REGISTRY.pop("plugbench", None)
    algorithm._ALGORITHMS.pop("plugalgo", None)
    ALGORITHM_SECTIONS.pop("plugalgo", None)
    sys.modules.pop(module, None)
    for key in [k for k in plugins._loaded if module in k]:
        del plugins._loaded[key]
    if str(folder) in sys.path:
        sys.path.remove(str(folder))


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    """The plugin file (``my_methods.py``) and its recipe (``recipe.yaml``) in a new folder."""
    folder = tmp_path_factory.mktemp("mine")
    path = write_plugin(folder)
    yield path
    _forget("my_methods", folder)


def _gcnt(*argv: str, env: dict | None = None, cwd: Path | None = None) -> str:
    """``python -m gcnt.cli ARGV`` in a fresh process that knows nothing of the plugin; its
    output (it must succeed)."""
    done = subprocess.run(
        [sys.executable, "-m", "gcnt.cli", *argv],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, **(env or {})},
        cwd=cwd,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


@pytest.mark.slow
def test_a_plugin_named_once_reaches_eval_resume_and_fine_tune_in_fresh_processes(plugin, tmp_path):
    recipe, run = plugin.parent / "recipe.yaml", tmp_path / "run"
    _gcnt("--plugin", str(plugin), "train", str(recipe), f"run_dir={run}")
    # the run records the plugin (recipe key) and the file it came from (provenance)
    recorded = yaml.safe_load((run / "recipe.yaml").read_text())
    assert recorded["plugins"] == [str(plugin)]
    (session,) = json.loads((run / "provenance.json").read_text())["sessions"]
    assert [p["file"] for p in session["plugins"]] == [str(plugin)]
    # a fresh process, told nothing, evaluates, resumes and fine-tunes the plugin's run
    out = _gcnt("eval", str(run), "--robots", "hopper_4", "--episodes", "1", cwd=tmp_path)
    assert "hopper_4" in out
    _gcnt("train", "--resume", str(run), "collector.total_frames=60", cwd=tmp_path)
    assert RunDir(run).load_checkpoint()["env_steps"] == 60
    ft = tmp_path / "ft"
    _gcnt(
        "train", str(recipe), "--init-from", str(run), f"run_dir={ft}",
        "env.robots=[hopper_4]", "env.test_robots=[hopper_5]", cwd=tmp_path,
    )  # fmt: skip
    assert yaml.safe_load((ft / "recipe.yaml").read_text())["plugins"] == [str(plugin)]
    assert RunDir(ft).load_recipe().resolved["init_from"]["run"] == str(run)


@pytest.mark.slow
def test_a_sweep_runs_the_plugin_then_curves_and_zeroshot_import_it(plugin, tmp_path, capsys):
    sw = tmp_path / "sw"
    argv = ["--plugin", str(plugin), "sweep", str(plugin.parent / "recipe.yaml")]
    argv += ["--seeds", "0", "--jobs", "1", "--dir", str(sw), "--eval", "test"]
    assert gcnt([*argv, "--episodes", "1"]) == 0  # the runs: `python -m gcnt.cli` children
    manifest = json.loads((sw / "manifest.json").read_text())
    assert {r["state"] for r in manifest["runs"]} == {"done"}
    assert all(r["eval_state"] == {"test": "done"} for r in manifest["runs"])
    assert all(f"plugins={json.dumps([str(plugin)])}" in r["overrides"] for r in manifest["runs"])
    assert gcnt(["curves", str(sw), "--out", str(tmp_path / "fig")]) == 0
    assert "plugnet" in capsys.readouterr().out
    # a fresh process shows the plugin's display name: it imported what the runs recorded
    out = _gcnt("zeroshot", str(sw), "--out", str(tmp_path / "fig"), cwd=tmp_path)
    assert "PlugNet" in out and "hopper_4" in out


@pytest.mark.slow
def test_ppo_collector_workers_import_the_plugin(plugin, tmp_path):
    """torchrl's worker processes start fresh (spawn): the recipe they receive imports the
    plugin that defines their benchmark and network."""
    from test_ppo import tiny_recipe

    data = tiny_recipe(tmp_path / "run", collector="multi", workers=2).to_dict()
    data["env"]["benchmark"] = "plugbench"
    data["network"]["name"] = "plugnet"
    data["plugins"] = [str(plugin)]
    data["collector"]["total_frames"] = 160
    path = tmp_path / "ppo.yaml"
    path.write_text(yaml.safe_dump(data))
    assert gcnt(["train", str(path)]) == 0
    assert RunDir(tmp_path / "run").load_checkpoint()["env_steps"] >= 160


def test_a_recipe_names_plugins_relative_to_itself(plugin, tmp_path, monkeypatch):
    other = tmp_path / "elsewhere"
    other.mkdir()
    (other / "r.yaml").write_text(f"base: {plugin.parent / 'recipe.yaml'}\nplugins: [../x.py]\n")
    (tmp_path / "x.py").write_text("")
    monkeypatch.chdir(plugin.parent)  # neither folder
    assert load_recipe(other / "r.yaml", ["plugins=[my_methods]"]).plugins == ["my_methods"]
    monkeypatch.chdir(tmp_path.parent)
    assert load_recipe(other / "r.yaml").plugins == [str(tmp_path / "x.py")]


def test_the_variable_and_entry_points_name_plugins(tmp_path, monkeypatch, capsys):
    """GCNT_PLUGINS (module names, commas or colons) and an installed package's ``gcnt.plugins``
    entry point (a module, or a function called once)."""
    register = "from gcnt.nn import register_network\nfrom gcnt.nn.config import GCNTConfig\n"
    register += "from gcnt.nn.gcnt import gcnt_backbone\n"
    (tmp_path / "env_plug.py").write_text(
        f'{register}register_network("envnet", GCNTConfig, gcnt_backbone)\n'
    )
    (tmp_path / "ep_plug.py").write_text(
        f'{register}def setup():\n    register_network("epnet", GCNTConfig, gcnt_backbone)\n'
    )
    dist = tmp_path / "my_methods_pkg-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: my-methods-pkg\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[gcnt.plugins]\nmine = ep_plug:setup\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("GCNT_PLUGINS", "env_plug:")
    sweep = ["sweep", str(QUICKSTART), "--methods", "envnet,epnet", "--dry-run"]
    try:
        assert gcnt([*sweep, "--dir", str(tmp_path / "sw")]) == 0
        manifest = json.loads((tmp_path / "sw" / "manifest.json").read_text())
        # the variable's plugin is the command's own: its runs record it; an installed
        # package's entry point is imported by every gcnt process anyway
        assert all('plugins=["env_plug"]' in r["overrides"] for r in manifest["runs"])
        from gcnt import plugins

        vias = {p["via"]: p["file"] for p in plugins.loaded()}
        assert vias["entry point mine"] == str(tmp_path / "ep_plug.py")
        assert vias["GCNT_PLUGINS"] == str(tmp_path / "env_plug.py")
    finally:
        for module in ("env_plug", "ep_plug"):
            _forget(module, tmp_path)
    monkeypatch.delenv("GCNT_PLUGINS")
    (dist / "entry_points.txt").unlink()
    capsys.readouterr()
    line = error_line(capsys, [*sweep, "--dir", str(tmp_path / "sw2")])
    assert "unknown network 'envnet'" in line


def test_a_plugin_that_cannot_be_imported_is_one_line_naming_it(tmp_path, monkeypatch, capsys):
    recipe = str(QUICKSTART)
    line = error_line(capsys, ["--plugin", "no_such_plugin_mod", "train", recipe])
    assert "plugin no_such_plugin_mod (named by --plugin) cannot be imported" in line
    assert "ModuleNotFoundError" in line
    broken = tmp_path / "broken_plugin.py"
    broken.write_text("raise RuntimeError('my own bug')\n")
    line = error_line(capsys, ["train", recipe, "--plugin", str(broken)])
    assert f"plugin {broken} (named by --plugin)" in line and "RuntimeError: my own bug" in line
    line = error_line(capsys, ["train", recipe, "--plugin", str(tmp_path / "absent.py")])
    assert "absent.py (named by --plugin): no such file" in line
    monkeypatch.setenv("GCNT_PLUGINS", "no_such_plugin_mod")
    assert "(named by GCNT_PLUGINS)" in error_line(capsys, ["eval", str(tmp_path)])
    monkeypatch.delenv("GCNT_PLUGINS")
    assert gcnt(["train", recipe, "--plugin"]) == 2
    # a recipe naming one, and a run that recorded one that is gone
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"base: {QUICKSTART}\nplugins: [no_such_plugin_mod]\n")
    line = error_line(capsys, ["train", str(bad)])
    assert f"{bad}: plugin no_such_plugin_mod (named by the recipe key plugins)" in line
    run = tmp_path / "runs" / "old"
    run.mkdir(parents=True)
    (run / "recipe.yaml").write_text("task: t\nplugins: [no_such_plugin_mod]\n")
    line = error_line(capsys, ["curves", str(tmp_path / "runs")])
    assert f"plugin no_such_plugin_mod (named by the run {run})" in line
