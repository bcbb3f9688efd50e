"""Study 5's pre-registered test and its secondary tests, from the per-seed files beside this file.

    python docs/results/study5/verdict.py

Files (written by the commands in docs/results/README.md, "Study 5"): ``curves.seeds.csv``
(``gcnt curves --per-seed``: every run's logged exploring return and episode length),
``curves-eval.seeds.csv`` (``--metric eval --per-seed``: its periodic evaluations) and
``zeroshot.json`` (``gcnt zeroshot``: per-seed zero-shot returns). Primary: each seed's mean
exploring return over the logged rows of the last third of its steps (env steps above 2/3 of its
last logged env steps); GCNT against SMP by a two-sided Welch t-test, alpha = 0.05, with the
test's power (``gcnt.analysis.verdict``). Secondary, each its own Welch test, no correction: the
mean episode length over the same window, the last evaluation on the training robots, zero-shot
on each test robot. A study still running is reported as reached (steps per seed), no verdict.
"""

import csv
import json
import statistics as st
from pathlib import Path

from gcnt.analysis.verdict import verdict_line, welch

HERE = Path(__file__).parent
METHODS = ("gcnt", "smp")
BUDGET = 200_000


def per_seed(path: Path, column: str) -> dict[str, dict[int, list[tuple[int, float]]]]:
    """method -> seed -> [(env_steps, value)] of ``column``."""
    out: dict[str, dict[int, list[tuple[int, float]]]] = {}
    if not path.is_file():
        return out
    for row in csv.DictReader(path.open()):
        if row.get(column) not in (None, ""):
            seeds = out.setdefault(row["method"], {})
            seeds.setdefault(int(row["seed"]), []).append(
                (int(row["env_steps"]), float(row[column]))
            )
    return out


def last_third(points: list[tuple[int, float]]) -> float:
    end = max(s for s, _ in points)
    return st.mean(v for s, v in points if s > 2 * end / 3)


def main() -> None:
    train = HERE / "curves.seeds.csv"
    returns = per_seed(train, "train_return/mean")
    if not returns:
        print("no runs published yet")
        return
    reached = {
        m: {s: max(x for x, _ in pts) for s, pts in seeds.items()} for m, seeds in returns.items()
    }
    print("reached (env steps per seed):", json.dumps(reached))
    if any(
        len(reached.get(m, {})) < 3 or min(reached[m].values()) < BUDGET * 0.999 for m in METHODS
    ):
        print(
            "not every run has reached 200,000 steps: no verdict (the tests below are of what was reached)"
        )
    measures = {
        "primary (last-third exploring return)": returns,
        "episode length (last third)": per_seed(train, "train_length/mean"),
    }
    for name, data in measures.items():
        if not all(m in data for m in METHODS):
            continue
        g, s = ([last_third(p) for p in data[m].values()] for m in METHODS)
        if min(len(g), len(s)) >= 2:
            print(verdict_line(name, ("GCNT", "SMP"), welch(g, s), (len(g), len(s))))
    evals = per_seed(HERE / "curves-eval.seeds.csv", "eval")
    if all(m in evals for m in METHODS):
        g, s = ([max(p)[1] for p in evals[m].values()] for m in METHODS)
        if min(len(g), len(s)) >= 2:
            print(
                verdict_line(
                    "last evaluation, training robots",
                    ("GCNT", "SMP"),
                    welch(g, s),
                    (len(g), len(s)),
                )
            )
    zs = HERE / "zeroshot.json"
    if zs.is_file():
        for task in json.loads(zs.read_text()).values():
            for robot, cells in task["cells"].items():
                if all(m in cells for m in METHODS):
                    g, s = (list(cells[m]["per_seed"].values()) for m in METHODS)
                    if min(len(g), len(s)) >= 2:
                        print(
                            verdict_line(
                                f"zero-shot {robot}", ("GCNT", "SMP"), welch(g, s), (len(g), len(s))
                            )
                        )


if __name__ == "__main__":
    main()
