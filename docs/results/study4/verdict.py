"""Study 4's pre-registered test and its secondary tests, from its per-seed values.

    python docs/results/study4/verdict.py                       # from seeds.csv beside this file
    python docs/results/study4/verdict.py --from-sweep $STUDIES/study4   # rewrite seeds.csv first

Primary: each seed's mean exploring return (``train_return/mean``) over the logged rows of its
last 100,000 env steps; GCNT against SMP by a two-sided Welch t-test, alpha = 0.05. Secondary,
each with its own Welch test: the last periodic evaluation on the training robots, and zero-shot
on each test robot (the ``gcnt sweep --eval test`` files). Each line states the test's power
(``gcnt.analysis.verdict``). seeds.csv holds the values published in docs/results/README.md
(one decimal); the study's runs are not in the repository.
"""

import argparse
import csv
import statistics as st
from pathlib import Path

from gcnt.analysis.verdict import verdict_line, welch

HERE = Path(__file__).parent
WINDOW = 100_000
MEASURES = {
    "primary_last100k_return": "primary (last-100k exploring return)",
    "final_eval_train": "final evaluation, training robots",
    "zeroshot_walker_3_main": "zero-shot walker_3_main",
    "zeroshot_walker_6_main": "zero-shot walker_6_main",
}


def from_sweep(sweep: str) -> list[dict]:
    """The per-seed values from the study's sweep directory."""
    from gcnt.analysis.runs import find_runs

    rows = []
    for run in find_runs([sweep]):
        metrics = [r for r in run.metrics() if "train_return/mean" in r]
        end = run.last_env_steps()
        evals = run.evals()
        last = max((e for e in evals if e.label == ""), key=lambda e: e.env_steps)
        [test] = [e for e in evals if e.label == "test"]
        rows.append(
            {
                "method": run.method,
                "seed": run.seed,
                "env_steps": end,
                "primary_last100k_return": round(
                    st.mean(
                        r["train_return/mean"] for r in metrics if r["env_steps"] > end - WINDOW
                    ),
                    1,
                ),
                "final_eval_train": round(
                    st.mean(last.robots[n]["mean"] for n in run.train_robot_names()), 1
                ),
                **{f"zeroshot_{n}": round(v["mean"], 1) for n, v in test.robots.items()},
            }
        )
    return sorted(rows, key=lambda r: (r["method"], r["seed"]))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--from-sweep", metavar="DIR", help="rewrite seeds.csv from the sweep first")
    args = p.parse_args()
    path = HERE / "seeds.csv"
    if args.from_sweep:
        rows = from_sweep(args.from_sweep)
        with path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    rows = list(csv.DictReader(path.open()))
    for key, name in MEASURES.items():
        g = [float(r[key]) for r in rows if r["method"] == "gcnt"]
        s = [float(r[key]) for r in rows if r["method"] == "smp"]
        print(verdict_line(name, ("GCNT", "SMP"), welch(g, s), (len(g), len(s))))


if __name__ == "__main__":
    main()
