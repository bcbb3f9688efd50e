"""Every study's published tests recompute from the per-seed files published beside it
(``docs/results/<study>/verdict.py`` reads only its folder), to the p values the results page
states."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from gcnt.analysis.verdict import detectable, power_for, welch

RESULTS = Path(__file__).parents[1] / "docs/results"
SCRIPTS = sorted(RESULTS.glob("*/verdict.py"))
#: the p values each study's page states, in the order its script prints them (None: a test
#: the script prints that the page does not state)
PUBLISHED = {
    "study4": [0.149, 0.14, 0.94, 0.048],
    "ft-fair": [0.24, 0.13, 0.065, 0.059, None, 0.45]  # the variants
    + [0.21, 0.31, 0.73, 0.97, 0.016, 0.21, 0.058, 0.26],  # training, final evaluation
    "walker": [0.001, 0.03, 0.08, 0.90, 0.44, 0.37, 0.42, 0.48],  # exploring, evaluation
}
#: where the page states a bound over the tests after those instead: the smallest p it allows
SMALLEST_P = {"walker": 0.28}


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.parent.name for s in SCRIPTS])
def test_a_verdict_recomputes_from_the_published_seed_files(script):
    out = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, check=True
    ).stdout
    ps = [float(p) for p in re.findall(r"p = ([0-9.]+);", out)]
    study = script.parent.name
    expected = PUBLISHED.get(study)
    if expected is None:  # a study still running: its script runs on what was reached
        assert ps or "no runs" in out or "reached" in out
        return
    if study in SMALLEST_P:  # the tests after the stated ones: a bound
        rest, ps = ps[len(expected) :], ps[: len(expected)]
        assert rest and min(rest) >= SMALLEST_P[study]
    assert len(ps) == len(expected)
    for p, stated in zip(ps, expected, strict=True):
        if stated is None:
            continue
        digits = len(str(stated).split(".")[1])
        assert round(p, digits) == stated
        assert f"{stated}" in (RESULTS / "README.md").read_text()


def test_power_grows_with_the_difference_and_the_detectable_one_has_80_percent():
    assert power_for(0.0, 1.0, 1.0, 3, 3) < 0.06  # the test's size under no difference
    assert power_for(1.0, 1.0, 1.0, 3, 3) < power_for(3.0, 1.0, 1.0, 3, 3) < 1.0
    d = detectable(1.0, 1.0, 3, 3)
    assert power_for(d, 1.0, 1.0, 3, 3) >= 0.8 > power_for(0.95 * d, 1.0, 1.0, 3, 3)
    w = welch([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    assert w["p"] == pytest.approx(1.0) and w["diff"] == 0.0
