"""Study 4's pre-registered test and its secondary measures, from a finished sweep directory.

    python docs/results/study4/verdict.py $STUDIES/study4

Primary: each seed's mean exploring return (``train_return/mean`` in ``metrics.jsonl``) over the
rows of its last 100,000 env steps; GCNT against SMP by a two-sided Welch t-test, alpha = 0.05.
Secondary, each with its own Welch test: the last periodic evaluation on the 4 training robots,
and zero-shot on walker_3_main and walker_6_main (``eval/test-*.json``).
"""

import json
import statistics as st
import sys
from pathlib import Path

from scipy import stats

TRAIN = ["walker_2_main", "walker_4_main", "walker_5_main", "walker_7_main"]
METHODS = ("gcnt", "smp")


def primary(run: Path) -> float:
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    end = rows[-1]["env_steps"]
    window = [
        r["train_return/mean"]
        for r in rows
        if r["env_steps"] > end - 100_000 and "train_return/mean" in r
    ]
    return st.mean(window)


def last_eval(run: Path) -> float:
    last = max((run / "eval").glob("step*.json"), key=lambda p: int(p.stem[4:]))
    robots = json.loads(last.read_text())["robots"]
    return st.mean(robots[k]["mean"] for k in TRAIN)


def zero_shot(run: Path) -> dict[str, float]:
    [test] = (run / "eval").glob("test-*.json")
    return {k: v["mean"] for k, v in json.loads(test.read_text())["robots"].items()}


def welch(name: str, values: dict[str, list[float]]) -> None:
    g, s = values["gcnt"], values["smp"]
    t = stats.ttest_ind(g, s, equal_var=False)
    se = {m: st.stdev(v) / len(v) ** 0.5 for m, v in values.items()}
    print(
        f"{name}: GCNT {st.mean(g):.1f} ± {se['gcnt']:.1f}, SMP {st.mean(s):.1f} ± {se['smp']:.1f} "
        f"(mean ± s.e.); Welch t = {t.statistic:.3f}, df = {t.df:.2f}, p = {t.pvalue:.4f}"
    )


def main(sweep: Path) -> None:
    runs = {m: sorted((sweep / "study4-walkerpp" / f"td3-{m}").glob("seed*")) for m in METHODS}
    measures: dict[str, dict[str, list[float]]] = {}
    for m, rs in runs.items():
        for run in rs:
            row = {
                "primary (last-100k exploring return)": primary(run),
                "final evaluation, training robots": last_eval(run),
            }
            row.update({f"zero-shot {k}": v for k, v in zero_shot(run).items()})
            for k, v in row.items():
                measures.setdefault(k, {n: [] for n in METHODS})[m].append(v)
    for name, values in measures.items():
        welch(name, values)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
