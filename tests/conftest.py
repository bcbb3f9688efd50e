"""Import gcnt before any test module imports torch, so the tests run with the OpenMP settings
``gcnt`` chooses (torch reads them once, when it loads). Also the command-line tests' tiny run:
``recipe_file`` (a module may override it) and ``trained``, built once per module. The tests
read and write robot sets in a folder of their own, never the user's (``GCNT_MORPHOLOGIES``).

Tests marked ``gpu`` run on CUDA where there is one, else on the emulated GPU of
``tests/cuda_emulation`` (its rules are checked first, by tests/test_cuda_emulation.py). Those
also marked ``gpu_matrix`` (the whole GPU matrix) run only with ``--gpu-matrix``
(``make test-gpu-emulated``)."""

import gcnt  # noqa: F401  (first: before torch loads)

# isort: split
import os
from pathlib import Path

import pytest
import torch
from cli_helpers import tiny_td3_recipe

from gcnt import plugins
from gcnt.cli import main as gcnt_cli

try:  # the Slurm extra
    # imported here, before any test: its import configures logging, which closes every handler
    # there is; absl's (made when dm_control loads) then closes the stream it was made with, the
    # session's capture file, when a test under capsys is the first to import it (gcnt sweep
    # --slurm), and pytest fails at its end ("I/O operation on closed file")
    import submitit  # noqa: F401
except ImportError:
    pass

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


@pytest.fixture(autouse=True)
def own_plugin_session():
    """Each test's plugins are its own: a recipe a test loads in-process (``load_recipe``) adds
    its plugins to the session, as a command's would, and a later test's runs would record them."""
    yield
    plugins.end_session()


@pytest.fixture(scope="module")
def recipe_file(tmp_path_factory) -> Path:
    return tiny_td3_recipe(tmp_path_factory.mktemp("recipe") / "tiny.yaml")


@pytest.fixture(scope="module")
def trained(tmp_path_factory, recipe_file) -> Path:
    """A finished tiny run (never modified by the tests: copy it first)."""
    run = tmp_path_factory.mktemp("trained") / "run"
    assert gcnt_cli(["train", str(recipe_file), f"run_dir={run}"]) == 0
    return run


def pytest_addoption(parser):
    parser.addoption(
        "--gpu-matrix",
        action="store_true",
        help="also run the tests marked gpu_matrix (the whole GPU matrix; emulated without CUDA)",
    )


def pytest_collection_modifyitems(config, items):
    """The emulation's self-test first; the gpu_matrix tests only with --gpu-matrix."""
    first = [i for i in items if i.nodeid.startswith("tests/test_cuda_emulation.py")]
    items[:] = first + [i for i in items if i not in first]
    if config.getoption("--gpu-matrix"):
        return
    skipped = [i for i in items if i.get_closest_marker("gpu_matrix")]
    if skipped:
        config.hook.pytest_deselected(items=skipped)
        items[:] = [i for i in items if not i.get_closest_marker("gpu_matrix")]


_NATIVE_CUDA = torch.cuda.is_available()


@pytest.fixture(autouse=True)
def _gpu(request):
    """A test marked ``gpu`` runs on the real GPU where there is one, else on the emulated one;
    on the emulated one only after its self-test passed in this session."""
    if request.node.get_closest_marker("gpu") is None or _NATIVE_CUDA:
        yield
        return
    from cuda_emulation import emulate
    from test_cuda_emulation import require_self_test

    require_self_test(request)
    with emulate():
        yield
