"""Reading files that someone else may have put there: a recipe, a robot file, a checkpoint, a
replay file, a metrics log. Each is opened without blocking (a FIFO does not wait for a writer,
so stop signals keep working), checked to be a regular file (not a FIFO, a device such as
``/dev/zero`` behind a symlink, a socket or a directory) of at most a size that fits what it
claims to be, and only then read. The refusal is the caller's own error type, one line naming
the file and never quoting it."""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Iterable
from pathlib import Path
from typing import Any, BinaryIO

KiB, MiB, GiB = 1 << 10, 1 << 20, 1 << 30
#: the most read at once
_CHUNK = 4 * MiB
#: how deep lists and mappings of a YAML or JSON file gcnt reads may nest
MAX_DEPTH = 100
_TOO_DEEP = object()


def open_regular(path: str | Path, max_bytes: int, what: str, error: type[Exception]) -> BinaryIO:
    """``path`` opened for binary reading, if it is a regular file of at most ``max_bytes``;
    else ``error("<path>: <why>; <what>")``. ``what`` says what the file should be (e.g. "a
    robot file is MJCF XML"). An OSError while opening is ``error`` too."""
    try:
        # O_NONBLOCK: opening a FIFO does not wait for a writer; fstat then refuses it
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as e:
        raise error(f"{path}: cannot read ({e.strerror}); {what}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
            raise error(f"{path}: {kind}; {what}")
        if st.st_size > max_bytes:
            raise error(f"{path}: {_size(st.st_size)}, larger than {_size(max_bytes)}; {what}")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return open(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular(path: str | Path, max_bytes: int, what: str, error: type[Exception]) -> bytes:
    """The bytes of ``path`` after :func:`open_regular`'s checks (a file that grew past
    ``max_bytes`` while being read is refused too)."""
    with open_regular(path, max_bytes, what, error) as f:
        # what is there, in chunks: a cap of GiBs reserves nothing for a file of a few bytes
        size = os.fstat(f.fileno()).st_size
        chunks: list[bytes] = []
        total = 0
        while True:
            chunk = f.read(min(max(size - total, 0) + 1, _CHUNK, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:
                raise error(f"{path}: larger than {_size(max_bytes)}; {what}")
    return b"".join(chunks)


def read_text(path: str | Path, max_bytes: int, what: str, error: type[Exception]) -> str:
    """The text of ``path`` (UTF-8) after :func:`read_regular`; bytes that are not UTF-8 are
    ``error`` too."""
    try:
        return read_regular(path, max_bytes, what, error).decode("utf-8")
    except UnicodeDecodeError:
        raise error(f"{path}: not UTF-8 text; {what}") from None


def too_deep(value: Any, limit: int = MAX_DEPTH) -> bool:
    """Whether lists and mappings in ``value`` nest deeper than ``limit`` (walked without
    recursion, so that the check itself cannot overflow the stack)."""
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            children: Iterable[Any] = [*item.keys(), *item.values()]
        elif isinstance(item, (list, tuple)):
            children = item
        else:
            continue
        if depth > limit:
            return True
        stack.extend((c, depth + 1) for c in children)
    return False


def parse_json(text: str | bytes, path: str | Path, what: str, error: type[Exception]) -> Any:
    """``text`` read as JSON; malformed or nested deeper than :data:`MAX_DEPTH` is ``error``
    naming ``path``."""
    try:
        value = json.loads(text)
    except RecursionError:
        value = _TOO_DEEP
    except (ValueError, UnicodeDecodeError) as e:
        raise error(f"{path}: not valid JSON ({e}); {what}") from None
    if value is _TOO_DEEP or too_deep(value):
        raise error(f"{path}: nested deeper than {MAX_DEPTH} levels; {what}")
    return value


def parse_yaml(
    text: str | bytes, path: str | Path, what: str, error: type[Exception], loader: Any = None
) -> Any:
    """``text`` read as YAML (``loader``, default ``yaml.SafeLoader``); malformed or nested
    deeper than :data:`MAX_DEPTH` is ``error`` naming ``path``."""
    import yaml

    try:
        value = yaml.load(text, Loader=loader or yaml.SafeLoader)
    except RecursionError:
        value = _TOO_DEEP
    except yaml.YAMLError as e:
        problem = getattr(e, "problem", None) or type(e).__name__
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise error(f"{path}: not valid YAML ({problem}{where}); {what}") from None
    if value is _TOO_DEEP or too_deep(value):
        raise error(f"{path}: nested deeper than {MAX_DEPTH} levels; {what}")
    return value


def read_json(path: str | Path, max_bytes: int, what: str, error: type[Exception]) -> Any:
    """The JSON value of ``path``, read by :func:`read_regular` and :func:`parse_json`."""
    return parse_json(read_regular(path, max_bytes, what, error), path, what, error)


def read_yaml(path: str | Path, max_bytes: int, what: str, error: type[Exception]) -> Any:
    """The YAML value of ``path`` (safe loader), read by :func:`read_text` and
    :func:`parse_yaml`."""
    return parse_yaml(read_text(path, max_bytes, what, error), path, what, error)


def write_text(path: str | Path, text: str) -> None:
    """``Path(path).write_text(text)``, whose OSError names ``path`` even when the write
    itself fails (a full disk fails in ``write``, and such an error names no file)."""
    write_bytes(path, text.encode("utf-8"))


def write_bytes(path: str | Path, data: bytes) -> None:
    """``Path(path).write_bytes(data)``; an OSError names ``path`` (see :func:`write_text`)."""
    try:
        Path(path).write_bytes(data)
    except OSError as e:
        if e.filename is None:
            e.filename = str(path)
        raise


def _size(n: int) -> str:
    for unit, scale in (("GiB", GiB), ("MiB", MiB), ("KiB", KiB)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"
