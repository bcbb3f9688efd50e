"""Import gcnt before any test module imports torch, so the tests run with the OpenMP settings
``gcnt`` chooses (torch reads them once, when it loads). Also the command-line tests' tiny run:
``recipe_file`` (a module may override it) and ``trained``, built once per module. The tests
read and write robot sets in a folder of their own, never the user's (``GCNT_MORPHOLOGIES``)."""

import os
from pathlib import Path

import pytest
from cli_helpers import tiny_td3_recipe

import gcnt  # noqa: F401
from gcnt.cli import main as gcnt_cli

#: the variable naming the user's robot-set folder (gcnt.data_folders)
MORPHOLOGIES_ENV = "GCNT_MORPHOLOGIES"


@pytest.fixture(scope="session", autouse=True)
def own_robot_sets(tmp_path_factory):
    """The user's robot-set folder, for the whole session (and the processes it starts)."""
    old = os.environ.get(MORPHOLOGIES_ENV)
    os.environ[MORPHOLOGIES_ENV] = str(tmp_path_factory.mktemp("user-robot-sets"))
    yield
    if old is None:
        os.environ.pop(MORPHOLOGIES_ENV, None)
    else:
        os.environ[MORPHOLOGIES_ENV] = old


@pytest.fixture(scope="module")
def recipe_file(tmp_path_factory) -> Path:
    return tiny_td3_recipe(tmp_path_factory.mktemp("recipe") / "tiny.yaml")


@pytest.fixture(scope="module")
def trained(tmp_path_factory, recipe_file) -> Path:
    """A finished tiny run (never modified by the tests: copy it first)."""
    run = tmp_path_factory.mktemp("trained") / "run"
    assert gcnt_cli(["train", str(recipe_file), f"run_dir={run}"]) == 0
    return run
