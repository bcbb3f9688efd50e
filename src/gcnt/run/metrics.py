"""``metrics.jsonl``, a run's local record: one strict-JSON line per log step.

Written by :meth:`gcnt.run.directory.RunDir.log_metrics` and read by every reader (resume, the
analysis commands) through :func:`read_metrics`. A run stopped while appending a line (killed,
or a full disk) leaves that last line incomplete: it is dropped with one warning. A corrupt
line before the last one is damage of another kind (two writers, an edit) and is an error
naming the file and line. Imports no torch, so that the analysis commands stay quick.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

from gcnt.files import GiB, open_regular, too_deep

log = logging.getLogger(__name__)

#: (file, line number) of the incomplete last lines already warned about in this process
_warned: set[tuple[str, int]] = set()


class MetricsFileError(ValueError):
    """A ``metrics.jsonl`` line before the last one that is not a JSON object."""


def strict_json(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, ±inf) replaced by None, so that ``json.dumps``
    writes ``null`` (strict JSON has no ``NaN``); dicts, lists and tuples are copied."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict_json(v) for v in value]
    return value


def metrics_line(row: dict[str, Any]) -> str:
    """One ``metrics.jsonl`` line: strict JSON (non-finite values as ``null``), keys sorted."""
    return json.dumps(strict_json(row), sort_keys=True, allow_nan=False) + "\n"


def read_metrics_row(row: Any) -> Any:
    """A metrics row as read from JSON, with ``null`` values back as NaN (what was logged)."""
    if not isinstance(row, dict):
        return row
    return {k: math.nan if v is None else v for k, v in row.items()}


#: the largest metrics log read (a row per log interval: a paper-scale run writes a few MiB)
MAX_METRICS_BYTES = 4 * GiB
#: the longest metrics row read (a row of a few hundred robots' returns: tens of KiB)
MAX_LINE_BYTES = 1 << 20


def read_metrics(path: str | Path) -> list[dict[str, Any]]:
    """The rows of the metrics file ``path`` (none when it does not exist), ``null`` read as
    NaN, read a line at a time (a line longer than :data:`MAX_LINE_BYTES`, as a file of zeros
    is, is refused without reading the rest). An incomplete last line is dropped with a
    warning; a line before it that is not a JSON object raises MetricsFileError naming the
    file and line."""
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        return []
    what = "a metrics log is JSON lines"
    rows: list[dict[str, Any]] = []
    bad = 0  # the last line that was not a row (fatal once another line follows it)
    number = 0
    with open_regular(path, MAX_METRICS_BYTES, what, MetricsFileError) as f:
        while line := f.readline(MAX_LINE_BYTES + 1):
            number += 1
            if bad:
                raise MetricsFileError(
                    f"{path}, line {bad}: not a metrics row (the file is damaged; was it written "
                    "by two runs at once or edited?)"
                )
            if len(line) > MAX_LINE_BYTES:
                raise MetricsFileError(
                    f"{path}, line {number}: longer than {MAX_LINE_BYTES >> 20} MiB; {what}"
                )
            try:
                text = line.decode("utf-8")
            except UnicodeDecodeError:
                raise MetricsFileError(f"{path}, line {number}: not text; {what}") from None
            if not text.strip():
                continue
            try:
                row = json.loads(text)
            except (json.JSONDecodeError, RecursionError):
                row = None
            if isinstance(row, dict) and not too_deep(row):
                rows.append(read_metrics_row(row))
            else:
                bad = number
    if bad:
        _warn_incomplete(path, bad)
    return rows


def _warn_incomplete(path: Path, number: int) -> None:
    key = (str(path.resolve()), number)
    if key not in _warned:
        _warned.add(key)
        log.warning(
            "%s: line %d is incomplete (the run stopped while writing it); dropped", path, number
        )
