"""Command-line options that several commands share."""

from __future__ import annotations

import argparse


def add_eval_protocol(p: argparse.ArgumentParser, dest: str, what: str = "") -> None:
    """``--deterministic`` / ``--stochastic`` (mutually exclusive) into ``dest``: True, False,
    or None (the run's recipe ``eval.deterministic`` decides). ``what`` prefixes the help."""
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--deterministic",
        dest=dest,
        action="store_const",
        const=True,
        default=None,
        help=f"{what}the policy's mean action (default: the run's eval.deterministic)",
    )
    mode.add_argument(
        "--stochastic",
        dest=dest,
        action="store_const",
        const=False,
        help=f"{what}actions sampled from the policy (ModuMorph's PPO protocol; default: the "
        "run's eval.deterministic)",
    )


def _formats(text: str) -> list[str]:
    from gcnt.analysis.plotting import FORMATS

    formats = [f.strip().lower().lstrip(".") for f in text.split(",") if f.strip()]
    for f in formats:
        if f not in FORMATS:
            raise argparse.ArgumentTypeError(f"{f!r} is not one of {', '.join(FORMATS)}")
    if not formats:
        raise argparse.ArgumentTypeError("no format given")
    return formats


def _figsize(text: str) -> tuple[float, float]:
    parts = text.replace("x", ",").split(",")
    try:
        w, h = (float(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not W,H in inches (e.g. 3.4,2.6)") from None
    if not (0 < w < 1000 and 0 < h < 1000):
        raise argparse.ArgumentTypeError(f"{text!r}: width and height must be positive inches")
    return w, h


def _positive(kind: type):
    """A parser of positive ``kind`` values (argparse ``type=``)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"{text!r} must be positive")
        return value

    return parse


class NamesFile(dict):
    """The display names of a ``--names`` file (a file may serve several figures: its keys
    need only be known somewhere, see :func:`check_names`)."""


def _names(text: str) -> dict[str, str]:
    """``KEY=NAME[,KEY=NAME...]``, or a YAML/JSON file mapping keys to names (a
    :class:`NamesFile`)."""
    from pathlib import Path

    path = Path(text)
    if "=" not in text and (path.suffix in (".yaml", ".yml", ".json") or path.is_file()):
        from gcnt.files import MiB, read_yaml

        what = "a names file maps ids to display names in YAML or JSON"
        data = read_yaml(path, MiB, what, argparse.ArgumentTypeError)
        if not isinstance(data, dict) or not all(
            isinstance(k, str) and isinstance(v, str | int | float) for k, v in data.items()
        ):
            raise argparse.ArgumentTypeError(f"{text}: not a mapping of ids to display names")
        return NamesFile({k: str(v) for k, v in data.items()})
    out = {}
    for item in text.split(","):
        key, sep, name = item.partition("=")
        key, name = key.strip(), name.strip().strip("\"'")
        if not sep or not key or not name:
            raise argparse.ArgumentTypeError(
                f"{item.strip()!r} is not KEY=NAME (e.g. metamorph_star=MetaMorph*), "
                "nor a names file"
            )
        out[key] = name
    return out


def add_figure_options(p: argparse.ArgumentParser) -> None:
    """The options every figure command shares: file formats, size, font size, resolution,
    title and display names (:class:`gcnt.analysis.plotting.FigureStyle`)."""
    g = p.add_argument_group("figure options")
    g.add_argument(
        "--format",
        dest="formats",
        type=_formats,
        action="append",
        metavar="FMT",
        help="png, pdf or svg; repeat or list (pdf,svg) for several files (default: png)",
    )
    g.add_argument(
        "--figsize", type=_figsize, metavar="W,H", help="figure size in inches (default: by panels)"
    )
    g.add_argument(
        "--font-size", type=_positive(float), metavar="PT", help="base font size in points"
    )
    g.add_argument(
        "--dpi", type=_positive(int), default=150, help="resolution of PNG files (default 150)"
    )
    g.add_argument("--title", help="the figure's title (replaces its default)")
    add_names_option(g)


def add_names_option(p: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--names``: display names over the defaults (:mod:`gcnt.analysis.names`), for figure
    and table commands."""
    p.add_argument(
        "--names",
        type=_names,
        action="append",
        metavar="KEY=NAME,...|FILE",
        help="display names of methods, tasks or robot sets, over the defaults (GCNT, "
        "MetaMorph*, Walker++, ...): metamorph_star=MetaMorph*,gcnt=Ours, or a YAML/JSON file "
        "of them",
    )


def check_names(args: argparse.Namespace, shown) -> None:
    """An error naming the first ``--names`` key that names nothing ``shown`` (the methods,
    tasks and robot sets of this figure or table, e.g.
    :func:`gcnt.analysis.names.run_keys`), with the closest keys. A names file's keys may also
    be any method or task of the default tables."""
    from gcnt.analysis.names import unknown_names
    from gcnt.analysis.runs import AnalysisError

    shown = set(shown)
    for group in args.names or []:
        if problem := unknown_names(group, shown, any_known=isinstance(group, NamesFile)):
            raise AnalysisError(problem)


def _names_of(args: argparse.Namespace) -> dict[str, str]:
    return {k: v for group in args.names or [] for k, v in group.items()}


def table_style(args: argparse.Namespace):
    """The :class:`~gcnt.analysis.plotting.FigureStyle` of a table command: its ``--names``."""
    from gcnt.analysis.plotting import FigureStyle

    return FigureStyle(names=_names_of(args))


def figure_style(args: argparse.Namespace):
    """The :class:`~gcnt.analysis.plotting.FigureStyle` of :func:`add_figure_options`'s
    options."""
    from gcnt.analysis.plotting import FigureStyle

    formats = [f for group in args.formats or [["png"]] for f in group]
    return FigureStyle(
        formats=tuple(dict.fromkeys(formats)),
        figsize=args.figsize,
        font_size=args.font_size,
        dpi=args.dpi,
        title=args.title,
        names=_names_of(args),
    )
