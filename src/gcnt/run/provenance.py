"""What made a run or a sweep: the code (gcnt version, git commit, uncommitted changes), the
packages, the machine and the command line, one entry per session.

``gcnt train`` writes ``provenance.json`` in the run directory when a run starts and adds an
entry each time it is resumed (``{"sessions": [...]}``, oldest first), so that each session's
code is known; a sweep's manifest holds the same list under ``provenance``. Figures and tables
name the code of the runs they show in a caption (:func:`caption`).

The git state comes from the checkout that holds the imported ``gcnt`` package (never the
working folder). A package installed from a wheel or sdist built from a git checkout names the
commit it was built from (``gcnt/_build.json``, written by the build: ``setup.py``; ``git_note``
says so); one without that file has no commit (``git_commit`` None), and a missing git binary
or a git failure never stops a run (None, with the reason in ``git_note``). ``git_dirty``
counts changes to tracked files only (as ``git describe --dirty``).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import importlib.metadata
import json
import logging
import os
import platform
import socket
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import gcnt
from gcnt import plugins
from gcnt.files import KiB, MiB, read_json, read_text, rename, write_text

log = logging.getLogger(__name__)

PROVENANCE_FILE = "provenance.json"

#: the packages whose versions each session records
PACKAGES = ("torch", "torchrl", "tensordict", "mujoco", "dm_control", "numpy", "wandb")

#: the largest provenance.json read (a session is about 1 KiB)
MAX_BYTES = 16 * MiB

_command: list[str] | None = None


class ProvenanceError(ValueError):
    """A provenance file that cannot be read; the message names it."""


def set_command(argv: Sequence[str]) -> None:
    """The command line sessions record (the ``gcnt`` command sets its own; otherwise
    ``sys.argv``)."""
    global _command
    _command = list(argv)


def collect(argv: Sequence[str] | None = None, *, repo: str | Path | None = None) -> dict[str, Any]:
    """This process's session: gcnt version, git state of ``repo`` (default: the checkout
    holding the gcnt package, if any), Python, package versions, platform, the host (a hash of
    its name: whether sessions ran on one machine, not which), CUDA (when torch is loaded),
    ``argv`` (default: the command line), and the plugins imported (:mod:`gcnt.plugins`: each
    one's name, sha256 and where it was named). A run directory is handed on with this
    record: no folder of this machine (working folder, Python executable, plugin files) and no
    host name is in it."""
    git = git_state(repo)
    return {
        "gcnt_version": gcnt.__version__,
        "git_commit": git["commit"],
        "git_dirty": git["dirty"],
        "git_note": git["note"],
        "python": platform.python_version(),
        "packages": {name: _version(name) for name in PACKAGES},
        "platform": platform.platform(),
        "host": host_hash(),
        "cuda": _cuda(),
        "command": list(argv if argv is not None else (_command or sys.argv)),
        "plugins": plugins.identities(via=True),
        "started": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
    }


def host_hash(name: str | None = None) -> str:
    """The first 16 hex digits of the sha256 of a host name (default: this machine's)."""
    return hashlib.sha256((name or socket.gethostname()).encode()).hexdigest()[:16]


#: seconds a query of gcnt's own checkout is reused: the runs one process starts together
#: (``gcnt train --seeds``) ask git once, not three times per run
GIT_CACHE_S = 60.0
_package_git: dict[tuple[str, str | None], tuple[float, dict[str, Any]]] = {}


def git_state(repo: str | Path | None = None) -> dict[str, Any]:
    """``{"commit", "dirty", "note"}`` of ``repo``, or of the checkout whose tracked files
    include the imported gcnt package (asked again after :data:`GIT_CACHE_S`); commit and dirty
    are None where unknown, and ``note`` says why."""
    if repo is not None:
        return _git_state(repo)
    key = (gcnt.__file__, os.environ.get("PATH"))  # where gcnt is, and which git answers
    now = time.monotonic()
    cached = _package_git.get(key)
    if cached is None or now - cached[0] > GIT_CACHE_S:
        cached = _package_git[key] = (now, _git_state(None))
    return dict(cached[1])


def _git_state(repo: str | Path | None) -> dict[str, Any]:
    try:
        if repo is None:
            package = Path(gcnt.__file__).resolve()
            # the folder may lie inside some other checkout (a virtual environment in a
            # project): only a checkout that tracks the package's own file counts
            try:
                tracked = _git(package.parent, "ls-files", "--", package.name)
            except subprocess.CalledProcessError as e:
                if "not a git repository" not in (e.stderr or ""):
                    raise
                tracked = ""
            if not tracked.strip():
                return _built("the gcnt package is not in a git checkout")
            repo = package.parent
        commit = _git(repo, "rev-parse", "HEAD").strip()
        changes = _git(repo, "status", "--porcelain", "--untracked-files=no")
    except FileNotFoundError:
        return _built("git is not installed", repo)
    except subprocess.CalledProcessError as e:
        why = (e.stderr or "").strip().splitlines()
        return _built(f"git failed: {why[-1] if why else f'exit code {e.returncode}'}", repo)
    except (subprocess.TimeoutExpired, OSError) as e:
        return _built(f"git failed: {e}", repo)
    return {"commit": commit, "dirty": bool(changes.strip()), "note": None}


#: the file a build of the package (wheel, sdist) writes beside ``gcnt/__init__.py``:
#: ``{"commit", "dirty"}`` of the checkout it was built from (``setup.py``)
BUILD_FILE = "_build.json"


def _built(why: str, repo: str | Path | None = None) -> dict[str, Any]:
    """Where git cannot tell the package's commit: the one its build recorded
    (:data:`BUILD_FILE`), else unknown because ``why``. Only for gcnt's own package (``repo``
    None), never for a repository asked about."""
    path = Path(gcnt.__file__).resolve().parent / BUILD_FILE
    if repo is not None or not path.is_file():
        return _unknown(why)
    unreadable = _unknown(f"{why}; gcnt's {BUILD_FILE} names no commit")
    try:
        data = read_json(path, 64 * KiB, "the commit a build of gcnt came from", ValueError)
    except ValueError:
        return unreadable
    commit, dirty = (data.get("commit"), data.get("dirty")) if isinstance(data, dict) else (0, 0)
    if not (isinstance(commit, str) and commit.strip() and isinstance(dirty, bool)):
        return unreadable
    return {"commit": commit.strip(), "dirty": dirty, "note": "recorded by the build of gcnt"}


def _git(where: str | Path, *args: str) -> str:
    # no optional locks: a run never contends with git commands someone runs in the checkout
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}
    return subprocess.run(
        ["git", "-C", str(where), *args],
        capture_output=True,
        text=True,
        timeout=30,
        check=True,
        env=env,
    ).stdout


def _unknown(note: str) -> dict[str, Any]:
    return {"commit": None, "dirty": None, "note": note}


def tested_versions() -> dict[str, str]:
    """The exact version of each package gcnt is tested with (its shipped ``constraints.txt``;
    the development tools after its ``# dev`` line are left out)."""
    from gcnt.data_folders import tested_versions_file

    out: dict[str, str] = {}
    text = read_text(tested_versions_file(), 64 * KiB, "gcnt's tested versions", ValueError)
    for line in text.splitlines():
        if line.strip() == "# dev":
            break
        name, sep, version = line.split("#")[0].strip().partition("==")
        if sep:
            out[name] = version
    return out


def versions_report() -> str:
    """``gcnt --version --verbose``: gcnt's version, then per package the version tested and
    the one installed here (flagged where they differ), and how to install the tested ones."""
    from gcnt import __version__
    from gcnt.data_folders import tested_versions_file

    lines = [f"gcnt {__version__}", "package        tested     here"]
    for name, tested in tested_versions().items():
        here = _version(name) or "missing"
        same = here.split("+")[0] == tested  # torch's local build tag (+cpu, +cu128) aside
        lines.append(f"{name:<15}{tested:<11}{here}{'' if same else '  (differs)'}")
    lines.append(
        f"the tested versions as pip constraints: {tested_versions_file()} (pip install -c "
        "FILE ...; torch first, the build for your platform: README, Set-up)"
    )
    return "\n".join(lines)


def _version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def _cuda() -> dict[str, Any] | None:
    """torch's CUDA version and the device in use; None where torch is not loaded (a sweep's
    own process: its runs record theirs). CUDA is not initialised for this: the device name
    is known once the run has put something on it."""
    torch = sys.modules.get("torch")
    if torch is None:
        return None
    device = None
    if torch.cuda.is_initialized():
        device = torch.cuda.get_device_name(torch.cuda.current_device())
    return {"version": torch.version.cuda, "device": device}


# --- files


def read_sessions(run_dir: str | Path) -> list[dict[str, Any]]:
    """The sessions of a run directory's ``provenance.json``; an empty list where there is
    none; a ProvenanceError naming it where it cannot be read."""
    path = Path(run_dir) / PROVENANCE_FILE
    if not path.exists():
        return []
    what = "provenance.json is the file gcnt train writes"
    data = read_json(path, MAX_BYTES, what, ProvenanceError)
    sessions = data.get("sessions") if isinstance(data, dict) else None
    if not isinstance(sessions, list) or not all(isinstance(s, dict) for s in sessions):
        raise ProvenanceError(f"{path}: no list of sessions; {what}")
    return sessions


def add_session(run_dir: str | Path, session: dict[str, Any] | None = None) -> Path:
    """Append ``session`` (default: :func:`collect`) to ``<run_dir>/provenance.json``,
    atomically. A file that cannot be read is kept as ``provenance.json.unreadable`` (with a
    warning) and a new list begun: a run never stops over it."""
    path = Path(run_dir) / PROVENANCE_FILE
    try:
        sessions = read_sessions(run_dir)
    except ProvenanceError as e:
        aside = path.with_name(PROVENANCE_FILE + ".unreadable")
        rename(path, aside)
        log.warning("%s; kept as %s, a new list of sessions begins", e, aside)
        sessions = []
    sessions.append(session if session is not None else collect())
    write_text(path, json.dumps({"sessions": sessions}, indent=1) + "\n")
    return path


# --- captions


def code_label(session: dict[str, Any]) -> str:
    """``abc1234`` (the short commit), ``abc1234-dirty``, or ``unknown`` (not a git checkout,
    or git failed)."""
    commit = session.get("git_commit")
    if not commit:
        return "unknown"
    return f"{str(commit)[:7]}{'-dirty' if session.get('git_dirty') else ''}"


def caption(run_dirs: Iterable[str | Path]) -> str:
    """One line naming the gcnt versions and commits of the runs in ``run_dirs``, e.g.
    ``runs from gcnt 0.1.0 at commit abc1234 (3 runs), def5678-dirty (1 run)``. A run resumed
    at other code counts under all of them joined (``abc1234+def5678``); runs without a
    readable ``provenance.json`` are counted as ``provenance not recorded``."""
    versions: set[str] = set()
    labels: Counter[str] = Counter()
    missing = 0
    for run_dir in run_dirs:
        try:
            sessions = read_sessions(run_dir)
        except ProvenanceError as e:
            log.warning("%s", e)
            sessions = []
        if not sessions:
            missing += 1
            continue
        for s in sessions:
            versions.add(str(s.get("gcnt_version") or "?"))
        labels["+".join(dict.fromkeys(code_label(s) for s in sessions))] += 1
    parts = []
    if labels:
        counts = sorted(labels.items(), key=lambda kv: (-kv[1], kv[0]))  # the most runs first
        at = ", ".join(f"{label} ({_n(n, 'run')})" for label, n in counts)
        parts.append(f"runs from gcnt {', '.join(sorted(versions))} at commit {at}")
    if missing:
        parts.append(f"provenance not recorded ({_n(missing, 'run')})")
    return "; ".join(parts) or "no runs"


def this_code(what: str) -> str:
    """A caption for output this process computes itself (no runs): ``<what> from gcnt 0.1.0
    at commit abc1234``."""
    git = git_state()
    label = code_label({"git_commit": git["commit"], "git_dirty": git["dirty"]})
    return f"{what} from gcnt {gcnt.__version__} at commit {label}"


def _n(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def write_caption(text: str, path: str | Path) -> Path:
    """Write a caption (:func:`caption`, :func:`this_code`) to ``path``, one line."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, text + "\n")
    return path
