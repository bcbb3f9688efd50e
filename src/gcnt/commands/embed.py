"""``gcnt embed [RUN_DIR...] [--untrained gcnt,swat]``: t-SNE of per-limb structural vectors
(paper figure 10): GCNT's projected [GCN ‖ WL] features and SWAT's traversal embeddings of every
limb of the CWHH++ robots, side by side: marker = robot family, colour = limb type, with one
legend for each below the panels.

Runs give trained networks (in a sweep directory, the first seed of each GCNT/SWAT method);
without runs, or with ``--untrained``, freshly initialised networks. Panels are titled with the
methods' and tasks' display names. Writes ``embed.png`` (``--format pdf,svg``: those; the figure
options set size, fonts, title and names).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from gcnt.commands.options import add_figure_options, check_names, figure_style


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="*", metavar="DIR", help="run or sweep directories")
    p.add_argument(
        "--untrained",
        type=lambda s: [m.strip() for m in s.split(",") if m.strip()],
        default=None,
        help="also (or only) untrained networks of these methods (default without runs: gcnt,swat)",
    )
    p.add_argument("--robots", nargs="+", default=["CWHH++:all"], help="robots (CWHH++:all)")
    p.add_argument("--all-seeds", action="store_true", help="a panel per run, not per method")
    p.add_argument("--seed", type=int, default=0, help="t-SNE (and untrained init) seed")
    p.add_argument(
        "--out",
        type=Path,
        help="output folder (default: <DIR>/figures; a run directory's beside it, <RUN>-figures)",
    )
    p.add_argument("--name", default="embed", help="file name stem (default: embed)")
    add_figure_options(p)


def run(args: argparse.Namespace) -> int:
    import torch

    from gcnt.analysis.embed import (
        STRUCTURAL_METHODS,
        NoStructureError,
        has_structure,
        plot_embeddings,
        run_embedding,
    )
    from gcnt.analysis.embed import structural_vectors as vectors
    from gcnt.analysis.names import run_keys
    from gcnt.analysis.runs import AnalysisError, default_out, find_runs, first_seed_per_method

    embeddings = []
    style = figure_style(args)
    untrained = (
        args.untrained if args.untrained is not None else ([] if args.paths else ["gcnt", "swat"])
    )
    found = find_runs(args.paths) if args.paths else []
    check_names(args, {*run_keys(found), *untrained})
    if args.paths:
        runs = [r for r in found if has_structure(r.method)]
        skipped = {r.method: "no per-limb structural vector" for r in found if r not in runs}
        for r in runs if args.all_seeds else first_seed_per_method(runs):
            try:
                embeddings.append(run_embedding(r, args.robots, style.names))
            except NoStructureError:
                skipped[r.method] = "its chain writes no limbs/hidden and limbs/embed"
        if skipped:
            print("not embedded: " + "; ".join(f"{m} ({why})" for m, why in skipped.items()))
        if not embeddings and args.untrained is None:
            raise AnalysisError(
                f"no run with structural vectors in {', '.join(args.paths)} "
                f"(gcnt's methods with them: {', '.join(STRUCTURAL_METHODS)}; a plugin's method "
                "whose chain writes limbs/hidden and limbs/embed)"
            )
    for m in untrained:
        torch.manual_seed(args.seed)
        embeddings.append(vectors(m, args.robots, title=f"{style.name(m)} (untrained)"))
    if not embeddings:
        raise AnalysisError("nothing to embed: give runs or --untrained METHODS")
    out = args.out or (default_out(args.paths) if args.paths else Path("figures"))
    plot_embeddings(embeddings, out / f"{args.name}.png", seed=args.seed, style=style)
    for e in embeddings:
        print(
            f"{e.title}: {len(e.vectors)} limbs of {len(set(e.robots))} robots, d={e.vectors.shape[1]}"
        )
    for path in style.outputs(out / f"{args.name}.png"):
        print(f"written: {path}")
    return 0
