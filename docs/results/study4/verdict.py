"""Study 4's pre-registered test and its secondary measures, from a finished sweep directory.

    python docs/results/study4/verdict.py $STUDIES/study4

Primary: each seed's mean exploring return (``train_return/mean``) over the logged rows of its
last 100,000 env steps; GCNT against SMP by a two-sided Welch t-test, alpha = 0.05. Secondary,
each with its own Welch test: the last periodic evaluation on the training robots, and zero-shot
on each test robot (the ``gcnt sweep --eval test`` files).
"""

import statistics as st
import sys

from scipy import stats

from gcnt.analysis.runs import find_runs
from gcnt.run_data import Run

WINDOW = 100_000


def measures(run: Run) -> dict[str, float]:
    rows = [r for r in run.metrics() if "train_return/mean" in r]
    end = run.last_env_steps()
    out = {
        "primary (last-100k exploring return)": st.mean(
            r["train_return/mean"] for r in rows if r["env_steps"] > end - WINDOW
        )
    }
    evals = run.evals()
    last = max((e for e in evals if e.label == ""), key=lambda e: e.env_steps)
    out["final evaluation, training robots"] = st.mean(
        last.robots[name]["mean"] for name in run.train_robot_names()
    )
    [test] = [e for e in evals if e.label == "test"]
    out.update({f"zero-shot {name}": v["mean"] for name, v in test.robots.items()})
    return out


def main(sweep: str) -> None:
    values: dict[str, dict[str, list[float]]] = {}
    for run in find_runs([sweep]):
        for name, v in measures(run).items():
            values.setdefault(name, {}).setdefault(run.method, []).append(v)
    for name, by_method in values.items():
        g, s = by_method["gcnt"], by_method["smp"]
        t = stats.ttest_ind(g, s, equal_var=False)
        print(
            f"{name}: GCNT {st.mean(g):.1f} ± {st.stdev(g) / len(g) ** 0.5:.1f}, "
            f"SMP {st.mean(s):.1f} ± {st.stdev(s) / len(s) ** 0.5:.1f} (mean ± s.e., "
            f"{len(g)} + {len(s)} seeds); Welch t = {t.statistic:.3f}, df = {t.df:.2f}, "
            f"p = {t.pvalue:.4f}"
        )


if __name__ == "__main__":
    main(sys.argv[1])
