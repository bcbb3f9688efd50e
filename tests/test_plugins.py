"""Plugins: a method, a benchmark and an algorithm defined in a temporary folder, named once
(``--plugin``, the recipe key ``plugins``, GCNT_PLUGINS, an installed package's entry point),
reach every command and every process gcnt starts: training, evaluation, resume and fine-tuning
in fresh processes that were not told about the plugin, a sweep's runs, PPO's collector workers,
and the analysis commands. A plugin that cannot be imported is one error line naming it."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from cli_helpers import TINY_SWEEP_OVERRIDES, error_line
from plugin_helpers import write_plugin

from gcnt.cli import main as gcnt
from gcnt.recipes import load_recipe
from gcnt.run.directory import RunDir

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


def _gcnt_fails(*argv: str, cwd: Path | None = None) -> str:
    """``python -m gcnt.cli ARGV`` in a fresh process: it must exit 2 in one error line (the
    line)."""
    done = subprocess.run(
        [sys.executable, "-m", "gcnt.cli", *argv],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=cwd,
    )
    assert done.returncode == 2, done.stderr[-3000:]
    lines = [line for line in done.stderr.splitlines() if line.startswith("gcnt ")]
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr[-3000:]
    return lines[0]


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow
def test_a_plugin_run_records_its_plugin_and_needs_it_named_wherever_the_file_moved(tmp_path):
    plugin = write_plugin(tmp_path / "first")
    sha = _sha256(plugin)
    recipe, run = plugin.parent / "recipe.yaml", tmp_path / "run"
    _gcnt("--plugin", str(plugin), "train", str(recipe), f"run_dir={run}")
    # the run records the plugin's identity (name, hash of its source), never its path
    recorded = yaml.safe_load((run / "recipe.yaml").read_text())
    assert recorded["resolved"]["plugins"] == [{"name": "my_methods.py", "sha256": sha}]
    assert recorded["plugins"] == ["my_methods.py"]
    (session,) = json.loads((run / "provenance.json").read_text())["sessions"]
    assert session["plugins"] == [{"name": "my_methods.py", "sha256": sha, "via": "--plugin"}]
    assert str(plugin.parent) not in (run / "recipe.yaml").read_text()  # (the command: as typed)
    # a fresh process that does not name it: one line naming it, its hash and --plugin
    line = _gcnt_fails("eval", str(run), "--robots", "hopper_4", "--episodes", "1", cwd=tmp_path)
    assert "my_methods.py" in line and sha[:16] in line and "--plugin" in line
    # the file moves: the run plots without it, and evaluates, resumes and fine-tunes with
    # --plugin NEWPATH
    moved = tmp_path / "moved"
    shutil.move(plugin.parent, moved)
    new = moved / "my_methods.py"
    out = _gcnt("curves", str(run), "--out", str(tmp_path / "fig"), cwd=tmp_path)
    assert "plugnet" in out
    out = _gcnt(
        "--plugin", str(new), "eval", str(run), "--robots", "hopper_4", "--episodes", "1",
        cwd=tmp_path,
    )  # fmt: skip
    assert "hopper_4" in out
    _gcnt("--plugin", str(new), "train", "--resume", str(run), "collector.total_frames=60")
    assert RunDir(run).load_checkpoint()["env_steps"] == 60
    ft = tmp_path / "ft"
    _gcnt(
        "--plugin", str(new), "train", str(moved / "recipe.yaml"), "--init-from", str(run),
        f"run_dir={ft}", "env.robots=[hopper_4]", "env.test_robots=[hopper_5]", cwd=tmp_path,
    )  # fmt: skip
    ft_recipe = yaml.safe_load((ft / "recipe.yaml").read_text())
    assert ft_recipe["resolved"]["init_from"]["run"] == str(run)
    assert ft_recipe["resolved"]["plugins"] == [{"name": "my_methods.py", "sha256": sha}]
    # a changed plugin of the same name: a warning naming both hashes
    new.write_text(new.read_text() + "\n# changed\n")
    done = subprocess.run(
        [sys.executable, "-m", "gcnt.cli", "--plugin", str(new), "eval", str(run), "--robots",
         "hopper_4", "--episodes", "1"],
        capture_output=True, text=True, timeout=600, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert sha[:16] in done.stderr and _sha256(new)[:16] in done.stderr


@pytest.mark.slow
def test_a_sweep_with_a_plugin_method_leaves_its_other_runs_free_of_it(tmp_path, capsys):
    plugin = write_plugin(tmp_path / "first")
    sw = tmp_path / "sw"
    argv = ["--plugin", str(plugin), "sweep", str(QUICKSTART), "--methods", "plugnet,gcnt"]
    argv += ["--seeds", "0", "--jobs", "1", "--dir", str(sw), "--eval", "test", "--episodes", "1"]
    try:  # the runs: `python -m gcnt.cli` children
        assert gcnt([*argv, *TINY_SWEEP_OVERRIDES]) == 0
    finally:
        _forget("my_methods", plugin.parent)
    manifest = json.loads((sw / "manifest.json").read_text())
    assert {r["state"] for r in manifest["runs"]} == {"done"}
    assert not any("plugins=" in o for r in manifest["runs"] for o in r["overrides"])
    runs = {r["method"]: sw / r["run_dir"] for r in manifest["runs"]}
    shutil.move(plugin.parent, tmp_path / "moved")
    # reading results needs no code: curves and zeroshot in a fresh process, no plugin named
    assert "plugnet" in _gcnt("curves", str(sw), "--out", str(tmp_path / "fig"), cwd=tmp_path)
    out = _gcnt("zeroshot", str(sw), "--out", str(tmp_path / "fig"), cwd=tmp_path)
    assert "plugnet" in out and "hopper_4" in out
    _gcnt("sweep", str(sw), "--status", cwd=tmp_path)
    # the GCNT run does not need the plugin; the plugin's run names it
    out = _gcnt("eval", str(runs["gcnt"]), "--episodes", "1", cwd=tmp_path)
    assert "hopper_4" in out
    assert "my_methods.py" in _gcnt_fails("eval", str(runs["plugnet"]), cwd=tmp_path)


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


def test_from_python_a_missing_plugin_is_named_with_the_call_that_loads_it(tmp_path):
    """``gcnt.load_policy`` on a run of a plugin's method: the error says how to name the plugin
    from Python as well as on the command line."""
    import gcnt
    from gcnt.plugins import PluginError
    from gcnt.recipes import read_recipe_file

    data = read_recipe_file(QUICKSTART)
    data.pop("base", None)
    data["network"] = {**data.get("network", {}), "name": "plugnet_elsewhere"}
    data["resolved"] = {"plugins": [{"name": "my_methods.py", "sha256": "ab" * 32}]}
    run = tmp_path / "run"
    run.mkdir()
    (run / "recipe.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(PluginError) as e:
        gcnt.load_policy(run)
    said = str(e.value)
    assert "my_methods.py" in said and "--plugin" in said and "GCNT_PLUGINS" in said
    assert "gcnt.plugins.load([PATH_OR_MODULE])" in said


def test_a_written_recipe_names_plugin_files_without_their_folder(tmp_path):
    """recipe.yaml and the W&B config (``Recipe.to_dict``) hold no folder of this machine; the
    recipe in memory (what worker processes import) keeps the path."""
    recipe = load_recipe(QUICKSTART)
    recipe.plugins = [str(tmp_path / "mine" / "my_methods.py"), "my_pkg.methods"]
    assert recipe.to_dict()["plugins"] == ["my_methods.py", "my_pkg.methods"]
    assert recipe.plugins[0] == str(tmp_path / "mine" / "my_methods.py")


def test_a_recipe_names_plugins_relative_to_itself(plugin, tmp_path, monkeypatch):
    other = tmp_path / "elsewhere"
    other.mkdir()
    (other / "r.yaml").write_text(f"base: {plugin.parent / 'recipe.yaml'}\nplugins: [../x.py]\n")
    (tmp_path / "x.py").write_text("")
    monkeypatch.syspath_prepend(str(plugin.parent))  # a module plugin: from the Python path
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
        # the variable's plugin is the command's own: its runs are given it by --plugin (the
        # manifest records none); an installed package's entry point is imported by every
        # gcnt process anyway
        assert not any("plugins=" in o for r in manifest["runs"] for o in r["overrides"])
        from gcnt import plugins
        from gcnt.sweep import RunSpec, commands

        plugins.start_session()  # a command that continues the sweep, GCNT_PLUGINS still set
        (_, train), *_ = commands(RunSpec(**manifest["runs"][0]))
        plugins.end_session()
        assert train[3:5] == ["--plugin", "env_plug"] and train[-1] == "plugins=[]"

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
    # a recipe naming one
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"base: {QUICKSTART}\nplugins: [no_such_plugin_mod]\n")
    line = error_line(capsys, ["train", str(bad)])
    assert f"{bad}: plugin no_such_plugin_mod (named by the recipe key plugins)" in line


@pytest.mark.parametrize(
    "body, said",
    [
        ("import sys\nsys.exit(0)\n", "sys.exit(0)"),
        ("import sys\nsys.exit(3)\n", "sys.exit(3)"),
        ("raise KeyboardInterrupt\n", "KeyboardInterrupt"),
        ("raise OSError('disk on fire')\n", "OSError: disk on fire"),
        (
            "from gcnt.nn import register_network\nfrom gcnt.nn.config import GCNTConfig\n"
            "from gcnt.nn.gcnt import gcnt_backbone\n"
            "register_network('gcnt', GCNTConfig, gcnt_backbone, replace=True)\n",
            "built-in method and cannot be replaced",
        ),
    ],
)
def test_a_plugin_that_exits_raises_or_replaces_a_built_in_is_one_line_exit_2(
    tmp_path, capsys, body, said
):
    from gcnt.nn.registry import NETWORKS

    builtin = NETWORKS["gcnt"]
    path = tmp_path / "leaving_plugin.py"
    path.write_text(body)
    try:
        line = error_line(capsys, ["--plugin", str(path), "robots"])
    finally:
        sys.modules.pop("leaving_plugin", None)
    assert f"plugin {path} (named by --plugin)" in line and said in line
    assert NETWORKS["gcnt"] is builtin
    from gcnt import plugins

    assert all("leaving_plugin" not in k for k in plugins._loaded)


def test_naming_a_plugin_leaves_the_python_path_as_it_is(tmp_path, monkeypatch):
    """A plugin file is imported from its path: neither its folder nor the current folder joins
    sys.path, so their stray modules (a ``pandas.py``) are never imported in place of the real
    ones, here or in a fresh process."""
    from gcnt import plugins

    folder, cwd = tmp_path / "plug", tmp_path / "cwd"
    for where in (folder, cwd):
        where.mkdir()
        (where / "pandas.py").write_text(f"open({str(where / 'RAN')!r}, 'w').close()\n")
    (folder / "quiet_plugin.py").write_text("VALUE = 1\n")
    monkeypatch.chdir(cwd)
    before = list(sys.path)
    try:
        plugins.load([str(folder / "quiet_plugin.py")], via="--plugin")
        assert sys.modules["quiet_plugin"].VALUE == 1
    finally:
        sys.modules.pop("quiet_plugin", None)
        plugins._loaded.pop(str(folder / "quiet_plugin.py"), None)
    assert sys.path == before
    probe = (
        "import importlib.util, sys\n"
        "from gcnt.cli import main\n"
        f"rc = main(['--plugin', {str(folder / 'quiet_plugin.py')!r}, 'robots'])\n"
        "spec = importlib.util.find_spec('pandas')\n"
        "print(rc, spec.origin if spec else None)\n"
        "import pandas\n"
    )
    done = subprocess.run(
        [sys.executable, "-P", "-c", probe], capture_output=True, text=True, timeout=600, cwd=cwd
    )
    rc, origin = done.stdout.split()[-2:]
    assert rc == "0" and str(tmp_path) not in origin
    assert not (folder / "RAN").exists() and not (cwd / "RAN").exists()
