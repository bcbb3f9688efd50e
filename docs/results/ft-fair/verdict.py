"""Study 2's variant-robustness tests (figure 8), from the per-seed scores in variants.json beside
this file (written by ``gcnt variants``): each comparison the results page states, by a
two-sided Welch t-test with its power (``gcnt.analysis.verdict``).

    python docs/results/ft-fair/verdict.py
"""

import json
from pathlib import Path

from gcnt.analysis.verdict import verdict_line, welch

HERE = Path(__file__).parent
SETS = {"unimal_000?-[lr]*": "kinematics", "unimal_000?-[adg]*": "dynamics"}
#: the pairs the page compares, in its order
PAIRS = [("modumorph", "gcnt"), ("gcnt", "metamorph"), ("gcnt_no_wl", "gcnt")]


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


if __name__ == "__main__":
    main()
