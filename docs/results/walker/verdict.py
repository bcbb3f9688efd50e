"""Study 1's tests, from the files beside this one: the exploring and evaluation returns at
12,000 steps (figure 6) from the seeds' means and standard errors at the last step of curves.csv
and curves-eval.csv (``gcnt curves``; Welch's test depends on the seeds only through them), then
the zero-shot tests (table 1) from the per-seed returns in zeroshot.json (``gcnt zeroshot``):
every pair of methods on each test robot. Each by a two-sided Welch t-test with its power
(``gcnt.analysis.verdict``). The page states that every zero-shot pair has p >= 0.28.

    python docs/results/walker/verdict.py
"""

import itertools
import json
from pathlib import Path

from gcnt.analysis.verdict import curves_line, last_points, verdict_line, welch

HERE = Path(__file__).parent
#: the pairs the page compares on the returns, in its order
RETURN_PAIRS = [("gcnt", "amorpheus"), ("gcnt", "smp"), ("swat", "amorpheus"), ("smp", "amorpheus")]


def main() -> None:
    for file, what in (("curves.csv", "exploring return"), ("curves-eval.csv", "evaluation")):
        points = last_points(HERE / file)
        for a, b in RETURN_PAIRS:
            print(curves_line(f"{what}, {a} against {b}", a, b, points))
    for table in json.loads((HERE / "zeroshot.json").read_text()).values():
        for robot, cells in table["cells"].items():
            for a, b in itertools.combinations(table["methods"], 2):
                x = list(cells[a]["per_seed"].values())
                y = list(cells[b]["per_seed"].values())
                print(
                    verdict_line(
                        f"zero-shot {robot}, {a} against {b}", (a, b), welch(x, y), (len(x), len(y))
                    )
                )


if __name__ == "__main__":
    main()
