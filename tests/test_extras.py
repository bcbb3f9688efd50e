"""The optional extras: a command that needs a package of one that is missing says which extra
installs it, in one line, exit 2, and writes nothing."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from cli_helpers import TINY_SWEEP_OVERRIDES, error_line

from gcnt.extras import MissingExtraError, require

ROOT = __import__("pathlib").Path(__file__).parents[1]


def test_require_names_the_extra_of_a_missing_package(monkeypatch):
    monkeypatch.setitem(sys.modules, "submitit", None)  # import submitit -> ImportError
    with pytest.raises(MissingExtraError, match=r"pip install 'gcnt\[slurm\]'"):
        require("submitit", "a Slurm sweep")
    assert require("json", "anything").dumps([1]) == "[1]"


def test_a_slurm_sweep_without_submitit_is_one_line(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "submitit", None)
    argv = ["sweep", str(ROOT / "recipes/quickstart.yaml"), "--slurm", "--no-wait"]
    argv += ["--dir", str(tmp_path / "sw"), *TINY_SWEEP_OVERRIDES]
    line = error_line(capsys, argv)
    assert "submitit" in line and "gcnt[slurm]" in line
    assert not (tmp_path / "sw").exists()  # refused before the sweep directory is written


def test_a_tsne_without_scikit_learn_names_the_analysis_extra(monkeypatch):
    from gcnt.analysis.embed import tsne

    monkeypatch.setitem(sys.modules, "sklearn.manifold", None)
    with pytest.raises(MissingExtraError, match=r"scikit-learn.*gcnt\[analysis\]"):
        tsne(np.zeros((5, 3)))
