"""``gcnt tables``: the parameter tables (paper tables 7-8) as Markdown, from ``gcnt params``.

Writes ``params.md`` (methods by their display names, ``--names`` over the defaults) and
``params.json`` (by their ids) to ``--out`` (default ``figures``), and
``params.caption.txt``: the gcnt version and commit that computed them (also the last line of
``params.md``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from gcnt.commands.options import add_names_option, check_names, table_style
from gcnt.files import write_text


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--presets", default="smpenv,unimal", help="size presets (default: smpenv,unimal)"
    )
    p.add_argument("--out", type=Path, default=Path("figures"), help="output folder (figures)")
    add_names_option(p)


def run(args: argparse.Namespace) -> int:
    from gcnt.analysis.tables import parameter_tables
    from gcnt.nn.registry import NETWORKS
    from gcnt.run import provenance

    presets = tuple(s.strip() for s in args.presets.split(",") if s.strip())
    check_names(args, NETWORKS)  # the tables' rows: every registered method
    md, data = parameter_tables(presets, table_style(args))
    caption = provenance.this_code("tables")  # no runs: the code that computed them
    args.out.mkdir(parents=True, exist_ok=True)
    write_text(args.out / "params.md", f"{md}\n\n_{caption}_\n")
    write_text(args.out / "params.json", json.dumps(data, indent=1))
    cap = provenance.write_caption(caption, args.out / "params.caption.txt")
    print(md)
    print(caption)
    print(f"written: {args.out / 'params.md'}\nwritten: {args.out / 'params.json'}")
    print(f"written: {cap}")
    return 0
