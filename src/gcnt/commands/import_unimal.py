"""``gcnt import-unimal PATH [--name Unimal100] [--out DIR]``: the paper's UNIMAL-100 robots.

gcnt's UNIMAL robots (``Unimal:train``, ``Unimal:test``, ...) are generated, not the paper's
evolved ones. MetaMorph publishes those as ``unimals_100.zip`` (the data link of its README,
github.com/agrimgupta92/metamorph); this command takes the archive as downloaded, or the folder it
unpacks to, checks every robot file, and registers the set as a catalogue and benchmark:

gcnt import-unimal unimals_100.zip          # -> Unimal100:train, :test, :variants-dynamics, ...
gcnt robots Unimal100:test                  # its robots and their statistics
gcnt train recipes/unimal/ft_unimal100.yaml  # UNIMAL FT on the paper's robots

The set goes into the user's robot-set folder (``$GCNT_MORPHOLOGIES``, default
``~/.local/share/gcnt/morphologies``), read beside the robots that ship with gcnt; ``--out DIR``
imports into another folder (gcnt reads it when ``GCNT_MORPHOLOGIES`` points there). See
``gcnt.morphology.unimal.imported`` for the layout it reads and writes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from gcnt.morphology.unimal.imported import ARCHIVE, DEFAULT_NAME

    parser.add_argument(
        "path",
        type=Path,
        metavar="PATH",
        help=f"MetaMorph's {ARCHIVE} as downloaded, or the unimals_100/ folder it unpacks to",
    )
    parser.add_argument(
        "--name",
        default=DEFAULT_NAME,
        help=f"the catalogue and benchmark name (default: {DEFAULT_NAME}); robot lists then say "
        "NAME:train, NAME:test, NAME:variants-dynamics, NAME:variants-kinematics",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="the robot-set folder to import into (default: the one gcnt reads, "
        "$GCNT_MORPHOLOGIES or ~/.local/share/gcnt/morphologies)",
    )


def run(args: argparse.Namespace) -> int:
    from gcnt.data_folders import user_morphologies
    from gcnt.morphology.unimal.imported import import_unimals

    print(f"checking every robot file of {args.path} ...", flush=True)
    try:
        imported = import_unimals(args.path, name=args.name, out=args.out)
    except ValueError as e:  # a bad file or folder, a name taken: the message names it
        print(f"gcnt import-unimal: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:  # SIGTERM or Ctrl-C: the temporary folder is gone
        how = str(e) or "stopped by SIGINT"
        print(f"gcnt import-unimal: {how}; nothing was imported", file=sys.stderr)
        return 143 if "SIGTERM" in how else 130
    total = sum(len(names) for names in imported.splits.values())
    print(f"imported {total} UNIMAL robots into {imported.folder}:")
    for split, names in imported.splits.items():
        print(f"  {imported.name}:{split:<22} {len(names):5d} robots")
    print(
        f"use them as env.robots: ['{imported.name}:train'], "
        f"env.test_robots: ['{imported.name}:test'] (recipes/unimal/ft_unimal100.yaml)"
    )
    if imported.folder.parent != user_morphologies():
        print(f"gcnt reads them where GCNT_MORPHOLOGIES={imported.folder.parent}")
    return 0
