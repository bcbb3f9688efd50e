"""Study 1's zero-shot tests (table 1), from the per-seed returns in zeroshot.json beside this
file (written by ``gcnt zeroshot``): every pair of methods on each test robot, by a two-sided
Welch t-test with its power (``gcnt.analysis.verdict``). The page states that every pair has
p >= 0.3 on both robots.

    python docs/results/walker/verdict.py
"""

import itertools
import json
from pathlib import Path

from gcnt.analysis.verdict import verdict_line, welch

HERE = Path(__file__).parent


def main() -> None:
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
