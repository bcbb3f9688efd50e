"""``gcnt params``: parameter counts of every method, actor and critic, next to the paper's
appendix tables 7 (SMPENV) and 8 (UNIMAL); what the counts cover is in :mod:`gcnt.analysis.params`.

gcnt params                        SMPENV: TD3 actor / critic at the SMPENV preset
gcnt params --benchmark unimal     UNIMAL: PPO actor / critic at the UNIMAL preset, per world
gcnt params --recipe R.yaml [--methods a,b]
                                   the recipe's benchmark and world at its network sizes
                                   (``network.kwargs`` / ``method_kwargs``), each method's count
                                   and the size ratios next to the same ratios at the paper's
                                   sizes: a reduced study keeps the paper's proportions when they
                                   agree
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

#: how far a reduced recipe's size ratio may be from the paper's sizes' before it is flagged
RATIO_TOLERANCE = 0.10


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--benchmark",
        default="smpenv",
        help="benchmark whose widths and preset to count at: smpenv (default) or unimal",
    )
    parser.add_argument(
        "--recipe",
        default=None,
        help="count at this recipe's benchmark, world and network sizes, with the size ratios "
        "against the paper's sizes",
    )
    parser.add_argument(
        "--methods",
        default=None,
        help="with --recipe: comma-separated methods (default: the benchmark's paper columns "
        "that take the recipe's sizes)",
    )


def run(args: argparse.Namespace) -> int:
    if getattr(args, "recipe", None):
        return run_recipe(args.recipe, args.methods)
    if getattr(args, "methods", None):
        from gcnt.recipes import RecipeError

        raise RecipeError(
            "--methods counts methods at a recipe's sizes: give the recipe too (--recipe "
            "quickstart, or a recipe file); without it `gcnt params` prints the paper's columns"
        )
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


def run_recipe(path: str, methods: str | None) -> int:
    """Counts at a recipe's sizes, and each size ratio against the same ratio at the paper's
    sizes (flagged when more than :data:`RATIO_TOLERANCE` apart)."""
    from dataclasses import replace

    from gcnt.analysis.params import METHODS
    from gcnt.nn import make_config
    from gcnt.recipes import RecipeError, load_recipe

    recipe = load_recipe(path)
    benchmark, world = recipe.env.benchmark, recipe.env.world
    setup = setup_of(benchmark)
    worlds = [world] if world else None

    def sizes(name: str) -> dict:
        return replace(recipe.network, name=name).sizes()

    if methods:
        names = [m.strip() for m in methods.split(",") if m.strip()]
        for name in names:  # one line naming the method and what to change, not a traceback
            try:
                make_config(name, setup.preset, **sizes(name))
            except (TypeError, ValueError) as e:
                raise RecipeError(f"--methods {name}: {e}") from None
    else:
        names = []
        for name in METHODS.get(setup.benchmark, METHODS["unimal"]):
            try:
                make_config(name, setup.preset, **sizes(name))
            except (TypeError, ValueError) as e:
                print(f"{name}: not counted ({e})")
                continue
            names.append(name)
    rows = count_table(benchmark, sizes, worlds, names)
    paper_rows = count_table(benchmark, None, worlds, names)
    print(f"recipe {path}: benchmark {setup.benchmark}, world {world or '-'}")
    head = (
        f"{'world':<10}{'method':<16}{'sizes':<44}{'actor':>10}{'critic':>10}{'actor+critic':>14}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        kw = ", ".join(f"{k}={v}" for k, v in sizes(r["method"]).items()) or "the preset's"
        print(
            f"{r['world']:<10}{r['method']:<16}{kw:<44}{r['actor']:>10,}{r['critic']:>10,}"
            f"{r['total']:>14,}"
        )
    for w in dict.fromkeys(r["world"] for r in rows):
        here = ratios(rows, w)
        there = ratios(paper_rows, w)
        for label, (ours, _) in here.items():
            full = there[label][0]
            off = ours / full - 1.0
            flag = "within" if abs(off) <= RATIO_TOLERANCE else "NOT within"
            print(
                f"{label} (actor + critic): {ours:.3f} at the recipe's sizes, {full:.3f} at the "
                f"paper's sizes ({off:+.1%}: {flag} {RATIO_TOLERANCE:.0%})"
            )
    return 0
