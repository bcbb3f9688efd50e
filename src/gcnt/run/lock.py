"""One writer per run directory: ``<run_dir>/.lock``, held by ``gcnt train`` for the run's life.

The lock is a POSIX record lock (``fcntl.lockf``) on the file, chosen over ``flock`` because

* the kernel drops it when the holding process ends, however it ends (SIGKILL and OOM included),
  and it is not inherited by forked children (collector workers), so a dead trainer never leaves
  a stale lock behind on its own host;
* NFS forwards POSIX locks to the server (NLM, or NFSv4's own locking), and Lustre honours them
  when mounted with ``-o flock``, so a writer on another node is seen too; a node that crashed
  loses its locks when the server's lease for it expires.

The file also holds the holder's host, pid and start time, for the message a second writer gets.
Where the file system cannot lock at all (``ENOLCK``/``EOPNOTSUPP``), that holder record alone
decides: a holder on this host whose pid is gone is stale and taken over; one on another host is
trusted.

A POSIX lock is released when its process closes *any* descriptor of the file, so this process
never opens the lock file of a run it holds a second time (:data:`_HELD`).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import fcntl
import os
import socket
from dataclasses import dataclass
from pathlib import Path

from gcnt.files import NotRegularFileError, open_lock

LOCK_FILE = ".lock"

#: resolved run directory -> this process's open descriptor of its lock file
_HELD: dict[Path, int] = {}
_NO_LOCKING = (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS)


class RunDirError(ValueError):
    """A run directory that cannot be made or written (a file in the way, no permission)."""


class RunBusyError(FileExistsError):
    """Another process is training the run directory (a FileExistsError, as for a run directory
    that already holds another run; this module imports nothing heavy, for ``gcnt sweep``)."""


@dataclass(frozen=True)
class Holder:
    host: str
    pid: int
    since: str

    def __str__(self) -> str:
        return f"process {self.pid} on {self.host} (since {self.since})"

    def alive(self) -> bool:
        """Whether the holder may be alive: any holder on another host, a live pid on this one."""
        if self.host != socket.gethostname():
            return True
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:  # another user's live process
            return True
        return True


def _read_holder(fd: int) -> Holder | None:
    try:
        text = os.pread(fd, 4096, 0).decode(errors="replace").split()
        return Holder(text[0], int(text[1]), text[2])
    except (OSError, IndexError, ValueError):
        return None


def _try_lock(fd: int) -> bool | None:
    """True: locked; False: another process holds it; None: the file system cannot lock."""
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
        if e.errno in (errno.EACCES, errno.EAGAIN):
            return False
        if e.errno in _NO_LOCKING:
            return None
        raise
    return True


def holder(run_dir: str | Path) -> Holder | None:
    """Who trains ``run_dir`` now (None: nobody); takes no lock."""
    path = Path(run_dir).resolve()
    if path in _HELD:
        return _read_holder(_HELD[path])
    lock = path / LOCK_FILE
    if not lock.exists() and not lock.is_symlink():
        return None
    try:
        fd = open_lock(lock)
    except OSError:  # unreadable, or not a regular file: the writer will find out itself
        return None
    try:
        got = _try_lock(fd)
        record = _read_holder(fd)
        if got is None:
            return record if record is not None and record.alive() else None
        return None if got else record or Holder("?", 0, "?")
    finally:
        os.close(fd)  # also drops the probe's own lock, if it got one


@contextlib.contextmanager
def run_lock(run_dir: str | Path):
    """Hold ``run_dir``'s lock (creating the directory) while the block runs; a
    :class:`RunBusyError` naming the holder when another process has it."""
    path = Path(run_dir).resolve()
    if path in _HELD:  # this process already trains it (nested use)
        yield
        return
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunDirError(
            f"run_dir {run_dir}: cannot create the run directory ({e.strerror or e})"
        ) from None
    try:
        fd = open_lock(path / LOCK_FILE)  # never through a link, a FIFO or a device
    except NotRegularFileError as e:
        raise RunDirError(f"{e}; it is the run's lock file ({LOCK_FILE})") from None
    except OSError as e:
        raise RunDirError(
            f"run_dir {run_dir}: cannot create its lock file ({e.strerror or e})"
        ) from None
    try:
        got = _try_lock(fd)
        if not got:
            record = _read_holder(fd)
            if got is False or (record is not None and record.alive()):
                raise RunBusyError(
                    f"{run_dir} is being trained by "
                    f"{record if record is not None else 'another process'}; "
                    "wait for it to end or stop it (one writer per run directory)"
                )
        since = _dt.datetime.now().isoformat(timespec="seconds")
        record = f"{socket.gethostname()} {os.getpid()} {since}\n".encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, record, 0)
    except BaseException:
        os.close(fd)
        raise
    _HELD[path] = fd
    try:
        yield
    finally:
        del _HELD[path]
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)  # no holder left to name
        os.close(fd)  # releases the lock


@contextlib.contextmanager
def run_locks(run_dirs: list[str | Path]):
    """Hold the locks of several run directories (``gcnt train --seeds``)."""
    with contextlib.ExitStack() as stack:
        for d in run_dirs:
            stack.enter_context(run_lock(d))
        yield
