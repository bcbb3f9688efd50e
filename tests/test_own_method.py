"""A method of one's own, as docs/extending.md walks through it: its file (taken from the page)
runs on the shipped quick start unchanged, ``gcnt params`` counts it, ``gcnt embed`` names it
in one line; a config that takes some of the recipe's shared sizes is refused with the override
to add. Each command in a fresh process, so that the plugin registers nothing here."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import ROOT, TINY_SWEEP_OVERRIDES, error_line

from gcnt.recipes import RecipeError, load_recipe

HALF = """\
from dataclasses import dataclass

import meanmsg
from gcnt.nn import NetConfig, register_network


@dataclass
class HalfConfig(NetConfig):
    layers: int = 2
    hidden: int = 8


register_network("half", HalfConfig, meanmsg.build)
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """``meanmsg.py`` from docs/extending.md, and ``half.py`` beside it."""
    page = (ROOT / "docs" / "extending.md").read_text()
    (code,) = [b for b in re.findall(r"```python\n(.*?)```", page, re.S) if "meanmsg" in b]
    here = tmp_path_factory.mktemp("mine")
    (here / "meanmsg.py").write_text(code)
    (here / "half.py").write_text(HALF)
    return here


def _gcnt(folder: Path, *argv: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(folder), *sys.path])}
    return subprocess.run(
        [sys.executable, "-m", "gcnt.cli", *argv],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=folder,
        env=env,
    )


def test_params_counts_a_method_of_ones_own_or_names_the_override(folder: Path) -> None:
    done = _gcnt(folder, "params", "--recipe", "quickstart", "--methods", "gcnt,meanmsg",
                 "--plugin", "meanmsg.py")  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    (row,) = [line.split() for line in done.stdout.splitlines() if line.split()[:1] == ["meanmsg"]]
    assert row[1:3] == ["the", "preset's"] and int(row[-1].replace(",", "")) > 0
    done = _gcnt(folder, "params", "--recipe", "quickstart", "--methods", "half",
                 "--plugin", "half.py")  # fmt: skip
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "network.kwargs sets d_model, ff, not fields of HalfConfig" in done.stderr
    assert "network.method_kwargs.half={}" in done.stderr


def test_params_methods_without_a_recipe_is_refused(capsys) -> None:
    line = error_line(capsys, ["params", "--methods", "gcnt,swat"])
    assert "--methods counts methods at a recipe's sizes: give the recipe too" in line


def test_shared_sizes_go_to_the_family_that_has_them() -> None:
    recipe = load_recipe("quickstart")
    assert recipe.network.sizes() == {"d_model": 32, "layers": 1, "ff": 64}
    recipe.network.name = "amorpheus"  # a Transformer: the same fields
    assert recipe.network.sizes() == {"d_model": 32, "layers": 1, "ff": 64}
    recipe.network.name = "modumorph"
    assert recipe.network.sizes() == {"d_model": 32, "layers": 1, "ff": 64}
    recipe.network.name = "smp"  # its own entry
    assert recipe.network.sizes()["msg_dim"] == 16
    recipe.network.kwargs = {"d_modle": 32}  # a field of no method: a typo, named
    recipe.network.name = "gcnt"
    with pytest.raises(ValueError, match="unknown GCNTConfig field 'd_modle'.*'d_model'"):
        recipe.network.sizes()
    with pytest.raises(RecipeError):
        from gcnt.rl.loop import check_network

        check_network(recipe)


@pytest.mark.slow
def test_the_quick_start_trains_a_method_of_ones_own_unchanged_and_embed_names_it(
    folder: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    tiny = [o for o in TINY_SWEEP_OVERRIDES if not o.startswith("network.")]
    done = _gcnt(folder, "train", "quickstart", "network.name=meanmsg", f"run_dir={run}",
                 "logger.backend=none", *tiny, "--plugin", "meanmsg.py")  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert (run / "eval").is_dir() and (run / "checkpoints" / "last.pt").is_file()
    done = _gcnt(
        folder, "embed", str(run), "--out", str(tmp_path / "fig"), "--plugin", "meanmsg.py"
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "not embedded: meanmsg (its chain writes no limbs/hidden and limbs/embed)" in done.stdout
    assert "no run with structural vectors" in done.stderr
