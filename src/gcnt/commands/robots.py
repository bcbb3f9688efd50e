"""``gcnt robots``: list benchmarks and robots; rebuild, check or generate robot files.

gcnt robots                        benchmarks with their splits, the SMPENV robots, UNIMAL statistics
gcnt robots CWHH++:test hopper_4   only these robots (names, .xml paths or folders, Benchmark:split)
gcnt robots ~/unimals_100/train/xml   a folder of (MetaMorph) robot files
gcnt robots Unimal100:test         the paper's UNIMAL-100 robots, once `gcnt import-unimal` ran
gcnt robots path/to/ant.xml        any robot file: its family (read from its structure) and limbs
gcnt robots --rebuild [--out D]    regenerate every catalogue's files (into D/<catalogue>/...)
gcnt robots --check [--out D]      exit 1 unless gcnt's robot files (or D's) equal a regeneration
gcnt robots --generate 20 --seed 500 --out D   20 new UNIMAL robots (seeds 500-519) into D
Add ``--catalogue smpenv`` (or unimal) to rebuild or check one catalogue only.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from gcnt.data_folders import MORPHOLOGIES_ENV, user_morphologies
from gcnt.files import write_text
from gcnt.morphology.catalogues import (
    catalogue_names,
    get_catalogue,
    imported_catalogues,
    load_benchmarks,
    morphologies_dir,
    resolve_robots,
)
from gcnt.morphology.robot import Robot
from gcnt.morphology.smpenv import SMPENV_ROBOTS

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "specs",
        nargs="*",
        metavar="ROBOT",
        help="robots to list: names, .xml paths or folders, Benchmark:split "
        "(default: every SMPENV robot and the UNIMAL set's statistics)",
    )
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument(
        "--rebuild", action="store_true", help="regenerate the catalogues' robot and split files"
    )
    mode.add_argument(
        "--check",
        action="store_true",
        help="verify the checked-in robot and split files are identical to a regeneration",
    )
    mode.add_argument(
        "--generate",
        type=int,
        metavar="N",
        default=None,
        help="write N new UNIMAL robots (seeds --seed ... --seed+N-1) into --out",
    )
    parser.add_argument("--seed", type=int, default=0, help="first seed for --generate")
    parser.add_argument(
        "--catalogue",
        default=None,
        help="only this catalogue for --rebuild/--check (default: all)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="--rebuild, --check: the robot folder to write or check (default: the one that "
        "ships with gcnt, in a checkout its morphologies/); --generate: the folder for the new "
        "files (required)",
    )


def _selected(name: str | None) -> list[str]:
    return [get_catalogue(name).name] if name else catalogue_names()


def _rebuild(out: Path | None, catalogue: str | None) -> int:
    root = out if out is not None else morphologies_dir()
    for name in _selected(catalogue):
        cat = get_catalogue(name)
        if cat.rebuild is None:
            continue
        paths = cat.rebuild(root)
        print(f"{name}: wrote {len(paths)} files under {root}")
    return 0


def _check(out: Path | None, catalogue: str | None) -> int:
    root = out if out is not None else morphologies_dir()
    problems: list[str] = []
    for name in _selected(catalogue):
        cat = get_catalogue(name)
        if cat.check is None:
            continue
        found = cat.check(root)
        problems += found
        if not found:
            print(f"{name}: all files in {root} match a regeneration")
    if problems:
        print("\n".join(problems))
        print(f"{len(problems)} problem(s); run `gcnt robots --rebuild` to regenerate")
        return 1
    return 0


def _generate(n: int, seed: int, out: Path | None) -> int:
    from gcnt.morphology.unimal import build_mjcf, generate
    from gcnt.morphology.unimal.catalogue import robot_name

    if out is None:
        print("gcnt robots: error: --generate needs --out DIR", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    for s in range(seed, seed + n):
        write_text(out / f"{robot_name(s)}.xml", build_mjcf(generate(s)))
    print(f"wrote {n} UNIMAL robots (seeds {seed}-{seed + n - 1}) to {out}")
    return 0


def _table(rows: list[tuple[str, ...]], header: tuple[str, ...]) -> str:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    lines = [fmt.format(*header), fmt.format(*("-" * w for w in widths))]
    lines += [fmt.format(*r) for r in rows]
    return "\n".join(line.rstrip() for line in lines)


def _benchmark_of() -> dict[str, str]:
    """Robot name -> the first ``Benchmark:split`` that lists it."""
    where: dict[str, str] = {}
    for bench, splits in load_benchmarks().items():
        for split, names in splits.items():
            for n in names:
                where.setdefault(n, f"{bench}:{split}")
    return where


def _robot_rows(robots: list[Robot]) -> str:
    where = _benchmark_of()
    rows = [
        (
            r.name,
            where.get(r.name, "-"),
            r.catalogue,
            r.family,
            str(r.num_limbs),
            str(r.num_motors),
            " ".join(r.body_names),
        )
        for r in robots
    ]
    header = ("robot", "benchmark", "catalogue", "family", "limbs", "motors", "limbs (pre-order)")
    return _table(rows, header)


def _stats_block(sets: dict[str, list[Robot]]) -> str:
    from gcnt.morphology.unimal.stats import PUBLISHED, set_stats

    stats = {name: set_stats(robots) for name, robots in sets.items() if robots}

    def fmt(v: tuple[float, float | None, float], digits: int) -> str:
        mean = "?" if v[1] is None else f"{v[1]:.1f}"
        return f"{v[0]:.{digits}f} / {mean} / {v[2]:.{digits}f}"

    rows = []
    for key in PUBLISHED:
        digits = 1 if key == "mass" else 0
        cells = [fmt(s[key], digits) for s in stats.values()]
        rows.append((key + (" (kg)" if key == "mass" else ""), *cells, fmt(PUBLISHED[key], digits)))
    header = ("min / mean / max", *(f"{n} ({len(sets[n])})" for n in stats), "published train")
    return _table(rows, header)


def _list(specs: list[str]) -> int:
    if specs:
        robots = resolve_robots(specs)
        print(_robot_rows(robots))
        unimals = [r for r in robots if r.family == "unimal"]
        if unimals:
            print()
            print(_stats_block({"these UNIMAL robots": unimals}))
        return 0
    print("Benchmarks:")
    for bench, splits in load_benchmarks().items():
        for split, names in splits.items():
            shown = ", ".join(names) if len(names) <= 12 else f"{names[0]} ... {names[-1]}"
            print(f"  {bench + ':' + split:<28} {len(names):3d}  {shown or '-'}")
    print()
    print(_robot_rows(resolve_robots(list(SMPENV_ROBOTS))))
    print()
    print(UNIMAL_NOTE)
    sets = {f"Unimal:{s}": resolve_robots([f"Unimal:{s}"]) for s in ("train", "test")}
    for name in imported_catalogues():  # MetaMorph's robots, imported, by their benchmark's name
        for bench in load_benchmarks(catalogue=name):
            sets |= {f"{bench}:{s}": resolve_robots([f"{bench}:{s}"]) for s in ("train", "test")}
    print(_stats_block(sets))
    print()
    print(f"gcnt's robot files: {morphologies_dir()}")
    print(f"your robot sets ({MORPHOLOGIES_ENV}, added to gcnt's): {user_morphologies()}")
    return 0


#: what the UNIMAL statistics above compare, said where a reader chooses robots
UNIMAL_NOTE = (
    "UNIMAL robots: Unimal:* are generated by gcnt from the DERL design space, not the paper's\n"
    "evolved UNIMAL-100 (MetaMorph's published files). `gcnt import-unimal unimals_100.zip`\n"
    "registers those as Unimal100:train, :test, :variants-dynamics and :variants-kinematics."
)


def run(args: argparse.Namespace) -> int:
    if args.out is not None and not (args.rebuild or args.check or args.generate is not None):
        log.error("--out only applies to --rebuild, --check and --generate")
        return 2
    try:
        if args.rebuild:
            return _rebuild(args.out, args.catalogue)
        if args.check:
            return _check(args.out, args.catalogue)
        if args.generate is not None:
            return _generate(args.generate, args.seed, args.out)
        return _list(list(args.specs))
    except (ValueError, FileNotFoundError) as e:  # unknown names, bad robot or split files
        print(f"gcnt robots: error: {e}", file=sys.stderr)
        return 2
