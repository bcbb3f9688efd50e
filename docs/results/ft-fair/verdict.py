"""Study 2's tests, from the files beside this one: the variant-robustness tests (figure 8) from
the per-seed scores in variants.json (written by ``gcnt variants``), then the training and final
evaluation returns (figure 7) from the seeds' means and standard errors at the last step of
curves.csv and curves-eval.csv (``gcnt curves``; Welch's test depends on the seeds only through
them). Each comparison the results page states, by a two-sided Welch t-test with its power
(``gcnt.analysis.verdict``).

    python docs/results/ft-fair/verdict.py
"""

import json
from pathlib import Path

from gcnt.analysis.verdict import curves_line, last_points, verdict_line, welch

HERE = Path(__file__).parent
SETS = {"unimal_000?-[lr]*": "kinematics", "unimal_000?-[adg]*": "dynamics"}
#: the pairs the page compares, in its order
PAIRS = [("modumorph", "gcnt"), ("gcnt", "metamorph"), ("gcnt_no_wl", "gcnt")]
#: the pairs the page compares on the training and evaluation returns, in its order
RETURN_PAIRS = [*PAIRS, ("gcnt_dist_first", "gcnt")]


def main() -> None:
    data = json.loads((HERE / "variants.json").read_text())
    for a, b in PAIRS:
        for key, name in SETS.items():
            x = list(data[key][a]["mean"]["per_seed"].values())
            y = list(data[key][b]["mean"]["per_seed"].values())
            print(
                verdict_line(
                    f"{name} variants, {a} against {b}", (a, b), welch(x, y), (len(x), len(y))
                )
            )
    for file, what in (("curves.csv", "training return"), ("curves-eval.csv", "final evaluation")):
        points = last_points(HERE / file)
        for a, b in RETURN_PAIRS:
            print(curves_line(f"{what}, {a} against {b}", a, b, points))


if __name__ == "__main__":
    main()
