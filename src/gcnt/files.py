"""Reading files that someone else may have put there: a recipe, a robot file, a checkpoint, a
replay file, a metrics log. Each is opened without blocking (a FIFO does not wait for a writer,
so stop signals keep working), checked to be a regular file (not a FIFO, a device such as
``/dev/zero`` behind a symlink, a socket or a directory) of at most a size that fits what it
claims to be, and only then read. The refusal is the caller's own error type, one line naming
the file and never quoting it.

Writing files into folders someone else may have prepared: every file gcnt writes is first a
temporary file created exclusively in the target's folder (never through a link), which
replaces the target only where that is absent or a regular file; logs and lock files are
opened without following a link or waiting on a FIFO, and refused unless regular. What is
refused is a :class:`NotRegularFileError`: nothing is written through a link or onto a
device, a FIFO or a folder that gcnt did not make."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
import shutil
import stat
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO, TextIO

import yaml

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


#: the most YAML nodes a document gcnt reads may hold once its aliases are expanded (a recipe,
#: a run's recorded recipe, a sweep's)
MAX_YAML_NODES = 100_000


class CappedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` whose anchors and aliases are allowed (PyYAML's dumper writes them for
    repeated values), but a document whose aliases would expand beyond :data:`MAX_YAML_NODES`
    nodes, or refer to themselves, is refused as soon as it is composed, before any object is
    built: an alias bomb costs nothing."""

    def compose_document(self):
        node = super().compose_document()
        _expanded_size(node, {}, set())
        return node


def _expanded_size(node: yaml.Node, sizes: dict[int, int], open_: set[int]) -> int:
    """The number of nodes of ``node`` with every alias expanded (each shared node counted once
    per use, computed once); a yaml.MarkedYAMLError past :data:`MAX_YAML_NODES`."""
    key = id(node)
    if key in sizes:
        return sizes[key]
    if key in open_:
        raise yaml.MarkedYAMLError(
            problem="an alias refers to the value that contains it", problem_mark=node.start_mark
        )
    open_.add(key)
    if isinstance(node, yaml.SequenceNode):
        size = 1 + sum(_expanded_size(c, sizes, open_) for c in node.value)
    elif isinstance(node, yaml.MappingNode):
        size = 1 + sum(
            _expanded_size(k, sizes, open_) + _expanded_size(v, sizes, open_) for k, v in node.value
        )
    else:
        size = 1
    open_.discard(key)
    if size > MAX_YAML_NODES:
        raise yaml.MarkedYAMLError(
            problem=f"its aliases expand to more than {MAX_YAML_NODES} values",
            problem_mark=node.start_mark,
        )
    sizes[key] = size
    return size


def parse_yaml(
    text: str | bytes, path: str | Path, what: str, error: type[Exception], loader: Any = None
) -> Any:
    """``text`` read as YAML (``loader``, default :class:`CappedLoader`: a safe loader that
    refuses an alias bomb); malformed, expanding past :data:`MAX_YAML_NODES` values or nested
    deeper than :data:`MAX_DEPTH` is ``error`` naming ``path``."""
    try:
        value = yaml.load(text, Loader=loader or CappedLoader)
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


# --- writing


class NotRegularFileError(FileExistsError):
    """Something other than a regular file (a link, a FIFO, a device, a folder) is where gcnt
    would write: it is neither written through nor replaced. An OSError (``strerror`` says
    what is there), a FileExistsError for the CLI: one line, exit 2."""

    def __init__(self, path: str | Path, kind: str):
        super().__init__(errno.EEXIST, f"{kind}, not a regular file", str(path))
        self.kind = kind

    def __str__(self) -> str:
        return (
            f"{self.filename}: {self.kind}, not a regular file; gcnt neither writes through "
            "nor replaces it (remove it, or give another path)"
        )


class HardLinkError(NotRegularFileError):
    """A file with other names (a hard link: ``st_nlink`` > 1) where gcnt would write into
    the file itself (a lock, a log): writing would change the file under its other names too,
    wherever they are. It is neither written nor replaced."""

    def __init__(self, path: str | Path, names: int):
        super().__init__(path, f"a hard link (a file with {names} names)")

    def __str__(self) -> str:
        return (
            f"{self.filename}: {self.kind}; gcnt does not write into a file that has other "
            "names, which would change them too (remove it, or give another path)"
        )


def _kind(mode: int) -> str:
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def check_replaceable(path: str | Path) -> None:
    """A :class:`NotRegularFileError` unless ``path`` is absent or a regular file (not
    following a link: a link itself is refused)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISREG(st.st_mode):
        raise NotRegularFileError(path, _kind(st.st_mode))


#: flags of every file gcnt creates or opens to write: a link is never followed, a FIFO never
#: waited on, a descriptor never inherited by a child process
_NEW = os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
_OPEN = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)


_TMP = ".tmp-"


def _create_temp(path: Path) -> tuple[int, Path]:
    """A new, empty file beside ``path`` (in its folder), created exclusively under a name no
    other process uses (``.tmp-<pid>-<random>.<name>``: the suffix kept for writers that go by
    it), and its descriptor."""
    for _ in range(100):
        tmp = path.with_name(f"{_TMP}{os.getpid()}-{secrets.token_hex(4)}.{path.name}")
        try:
            return os.open(tmp, os.O_WRONLY | _NEW, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(path))


def _name_errors(path: str | Path, e: OSError) -> OSError:
    if e.filename is None or Path(e.filename).name.startswith(_TMP):
        e.filename = str(path)  # the target, not the temporary file, is what failed
    return e


@contextlib.contextmanager
def temp_path(path: str | Path) -> Iterator[Path]:
    """A temporary file for ``path``, created exclusively in its folder, for a writer that
    takes a path (a video encoder): once the block ends without error it replaces ``path``
    (only an absent or regular file, :func:`check_replaceable`), else it is removed. An
    OSError names ``path``."""
    path = Path(path)
    check_replaceable(path)
    try:
        fd, tmp = _create_temp(path)
        os.close(fd)
    except OSError as e:
        raise _name_errors(path, e) from None
    try:
        yield tmp
        check_replaceable(path)
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(e, OSError):
            raise _name_errors(path, e) from None
        raise


@contextlib.contextmanager
def writing(path: str | Path) -> Iterator[BinaryIO]:
    """A binary file to write ``path``'s new content into, atomically: a temporary file
    created exclusively in ``path``'s folder (never through a link), which replaces ``path``
    (only an absent or regular file) once the block ends without error; on an error it is
    removed and ``path`` is kept as it was. An OSError names ``path``."""
    with temp_path(path) as tmp:
        fd = os.open(tmp, os.O_WRONLY | _OPEN)
        with open(fd, "wb") as f:
            yield f


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:func:`writing`)."""
    with writing(path) as f:
        f.write(data)


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`writing`)."""
    write_bytes(path, text.encode("utf-8"))


def save_torch(obj: Any, path: str | Path) -> None:
    """``torch.save(obj)`` to ``path`` atomically (:func:`writing`)."""
    import torch

    with writing(path) as f:
        try:
            torch.save(obj, f)
        except RuntimeError as e:  # torch's writer reports a failed write (a full disk) so
            if "write" not in str(e):
                raise
            full = shutil.disk_usage(Path(path).parent).free < (1 << 20)
            code = errno.ENOSPC if full else errno.EIO
            raise OSError(code, os.strerror(code), str(path)) from None


def rename(src: str | Path, dst: str | Path) -> None:
    """Move ``src`` to ``dst`` (same folder), which must be absent or a regular file."""
    check_replaceable(dst)
    os.replace(src, dst)


def _open_existing_or_new(path: str | Path, flags: int) -> int:
    """A descriptor of the regular file ``path`` (created if absent), opened with ``flags``
    without following a link or waiting on a FIFO; else a :class:`NotRegularFileError` (a
    :class:`HardLinkError` for a file with other names: what is written into it, they get
    too)."""
    try:
        fd = os.open(path, flags | os.O_CREAT | _OPEN, 0o666)
    except OSError as e:
        if e.errno in (errno.ELOOP, errno.ENXIO, errno.EISDIR, errno.EMLINK):
            check_replaceable(path)
        raise _name_errors(path, e) from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise NotRegularFileError(path, _kind(st.st_mode))
    if st.st_nlink > 1:
        os.close(fd)
        raise HardLinkError(path, st.st_nlink)
    os.set_blocking(fd, True)
    return fd


def open_lock(path: str | Path) -> int:
    """A read-write descriptor of the lock file ``path`` (created if absent), which must be a
    regular file of its own: a link, a FIFO, a device or a file with other names (a hard link)
    is a :class:`NotRegularFileError`, nothing is opened through it or truncated."""
    return _open_existing_or_new(path, os.O_RDWR)


def open_append(path: str | Path) -> TextIO:
    """``path`` opened to append UTF-8 text to (created if absent: a log), a regular file only
    (see :func:`open_lock`)."""
    return open(_open_existing_or_new(path, os.O_WRONLY | os.O_APPEND), "a", encoding="utf-8")


def append_text(path: str | Path, text: str) -> None:
    """Append ``text`` to ``path`` (:func:`open_append`); an OSError (a full disk at the write
    or the flush) names ``path``."""
    try:
        with open_append(path) as f:
            f.write(text)
    except OSError as e:
        raise _name_errors(path, e) from None


def check_output(path: str | Path) -> None:
    """A :class:`NotRegularFileError` where :func:`write_output` would refuse ``path`` by its
    kind (a folder, a socket): checked before the work whose output it is."""
    try:
        st = os.stat(path)
    except OSError:
        return
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISCHR(st.st_mode) or stat.S_ISFIFO(st.st_mode)):
        raise NotRegularFileError(path, _kind(st.st_mode))


def write_output(path: str | Path, data: bytes) -> None:
    """Write ``data`` to an output the user named: a regular file (or an absent one) is
    written atomically, through the links the user gave (:func:`writing` at the real path); a
    device or a FIFO with a reader is written into (``/dev/null``, ``/dev/stdout``); anything
    else (a folder, a socket, a FIFO that nobody reads) is a :class:`NotRegularFileError`.
    Nothing but a regular file is ever replaced."""
    real = Path(os.path.realpath(path))
    try:
        st = os.stat(real)
    except FileNotFoundError:
        st = None
    if st is None or stat.S_ISREG(st.st_mode):
        write_bytes(real, data)
        return
    if not (stat.S_ISCHR(st.st_mode) or stat.S_ISFIFO(st.st_mode)):
        raise NotRegularFileError(path, _kind(st.st_mode))
    try:
        fd = os.open(real, os.O_WRONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        if e.errno == errno.ENXIO:  # a FIFO with no reader
            raise NotRegularFileError(path, "a FIFO that nobody reads") from None
        raise _name_errors(path, e) from None
    os.set_blocking(fd, True)
    with open(fd, "wb") as f:
        f.write(data)


def _size(n: int) -> str:
    for unit, scale in (("GiB", GiB), ("MiB", MiB), ("KiB", KiB)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"
