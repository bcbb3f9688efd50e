"""The one way analysis modules get matplotlib's pyplot."""

from __future__ import annotations

import sys


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg backend, unless pyplot was imported
    already: then its backend stays (a notebook's inline plots keep working)."""
    import matplotlib

    if "matplotlib.pyplot" not in sys.modules:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
