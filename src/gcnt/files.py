"""Reading files that someone else may have put there: a recipe, a robot file, a checkpoint, a
replay file, a metrics log. Each is opened without blocking (a FIFO does not wait for a writer,
so stop signals keep working), checked to be a regular file (not a FIFO, a device such as
``/dev/zero`` behind a symlink, a socket or a directory) of at most a size that fits what it
claims to be, and only then read. The refusal is the caller's own error type, one line naming
the file and never quoting it."""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

KiB, MiB, GiB = 1 << 10, 1 << 20, 1 << 30


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
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise error(f"{path}: larger than {_size(max_bytes)}; {what}")
    return data


def _size(n: int) -> str:
    for unit, scale in (("GiB", GiB), ("MiB", MiB), ("KiB", KiB)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"
