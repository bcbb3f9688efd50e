"""Import gcnt before any test module imports torch, so the tests run with the OpenMP settings
``gcnt`` chooses (torch reads them once, when it loads). Also the command-line tests' tiny run:
``recipe_file`` (a module may override it) and ``trained``, built once per module."""

from pathlib import Path

import pytest
from cli_helpers import tiny_td3_recipe

import gcnt  # noqa: F401
from gcnt.cli import main as gcnt_cli


@pytest.fixture(scope="module")
def recipe_file(tmp_path_factory) -> Path:
    return tiny_td3_recipe(tmp_path_factory.mktemp("recipe") / "tiny.yaml")


@pytest.fixture(scope="module")
def trained(tmp_path_factory, recipe_file) -> Path:
    """A finished tiny run (never modified by the tests: copy it first)."""
    run = tmp_path_factory.mktemp("trained") / "run"
    assert gcnt_cli(["train", str(recipe_file), f"run_dir={run}"]) == 0
    return run
