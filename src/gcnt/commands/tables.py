"""``gcnt tables``: the parameter tables (paper tables 7-8) as Markdown, from ``gcnt params``.

Writes ``params.md`` and ``params.json`` to ``--out`` (default ``figures``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--presets", default="smpenv,unimal", help="size presets (default: smpenv,unimal)"
    )
    p.add_argument("--out", type=Path, default=Path("figures"), help="output folder (figures)")


def run(args: argparse.Namespace) -> int:
    from gcnt.analysis.tables import parameter_tables

    presets = tuple(s.strip() for s in args.presets.split(",") if s.strip())
    md, data = parameter_tables(presets)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "params.md").write_text(md + "\n")
    (args.out / "params.json").write_text(json.dumps(data, indent=1))
    print(md)
    print(f"written: {args.out / 'params.md'}\nwritten: {args.out / 'params.json'}")
    return 0
