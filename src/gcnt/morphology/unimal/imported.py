"""UNIMAL catalogues imported from MetaMorph's published robot files (the paper's UNIMAL-100).

gcnt's own UNIMAL robots (``Unimal:*``) are generated from the DERL design space; the paper's
robots were evolved, and MetaMorph (github.com/agrimgupta92/metamorph) publishes them as
``unimals_100.zip`` (its README's data link). The archive unpacks to ``unimals_100/`` with one
folder per set: ``train/`` and ``test/`` and the variant sets ``dynamics/`` and ``kinematics/``,
each holding ``xml/<robot>.xml`` (the MuJoCo file), ``metadata/<robot>.json`` and
``unimal_init/<robot>.pkl`` (DERL's evolution records). A robot's split is the folder it is in.

:func:`import_unimals` reads that folder or the archive itself, checks every robot file (it must
load as a UNIMAL robot), and writes the catalogue folder ``<name>/`` into the user's robot-set
folder (``$GCNT_MORPHOLOGIES``, default ``~/.local/share/gcnt/morphologies``) or ``--out``:

* ``<name>/<set>/xml/<robot>.xml``: MetaMorph's files, byte for byte (gcnt reads neither the
  metadata nor the pickles, so they are not copied);
* ``<name>/catalogue.yaml``: the split file of the benchmark ``<name>``, with the splits
  ``train``, ``test``, ``variants-dynamics`` and ``variants-kinematics`` (the last two where the
  source has those folders);
* ``<name>/.gitignore``: the files have no licence that allows redistributing them, so git leaves
  the folder out of the repository.

The catalogue resolver finds the folder by its ``catalogue.yaml`` (``imported_catalogues`` in
``gcnt.morphology.catalogues``), so recipes and commands take ``Unimal100:train``,
``Unimal100:test``, ``Unimal100:variants-dynamics`` or a robot's own name. The robots are UNIMAL
benchmark robots (``Robot.catalogue == "unimal"``): every UNIMAL recipe, world and method runs them.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import re
import shutil
import zipfile
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from gcnt.data_folders import packaged_morphologies, user_morphologies
from gcnt.files import NotRegularFileError, open_lock, read_regular, write_bytes, write_text
from gcnt.morphology.catalogue_base import IMPORTED_INDEX
from gcnt.morphology.catalogues import (
    catalogue_names,
    get_catalogue,
    imported_catalogues,
    refresh_catalogues,
    split_keys,
)
from gcnt.morphology.robot import MAX_ROBOT_FILE_BYTES, robot_from_xml
from gcnt.morphology.unimal.catalogue import as_unimal
from gcnt.morphology.unimal.imported_set import DEFAULT_NAME, SETS, imported_catalogue

#: sets every import needs
REQUIRED_SETS = ("train", "test")
#: the archive's name as MetaMorph's README downloads it
ARCHIVE = "unimals_100.zip"
#: what a catalogue name and a robot name (a file name without ``.xml``) may be
_CATALOGUE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_+-]*")
_ROBOT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
_LAYOUT = (
    "MetaMorph's unimals_100 holds train/, test/, dynamics/ and kinematics/, each with "
    "xml/<robot>.xml"
)


log = logging.getLogger(__name__)


class UnimalImportError(ValueError):
    """A set of UNIMAL files that cannot be imported; the message names the file at fault."""


@dataclass(frozen=True)
class Member:
    """One robot file of the set being imported."""

    #: MetaMorph's set folder: train, test, dynamics or kinematics
    set: str
    #: the robot's name: the file name without ``.xml``
    name: str
    #: the file as the user can find it: a path, or ``archive.zip:member``
    where: str
    read: Callable[[], bytes]


@dataclass(frozen=True)
class ImportedSet:
    """What :func:`import_unimals` wrote: the catalogue folder and its splits."""

    folder: Path
    splits: dict[str, list[str]]

    @property
    def name(self) -> str:
        return self.folder.name


# ------------------------------------------------------------------------------ reading a set


def _set_root(path: Path) -> Path:
    """The folder of ``path`` that holds ``train/``: ``path`` itself or its one subfolder that
    does (``unimals_100/`` inside the folder the archive was unpacked in)."""
    if (path / "train").is_dir():
        return path
    inner = sorted(d for d in path.iterdir() if d.is_dir() and (d / "train").is_dir())
    if len(inner) > 1:
        raise UnimalImportError(
            f"{path}: holds several UNIMAL sets ({', '.join(d.name for d in inner)}); give one"
        )
    if not inner:
        raise UnimalImportError(f"{path}: no train/ folder; {_LAYOUT}")
    return inner[0]


def _folder_members(path: Path) -> list[Member]:
    root = _set_root(path)
    members: list[Member] = []
    for folder in SETS:
        xml = root / folder / "xml"
        if folder not in REQUIRED_SETS and not (root / folder).exists():
            continue
        if not xml.is_dir():
            raise UnimalImportError(f"{root}: no {folder}/xml/ folder; {_LAYOUT}")
        # hidden names left out: macOS's AppleDouble copies ._<robot>.xml are not robots
        files = sorted(p for p in xml.iterdir() if p.suffix == ".xml" and p.name[0] != ".")
        if not files:
            raise UnimalImportError(f"{xml}: no .xml robot files; {_LAYOUT}")
        for file in files:
            members.append(
                Member(
                    folder,
                    file.stem,
                    str(file),
                    lambda file=file: read_regular(
                        file, MAX_ROBOT_FILE_BYTES, "a robot file is MJCF XML", UnimalImportError
                    ),
                )
            )
    return members


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, where: str) -> bytes:
    if info.file_size > MAX_ROBOT_FILE_BYTES:
        raise UnimalImportError(f"{where}: {info.file_size} bytes, too large for a robot file")
    try:
        with archive.open(info) as f:
            data = f.read(MAX_ROBOT_FILE_BYTES + 1)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as e:  # a damaged archive
        raise UnimalImportError(f"{where}: cannot read it from the archive ({e})") from None
    except (RuntimeError, NotImplementedError) as e:  # encrypted, or compressed in another way
        raise UnimalImportError(
            f"{where}: cannot read it from the archive ({e}); unpack the archive and give the "
            "folder, or zip it again without a password"
        ) from None
    if len(data) > MAX_ROBOT_FILE_BYTES:
        raise UnimalImportError(f"{where}: too large for a robot file")
    return data


def _zip_members(path: Path, archive: zipfile.ZipFile) -> list[Member]:
    """The robot files ``[<root>/]<set>/xml/<robot>.xml`` of the archive (macOS's
    ``__MACOSX/`` copies left out); member names are never used as paths."""
    found: dict[str, list[tuple[str, zipfile.ZipInfo]]] = {}  # root -> (set, member)
    for info in archive.infolist():
        parts = PurePosixPath(info.filename).parts
        if info.is_dir() or not parts or parts[0] == "__MACOSX" or len(parts) < 3:
            continue
        if parts[-2] == "xml" and parts[-3] in SETS and parts[-1].endswith(".xml"):
            found.setdefault("/".join(parts[:-3]), []).append((parts[-3], info))
    if len(found) > 1:
        roots = ", ".join(f"{r or '(top level)'}" for r in sorted(found))
        raise UnimalImportError(f"{path}: holds several UNIMAL sets ({roots}); give one")
    if not found:
        raise UnimalImportError(f"{path}: no train/xml/*.xml files; {_LAYOUT}")
    root, entries = next(iter(found.items()))
    sets = {s for s, _ in entries}
    prefix = f"{root}/" if root else ""
    for required in REQUIRED_SETS:
        if required not in sets:
            raise UnimalImportError(f"{path}: no {prefix}{required}/xml/ files; {_LAYOUT}")
    members = []
    for folder in SETS:
        for s, info in sorted((e for e in entries if e[0] == folder), key=lambda e: e[1].filename):
            where = f"{path}:{info.filename}"
            name = PurePosixPath(info.filename).stem
            members.append(
                Member(
                    s,
                    name,
                    where,
                    lambda info=info, where=where: _read_member(archive, info, where),
                )
            )
    return members


@contextmanager
def read_set(path: str | Path) -> Iterator[list[Member]]:
    """The robot files of MetaMorph's set at ``path`` (the ``unimals_100`` folder, the folder it
    was unpacked in, or the ``.zip`` archive), readable inside the ``with`` block."""
    path = Path(path)
    if not path.exists():
        raise UnimalImportError(
            f"{path}: does not exist; give {ARCHIVE} or the folder it unpacks to"
        )
    if path.is_dir():
        yield _folder_members(path)
        return
    if not path.is_file() or not zipfile.is_zipfile(path):
        raise UnimalImportError(
            f"{path}: neither a folder nor a zip archive; give {ARCHIVE} as downloaded or the "
            "folder it unpacks to"
        )
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as e:
        raise UnimalImportError(f"{path}: cannot read the zip archive ({e})") from None
    with archive:
        yield _zip_members(path, archive)


def check_member(member: Member) -> bytes:
    """The file of ``member``, checked: a one-line error naming it unless it is a UNIMAL robot
    (standing alone: ``<include>`` and asset files are refused)."""
    if not _ROBOT_NAME.fullmatch(member.name):
        raise UnimalImportError(
            f"{member.where}: a robot file name must be letters, digits, '.', '_' and '-'"
        )
    data = member.read()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise UnimalImportError(
            f"{member.where}: not a text file (a robot file is MJCF XML)"
        ) from None
    as_unimal(robot_from_xml(text, source=member.where, name=member.name), member.where)
    return data


# ------------------------------------------------------------------------------ writing one


@dataclass
class Defined:
    """What a new catalogue in a morphologies folder must not reuse: gcnt's own catalogues and
    those already imported into that folder."""

    #: catalogue and benchmark names
    names: list[str]
    #: robot name -> its catalogue
    robots: dict[str, str]


def defined_in(out: Path) -> Defined:
    """The catalogue, benchmark and robot names defined for gcnt reading the robot-set folder
    ``out`` (beside its own robots and the sets imported among them)."""
    imported = imported_catalogues()
    cats = [get_catalogue(n) for n in catalogue_names() if n not in imported]
    for root in dict.fromkeys([packaged_morphologies(), Path(os.path.abspath(out))]):
        cats += [imported_catalogue(f) for f in imported_catalogues(root).values()]
    names: list[str] = []
    robots: dict[str, str] = {}
    for cat in cats:
        try:
            split = cat.split_path()
        except FileNotFoundError:
            split = None
        names += [cat.name, *split_keys(split)]
        for robot in cat.robot_names():
            robots.setdefault(robot, cat.name)
    return Defined(names, robots)


def check_name(name: str, out: Path, defined: Defined | None = None) -> None:
    """A UnimalImportError unless ``name`` can be a new catalogue and benchmark in ``out``."""
    if not _CATALOGUE_NAME.fullmatch(name):
        raise UnimalImportError(
            f"--name {name!r}: a catalogue name starts with a letter and has only letters, "
            "digits, '_', '+' and '-'"
        )
    folder = out / name
    if (folder / IMPORTED_INDEX).is_file():
        raise UnimalImportError(
            f"{folder}: already imported; remove the folder to import again, or give another --name"
        )
    taken = (defined or defined_in(out)).names
    clash = next((t for t in taken if t.lower() == name.lower()), None)
    if clash is not None:
        raise UnimalImportError(
            f"--name {name!r}: {clash!r} is already a catalogue or benchmark; give another --name"
        )
    if folder.exists():
        raise UnimalImportError(f"{folder}: already exists; give another --name")


def split_yaml(name: str, source: str, splits: dict[str, list[str]]) -> str:
    """The text of an imported catalogue's ``catalogue.yaml`` (a benchmark split file)."""
    lines = [
        "# MetaMorph's UNIMAL-100 robots (the paper's evolved robots), imported by",
        f"# `gcnt import-unimal` from {source}.",
        "# <set>/xml/<robot>.xml are MetaMorph's files, unchanged; a robot's split is the folder",
        "# MetaMorph put it in (dynamics/ -> variants-dynamics, kinematics/ -> variants-kinematics).",
        "",
        f"{name}:",
    ]
    for split, names in splits.items():
        lines.append(f"  {split}:")
        lines += [f"    - {n}" for n in names]
    return "\n".join(lines) + "\n"


def import_unimals(
    path: str | Path, name: str = DEFAULT_NAME, out: Path | None = None
) -> ImportedSet:
    """Import MetaMorph's set at ``path`` as the catalogue ``name`` into the robot-set folder
    ``out`` (default: the user's, :func:`gcnt.data_folders.user_morphologies`). Every file is
    checked before the folder appears: a bad file is a one-line error naming it, and nothing is
    left behind. One import into a folder at a time (a second is refused); SIGTERM ends it as
    Ctrl-C does, and the temporary folders of killed imports are removed."""
    out = Path(os.path.abspath(out)) if out is not None else user_morphologies()
    if out.exists() and not out.is_dir():
        raise UnimalImportError(
            f"--out {out}: not a folder; give the robot-set folder to import into"
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UnimalImportError(f"--out {out}: cannot create the folder ({e.strerror})") from None
    with _import_lock(out), _stop_on_sigterm():
        _remove_stale(out)
        return _import_into(path, name, out)


def _import_into(path: str | Path, name: str, out: Path) -> ImportedSet:
    defined = defined_in(out)
    check_name(name, out, defined)
    tmp = out / f"{_TMP_PREFIX.format(name=name)}{os.getpid()}"
    if tmp.is_symlink():  # the link itself goes, never what it points to
        tmp.unlink()
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()  # this import's own folder: every file is written below it
    splits: dict[str, list[str]] = {}
    origin: dict[str, list[str]] = {}
    try:
        with read_set(path) as members:
            for member in members:
                _check_other_catalogues(member, defined.robots)
                origin.setdefault(member.name, []).append(member.where)
                if len(origin[member.name]) > 1:
                    continue  # named with the others once every file was read
                data = check_member(member)
                dest = tmp / member.set / "xml" / f"{member.name}.xml"
                dest.parent.mkdir(parents=True, exist_ok=True)
                write_bytes(dest, data)
                splits.setdefault(SETS[member.set], []).append(member.name)
        _check_unique(origin)
        write_text(tmp / IMPORTED_INDEX, split_yaml(name, str(Path(path).resolve()), splits))
        write_text(
            tmp / ".gitignore",
            "# MetaMorph's robot files, imported by `gcnt import-unimal`: not part of the "
            "repository\n*\n",
        )
        tmp.rename(out / name)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    refresh_catalogues()
    return ImportedSet(out / name, splits)


#: the folder an import writes before it is renamed into place: ``.<name>.importing-<pid>``
_TMP_PREFIX = ".{name}.importing-"
_TMP = re.compile(r"^\.(?P<name>.+)\.importing-(?P<pid>[0-9]+)$")
#: the lock file of a morphologies folder being imported into
IMPORT_LOCK = ".import.lock"


@contextmanager
def _import_lock(out: Path) -> Iterator[None]:
    """One import into a morphologies folder at a time (a POSIX lock on ``IMPORT_LOCK``, which
    the kernel drops however the holder ends); a second one is a UnimalImportError. The holder
    removes the file when it is done (a file that was replaced meanwhile is locked afresh)."""
    import fcntl

    lock = out / IMPORT_LOCK
    while True:
        try:
            fd = open_lock(lock)  # never through a link, a FIFO or a device
        except NotRegularFileError as e:
            raise UnimalImportError(f"{e}; it is the folder's import lock") from None
        except OSError as e:
            raise UnimalImportError(
                f"{lock}: cannot create the import lock ({e.strerror})"
            ) from None
        try:
            fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            pid = os.pread(fd, 32, 0).decode(errors="replace").strip()
            os.close(fd)
            if e.errno not in (errno.EACCES, errno.EAGAIN):
                raise UnimalImportError(f"{lock}: cannot lock it ({e.strerror})") from None
            raise UnimalImportError(
                f"{out}: another gcnt import-unimal (process {pid or '?'}) is importing into this "
                "folder; wait for it to end, then run this one again"
            ) from None
        try:
            now = os.stat(lock)
        except FileNotFoundError:
            now = None
        held = os.fstat(fd)
        if now is not None and (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino):
            break
        os.close(fd)  # its holder removed it as this one opened it: lock the new file
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()
        os.close(fd)


@contextmanager
def _stop_on_sigterm() -> Iterator[None]:
    """SIGTERM ends the import as Ctrl-C does: the temporary folder is removed on the way out
    (the main thread only; elsewhere signals keep their handlers)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(f"stopped by {signal.Signals(signum).name}")

    old = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _remove_stale(out: Path) -> None:
    """Remove the temporary folders of imports into ``out`` whose process is gone (killed)."""
    for entry in out.iterdir():
        m = _TMP.match(entry.name)
        if m is None or not entry.is_dir() or entry.is_symlink():
            continue
        pid = int(m.group("pid"))
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            shutil.rmtree(entry, ignore_errors=True)
            log.info("removed %s, left by an import that was killed", entry)
        except PermissionError:
            pass  # another user's live process


def _check_unique(origin: dict[str, list[str]]) -> None:
    """A robot name is one robot: every name the set holds twice or more, with its files, in
    one line (``origin``: name -> the files of that name, in the order read)."""
    twice = {name: files for name, files in origin.items() if len(files) > 1}
    if twice:
        each = "; ".join(f"{name!r} ({', '.join(files)})" for name, files in twice.items())
        raise UnimalImportError(
            f"robot names given to more than one file ({len(twice)}): {each}; a robot name "
            "names one robot"
        )


def _check_other_catalogues(member: Member, robots: dict[str, str]) -> None:
    """A robot name of the set is not a robot of another catalogue (``robots``: name ->
    catalogue)."""
    other = robots.get(member.name)
    if other is not None:
        raise UnimalImportError(
            f"{member.where}: robot {member.name!r} is already a robot of catalogue {other!r}"
        )
