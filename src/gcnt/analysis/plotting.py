"""The one way analysis modules get matplotlib's pyplot, draw and write a figure.

Every figure function takes a :class:`FigureStyle` (the options ``--format``, ``--figsize``,
``--font-size``, ``--dpi``, ``--title``, ``--names`` of every figure command): it builds the
figure inside :meth:`FigureStyle.context`, names methods and tasks with
:meth:`FigureStyle.name`, and writes it with :meth:`FigureStyle.save`, once per format. Text
stays text in SVG and PDF files (editable, searchable); axis limits come from
:func:`padded_limits` over every drawn value and interval end, so nothing is clipped.
"""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gcnt.analysis.names import display_name
from gcnt.files import writing

#: the file formats a figure can be written in
FORMATS = ("png", "pdf", "svg")


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg backend, unless pyplot was imported
    already: then its backend stays (a notebook's inline plots keep working)."""
    import matplotlib

    if "matplotlib.pyplot" not in sys.modules:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


@dataclass(frozen=True)
class FigureStyle:
    """How a figure is drawn and written. The defaults: the format of the path's suffix, each
    figure's own size and matplotlib's font size, 150 dpi, each figure's own title, and the
    default display names (:mod:`gcnt.analysis.names`)."""

    #: file formats (``png``, ``pdf``, ``svg``); empty: the suffix of the path given
    formats: tuple[str, ...] = ()
    #: (width, height) in inches; None: the figure's own, from its number of panels
    figsize: tuple[float, float] | None = None
    #: base font size in points (relative sizes such as "small" follow it)
    font_size: float | None = None
    dpi: int = 150
    #: the figure's title (replaces its default one)
    title: str | None = None
    #: key -> display name, over the default tables
    names: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for f in self.formats:
            if f not in FORMATS:
                raise ValueError(f"format {f!r} is not one of {', '.join(FORMATS)}")
        if self.figsize is not None and not (
            len(self.figsize) == 2 and all(math.isfinite(v) and v > 0 for v in self.figsize)
        ):
            raise ValueError(f"figsize must be two positive inches, got {self.figsize}")
        if self.font_size is not None and not (self.font_size > 0):
            raise ValueError(f"font size must be positive, got {self.font_size}")
        if not self.dpi > 0:
            raise ValueError(f"dpi must be positive, got {self.dpi}")

    def name(self, key: str) -> str:
        """The display name of a method or task id."""
        return display_name(key, self.names)

    def size(self, default: tuple[float, float]) -> tuple[float, float]:
        """The figure size: the style's, else the figure's own ``default``."""
        return tuple(self.figsize) if self.figsize is not None else default

    @contextlib.contextmanager
    def context(self) -> Iterator[None]:
        """matplotlib settings while a figure is built and written: the font size, and text
        kept as text in SVG (``svg.fonttype: none``) and as TrueType in PDF."""
        import matplotlib

        rc: dict[str, Any] = {"svg.fonttype": "none", "pdf.fonttype": 42, "ps.fonttype": 42}
        if self.font_size is not None:
            rc["font.size"] = self.font_size
        with matplotlib.rc_context(rc):
            yield

    def suptitle(self, fig, default: str | None = None, **kwargs: Any) -> None:
        """The figure's title: the style's, else ``default`` (none if both are None)."""
        text = self.title if self.title is not None else default
        if text:
            fig.suptitle(text, **kwargs)

    def outputs(self, path: str | Path) -> list[Path]:
        """The files :meth:`save` writes for ``path``: one per format (the path's suffix
        replaced), or ``path`` itself when no format is set."""
        path = Path(path)
        if not self.formats:
            return [path]
        return [path.with_suffix(f".{f}") for f in dict.fromkeys(self.formats)]

    def save(self, fig, path: str | Path) -> list[Path]:
        """Write ``fig`` to :meth:`outputs` and close it: trimmed to what is drawn, or, with a
        ``figsize``, on a page of exactly that size with everything drawn (legends beside the
        axes included) fitted inside it (:func:`fit_page`)."""
        plt = pyplot()
        paths = self.outputs(path)
        try:
            with self.context():
                page = fit_page(fig, self.figsize) if self.figsize is not None else "tight"
                for p in paths:
                    p.parent.mkdir(parents=True, exist_ok=True)
                    with writing(p) as f:
                        fig.savefig(
                            f,
                            format=p.suffix[1:].lower() or None,
                            dpi=self.dpi,
                            bbox_inches=page,
                        )
        finally:
            plt.close(fig)
        return paths


#: the white margin around what is drawn, inches (matplotlib's ``savefig.pad_inches``)
PAGE_PAD = 0.05


def fit_page(fig, size: tuple[float, float], tries: int = 6):
    """The region of ``fig`` (a matplotlib ``Bbox`` in inches) to save as a page of exactly
    ``size`` inches: the figure is shrunk and laid out again (``tight_layout``) until what is
    drawn, with what hangs outside its axes (a legend beside them), fits the page; centred in
    it. Where it cannot fit (a page too small for the text), the page keeps its size and a
    warning says what was cut."""
    import warnings

    from matplotlib.transforms import Bbox

    width, height = size
    drawn = _drawn(fig)
    for _ in range(tries):
        over_w, over_h = drawn.width - width, drawn.height - height
        if over_w <= 1e-3 and over_h <= 1e-3:
            break
        w, h = fig.get_size_inches()
        new = (max(w - max(over_w, 0.0), 0.2 * width), max(h - max(over_h, 0.0), 0.2 * height))
        if new == (w, h):
            break
        fig.set_size_inches(*new)
        if fig.get_layout_engine() is None:
            fig.tight_layout()
        drawn = _drawn(fig)
    else:
        drawn = _drawn(fig)
    if drawn.width > width + 1e-3 or drawn.height > height + 1e-3:
        warnings.warn(
            f"the figure's text needs {drawn.width:.2f} x {drawn.height:.2f} in; the page of "
            f"{width:g} x {height:g} in cuts it (a smaller --font-size or a larger --figsize)",
            stacklevel=3,
        )
    x0 = drawn.x0 - (width - drawn.width) / 2
    y0 = drawn.y0 - (height - drawn.height) / 2
    return Bbox.from_bounds(x0, y0, width, height)


def _drawn(fig):
    """What ``fig`` draws, inches, with the page's white margin."""
    fig.canvas.draw()
    return fig.get_tightbbox(fig.canvas.get_renderer()).padded(PAGE_PAD)


def padded_limits(values: Iterable[float], margin: float = 0.05) -> tuple[float, float] | None:
    """(low, high) holding every finite value with ``margin`` of their span on each side (1 on
    each side of a single value); None without a finite value."""
    xs = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if not xs:
        return None
    lo, hi = min(xs), max(xs)
    pad = margin * (hi - lo) if hi > lo else max(1.0, 0.05 * abs(lo))
    return lo - pad, hi + pad
