"""A study's test of two methods from its per-seed values: the two-sided Welch t-test its
verdicts name, and the power that test had (``docs/results/*/verdict.py``).

The power of Welch's test has no closed form; it is simulated here: normal seed values with each
method's own standard deviation as observed, a fixed random stream (so a verdict's numbers
repeat), :data:`DRAWS` studies of the same seeds. ``power_for`` gives the chance that a true
difference of a given size reaches p < ``alpha``; ``detectable`` the smallest true difference
that does with 80% power. A verdict states both, so that "not decided" is read with what the test
could have decided.
"""

from __future__ import annotations

import math
import statistics as st
from collections.abc import Sequence

import numpy as np

#: simulated studies per power figure
DRAWS = 20_000


def power_for(
    diff: float, sd_a: float, sd_b: float, na: int, nb: int, alpha: float = 0.05
) -> float:
    """The power of a two-sided Welch t-test at ``alpha`` for a true difference ``diff``
    between two methods whose seed values are normal with standard deviations ``sd_a`` and
    ``sd_b`` (``na`` + ``nb`` seeds), simulated from a fixed random stream."""
    from scipy import stats

    rng = np.random.default_rng(0)
    a = diff + sd_a * rng.standard_normal((DRAWS, na))
    b = sd_b * rng.standard_normal((DRAWS, nb))
    p = stats.ttest_ind(a, b, axis=1, equal_var=False).pvalue
    return float(np.mean(p < alpha))


def detectable(
    sd_a: float, sd_b: float, na: int, nb: int, alpha: float = 0.05, power: float = 0.8
) -> float:
    """The smallest true difference (in the values' units) that the test detects with
    ``power``, by bisection over :func:`power_for` (the same random stream for every size)."""
    scale = max(sd_a, sd_b)
    if scale <= 0:
        return 0.0
    lo, hi = 0.0, scale
    while power_for(hi, sd_a, sd_b, na, nb, alpha) < power:
        lo, hi = hi, 2 * hi
        if hi > 1e6 * scale:
            return math.inf
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if power_for(mid, sd_a, sd_b, na, nb, alpha) < power else (lo, mid)
    return hi


def welch(a: Sequence[float], b: Sequence[float], alpha: float = 0.05) -> dict[str, float]:
    """Welch's two-sided t-test of ``a`` against ``b`` (means, standard errors, t, df, p), and
    the power of the seeds for the difference seen and the difference detectable at 80%."""
    se = [st.stdev(x) / math.sqrt(len(x)) for x in (a, b)]
    return welch_summary(st.mean(a), se[0], len(a), st.mean(b), se[1], len(b), alpha)


def welch_summary(
    mean_a: float, se_a: float, na: int, mean_b: float, se_b: float, nb: int, alpha: float = 0.05
) -> dict[str, float]:
    """:func:`welch` from each method's mean, standard error and number of seeds (what a
    published ``curves.csv`` holds): Welch's test depends on the seeds only through them."""
    from scipy import stats

    var = se_a**2 + se_b**2
    diff = mean_a - mean_b
    t = diff / math.sqrt(var) if var > 0 else math.nan  # no spread at all: no test
    df = var**2 / (se_a**4 / (na - 1) + se_b**4 / (nb - 1)) if var > 0 else math.nan
    sd_a, sd_b = se_a * math.sqrt(na), se_b * math.sqrt(nb)
    return {
        "mean_a": mean_a,
        "se_a": se_a,
        "mean_b": mean_b,
        "se_b": se_b,
        "diff": diff,
        "t": float(t),
        "df": float(df),
        "p": float(2 * stats.t.sf(abs(t), df)),
        "power_seen": power_for(diff, sd_a, sd_b, na, nb, alpha),
        "detectable_80": detectable(sd_a, sd_b, na, nb, alpha),
    }


def last_points(curves_csv) -> dict[str, tuple[float, float, int]]:
    """Each method's (mean, standard error, seeds) at its last step in a ``gcnt curves`` CSV."""
    import csv
    import io

    from gcnt.files import MiB, read_text

    text = read_text(curves_csv, 64 * MiB, "a gcnt curves CSV", ValueError)
    last: dict[str, tuple[int, float, float, int]] = {}
    for row in csv.DictReader(io.StringIO(text, newline="")):
        step = int(row["env_steps"])
        if row["method"] not in last or step > last[row["method"]][0]:
            last[row["method"]] = (
                step,
                float(row["mean"]),
                float(row["stderr"]),
                int(row["seeds"]),
            )
    return {m: (mean, se, n) for m, (_, mean, se, n) in last.items()}


def curves_line(name: str, a: str, b: str, points: dict) -> str:
    """:func:`verdict_line` of methods ``a`` against ``b`` at their last curve points."""
    (ma, sa, na), (mb, sb, nb) = points[a], points[b]
    return verdict_line(name, (a, b), welch_summary(ma, sa, na, mb, sb, nb), (na, nb))


def verdict_line(
    name: str, labels: tuple[str, str], w: dict[str, float], n: tuple[int, int]
) -> str:
    """One line of a study's verdict: both means ± s.e., the test, and its power."""
    a, b = labels
    return (
        f"{name}: {a} {w['mean_a']:.1f} ± {w['se_a']:.1f}, {b} {w['mean_b']:.1f} ± "
        f"{w['se_b']:.1f} (mean ± s.e., {n[0]} + {n[1]} seeds); Welch t = {w['t']:.3f}, df = "
        f"{w['df']:.2f}, p = {w['p']:.4f}; power for the difference seen ({w['diff']:.1f}) "
        f"{100 * w['power_seen']:.0f}%, difference detectable with 80% power "
        f"{w['detectable_80']:.1f}"
    )
