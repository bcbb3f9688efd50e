"""What an interval is called, and when a best result may be marked.

Every figure and table names its interval and the number of values behind it: ``mean ± 1 s.e.
(n = 3 seeds)``. A percentile bootstrap over fewer than :data:`MIN_BOOTSTRAP` values is not a
confidence interval (with two values its 95% interval is their range, whatever the level), so
there the values' range is given and called so. A best mean is marked only when its interval and
the runner-up's do not overlap.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from gcnt.bootstrap import MIN_BOOTSTRAP  # noqa: F401 (re-exported: the analysis names it here)


def count_text(counts: Iterable[int], unit: str = "seeds") -> str:
    """``n = 3 seeds``, or ``n = 2-3 seeds`` where the counts differ (``seed`` for one)."""
    ns = sorted({int(n) for n in counts})
    if not ns:
        return f"n = 0 {unit}"
    n = f"{ns[0]}" if len(ns) == 1 else f"{ns[0]}–{ns[-1]}"
    one = unit[:-1] if unit.endswith("s") and ns == [1] else unit
    return f"n = {n} {one}"


def stderr_text(counts: Iterable[int], unit: str = "seeds") -> str:
    """``mean ± 1 s.e. (n = 3 seeds)``; a single value has no standard error, which it says."""
    counts = list(counts)
    text = f"mean ± 1 s.e. ({count_text(counts, unit)})"
    if 1 in counts:
        text += "; n = 1: the value alone, no interval"
    return text


def separated_best(cells: Mapping[str, tuple[float, float, float]]) -> str | None:
    """The key with the highest mean when its interval lies wholly above the runner-up's
    (``cells``: key -> (mean, low, high)); None when they overlap or touch, when either has no
    interval (nan), or when there is no runner-up."""
    ranked = sorted(
        ((m, lo, hi, k) for k, (m, lo, hi) in cells.items() if math.isfinite(m)),
        key=lambda c: c[0],
        reverse=True,
    )
    if len(ranked) < 2:
        return None
    (m1, lo1, _, key), (m2, _, hi2, _) = ranked[0], ranked[1]
    if m1 == m2 or not (math.isfinite(lo1) and math.isfinite(hi2)):
        return None
    return key if lo1 > hi2 else None
