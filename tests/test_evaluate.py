"""Tests for ``gcnt.rl.evaluate``, the evaluation summaries: ``summarize_robots`` gives the mean
over robots with a bootstrap 95% confidence interval around it, collapsing to the value itself
for a single robot.
"""

import pytest

from gcnt.rl.evaluate import summarize_robots


def test_summarize_robots_bootstrap_ci():
    res = {f"r{i}": {"mean": float(m)} for i, m in enumerate([1.0, 2.0, 3.0, 4.0, 10.0])}
    s = summarize_robots(res)
    assert s["mean"] == pytest.approx(4.0) and s["robots"] == 5
    assert s["ci95_low"] < 4.0 < s["ci95_high"]
    assert summarize_robots({"a": {"mean": 2.0}})["ci95_low"] == 2.0
