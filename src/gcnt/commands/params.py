"""``gcnt params``: parameter counts of every method, actor and critic, next to the paper's
appendix tables 7 (SMPENV) and 8 (UNIMAL); what the counts cover is in :mod:`gcnt.analysis.params`.

gcnt params                        SMPENV: TD3 actor / critic at the SMPENV preset
gcnt params --benchmark unimal     UNIMAL: PPO actor / critic at the UNIMAL preset, per world
"""

from __future__ import annotations

import argparse

from gcnt.analysis.params import (
    ALGORITHM,
    COMPARED,
    SMP_ORIGINAL_ACTOR,
    count_table,
    ratios,
    setup_of,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--benchmark",
        default="smpenv",
        help="benchmark whose widths and preset to count at: smpenv (default) or unimal",
    )


def run(args: argparse.Namespace) -> int:
    setup = setup_of(args.benchmark)
    algo = ALGORITHM.get(setup.benchmark, "ppo")
    rows = count_table(args.benchmark)
    twin = " (one of TD3's twin critics)" if algo == "td3" else ""
    print(
        f"benchmark {setup.benchmark}: preset {setup.preset}, F={setup.obs_dim}, "
        f"A={setup.num_actions}; actor = {algo}_actor, critic = {algo}_critic{twin}"
    )
    compared = COMPARED.get(setup.benchmark, "total")
    rel_name = "actor/paper" if compared == "actor" else "ours/paper"
    head = (
        f"{'world':<10}{'method':<16}{'actor':>12}{'critic':>12}{'actor+critic':>14}"
        f"{'paper':>12}{rel_name:>12}"
    )
    for world, hfield in setup.worlds:
        print()
        if world:
            print(f"world {world}" + (f" (height map {hfield})" if hfield else ""))
        print(head)
        print("-" * len(head))
        for r in (r for r in rows if r["world"] == world):
            paper = f"{r['paper']:,}" if r["paper"] else "-"
            rel = f"{r[compared] / r['paper']:.3f}" if r["paper"] else "-"
            print(
                f"{world or '-':<10}{r['method']:<16}{r['actor']:>12,}{r['critic']:>12,}"
                f"{r['total']:>14,}{paper:>12}{rel:>12}"
            )
        for label, (ours, theirs) in ratios(rows, world).items():
            t = f"{theirs:.3f}" if theirs else "-"
            print(f"{label} (actor + critic): {ours:.3f} here, {t} in the paper")
    smp = next((r for r in rows if r["method"] == "smp"), None)
    if smp is not None and setup.benchmark == "smpenv":
        ratios_smp = ", ".join(
            f"{smp['actor'] / n:.3f} of {n:,} ({c} child slots)"
            for c, n in SMP_ORIGINAL_ACTOR.items()
        )
        print(
            f"SMP actor against the original code's actor: {ratios_smp}; the paper's "
            "694,410 counts each original tensor twice (see gcnt.analysis.params)"
        )
    print(
        "\npaper: appendix table 7 (SMPENV) / 8 (UNIMAL); it does not say what it counts "
        "(see `gcnt params --help` and this command's module docstring)."
    )
    return 0
