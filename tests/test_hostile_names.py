"""Names that collide: benchmark and catalogue names are one whatever their case (a user's set
defining ``hopper++`` beside the shipped ``Hopper++`` is left out with a warning), a user folder
named after a built-in catalogue is a warning naming it, and a folder in the current folder
named as a shipped recipe makes ``gcnt train NAME`` say how to pick either."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import error_line

from gcnt.data_folders import MORPHOLOGIES_ENV
from gcnt.morphology.catalogues import catalogue_names, load_benchmarks, refresh_catalogues


@pytest.fixture
def morph(tmp_path, monkeypatch) -> Path:
    folder = tmp_path / "morphologies"  # a robot-set folder read beside gcnt's own robots
    folder.mkdir()
    monkeypatch.setenv(MORPHOLOGIES_ENV, str(folder))
    refresh_catalogues()
    yield folder
    refresh_catalogues()


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]


@pytest.mark.parametrize("name, bench", [("Mine", "hopper++"), ("SMPENV", "Mine")])
def test_a_set_whose_names_differ_from_shipped_ones_only_in_case_is_left_out(
    morph, caplog, name, bench
):
    (morph / name).mkdir()
    (morph / name / "catalogue.yaml").write_text(f"{bench}:\n  train: []\n")
    with caplog.at_level("WARNING"):
        names = catalogue_names()
        benchmarks = load_benchmarks()
    assert name not in names and bench not in benchmarks
    clash = bench if bench == "hopper++" else name
    warned = [w for w in _warnings(caplog) if str(morph / name) in w and "left out" in w]
    assert len(warned) == 1 and repr(clash) in warned[0], _warnings(caplog)
    assert "whatever their case" in warned[0]


def test_a_user_folder_named_after_a_built_in_catalogue_is_a_warning(morph, caplog):
    (morph / "smpenv" / "xml").mkdir(parents=True)
    with caplog.at_level("WARNING"):
        assert catalogue_names().count("smpenv") == 1
    warned = [w for w in _warnings(caplog) if str(morph / "smpenv") in w]
    assert len(warned) == 1 and "'smpenv' is gcnt's built-in catalogue" in warned[0], warned


def test_a_folder_named_as_a_shipped_recipe_says_how_to_pick_either(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "quickstart").mkdir()
    line = error_line(capsys, ["train", "quickstart"])
    assert "quickstart: a folder here, and a recipe that ships with gcnt" in line, line
    assert "recipes/quickstart.yaml" in line and "quickstart/<file>.yaml" in line, line
