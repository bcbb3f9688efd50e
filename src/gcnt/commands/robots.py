"""``gcnt robots``: list benchmarks and robots; rebuild or check the SMPENV robot files.

gcnt robots                      benchmarks with their splits, and a table of all robots
gcnt robots CWHH++:test hopper_4 only these robots (names, .xml paths, Benchmark:split)
gcnt robots --rebuild [--out D]  regenerate morphologies/smpenv/*.xml (or into D)
gcnt robots --check              exit 1 unless the checked-in files equal a regeneration
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from gcnt.morphology.benchmarks import load_benchmarks, morphologies_dir, resolve_robots
from gcnt.morphology.smpenv import SMPENV_ROBOTS, build_mjcf, write_all

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "specs",
        nargs="*",
        metavar="ROBOT",
        help="robots to list: names, .xml paths or Benchmark:split (default: every SMPENV robot)",
    )
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument(
        "--rebuild", action="store_true", help="regenerate the SMPENV robot files from the builders"
    )
    mode.add_argument(
        "--check",
        action="store_true",
        help="verify the checked-in SMPENV robot files are identical to a regeneration",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="folder for --rebuild (default: <morphologies>/smpenv)",
    )


def _smpenv_dir() -> Path:
    return morphologies_dir() / "smpenv"


def _rebuild(out: Path | None) -> int:
    out = out if out is not None else _smpenv_dir()
    paths = write_all(out)
    print(f"wrote {len(paths)} robot files to {out}")
    return 0


def _check() -> int:
    folder = _smpenv_dir()
    stale: list[str] = []
    for name in SMPENV_ROBOTS:
        path = folder / f"{name}.xml"
        if not path.is_file():
            stale.append(f"{path}: missing")
        elif path.read_text() != build_mjcf(name):
            stale.append(f"{path}: differs from the builder's output")
    extra = sorted(p.name for p in folder.glob("*.xml") if p.stem not in SMPENV_ROBOTS)
    stale.extend(f"{folder / n}: not an SMPENV robot" for n in extra)
    if stale:
        print("\n".join(stale))
        print(f"{len(stale)} problem(s); run `gcnt robots --rebuild` to regenerate")
        return 1
    print(f"all {len(SMPENV_ROBOTS)} robot files in {folder} match the builders")
    return 0


def _table(rows: list[tuple[str, ...]], header: tuple[str, ...]) -> str:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    lines = [fmt.format(*header), fmt.format(*("-" * w for w in widths))]
    lines += [fmt.format(*r) for r in rows]
    return "\n".join(line.rstrip() for line in lines)


def _list(specs: list[str]) -> int:
    if not specs:
        print("Benchmarks (morphologies/smpenv.yaml):")
        for bench, splits in load_benchmarks().items():
            for split in ("train", "test"):
                names = splits[split]
                print(f"  {bench + ':' + split:<18} {len(names):2d}  {', '.join(names) or '-'}")
        print()
    robots = resolve_robots(specs or list(SMPENV_ROBOTS))
    rows = [
        (r.name, r.family, str(r.num_limbs), str(r.num_motors), " ".join(r.body_names))
        for r in robots
    ]
    print(_table(rows, ("robot", "family", "limbs", "motors", "bodies (pre-order)")))
    return 0


def run(args: argparse.Namespace) -> int:
    if args.out is not None and not args.rebuild:
        log.error("--out only applies to --rebuild")
        return 2
    try:
        if args.rebuild:
            return _rebuild(args.out)
        if args.check:
            return _check()
        return _list(list(args.specs))
    except (ValueError, FileNotFoundError) as e:  # unknown names, bad robot or split files
        print(f"gcnt robots: error: {e}", file=sys.stderr)
        return 2
