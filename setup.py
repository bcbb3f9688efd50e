"""The build of gcnt records the git commit it was built from (all else is in pyproject.toml).

A wheel or sdist built from a git checkout carries ``gcnt/_build.json``: ``{"commit", "dirty"}``
(HEAD, and whether tracked files had uncommitted changes), which :mod:`gcnt.run.provenance` reads
where the installed package is not in a git checkout. An sdist carries the file in its source
tree, so that a wheel built from it keeps the commit. Built without git (or from a folder git
does not track), nothing is written and a run's commit stays unknown.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

ROOT = Path(__file__).resolve().parent
#: the file, inside the package, that names the commit a build came from
BUILD_FILE = "_build.json"


def _git(*args: str) -> str:
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}
    return subprocess.run(
        ["git", "-C", str(ROOT), *args],
        capture_output=True, text=True, timeout=30, check=True, env=env,
    ).stdout  # fmt: skip


def build_record() -> str | None:
    """The text of ``_build.json`` for this checkout; None where git cannot tell (no git, not
    a checkout, or one that does not track gcnt's own files)."""
    try:
        if not _git("ls-files", "--", "src/gcnt/__init__.py").strip():
            return None
        commit = _git("rev-parse", "HEAD").strip()
        dirty = bool(_git("status", "--porcelain", "--untracked-files=no").strip())
    except (OSError, subprocess.SubprocessError):
        return None
    return json.dumps({"commit": commit, "dirty": dirty}) + "\n"


class BuildPy(build_py):
    """build_py that writes ``gcnt/_build.json`` from git (else keeps an sdist's own)."""

    def run(self) -> None:
        super().run()
        record = build_record()
        if record is not None:
            target = Path(self.build_lib) / "gcnt" / BUILD_FILE
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(record)


class Sdist(sdist):
    """sdist whose source tree carries ``src/gcnt/_build.json`` from git."""

    def make_release_tree(self, base_dir, files) -> None:
        super().make_release_tree(base_dir, files)
        record = build_record()
        if record is not None:
            target = Path(base_dir) / "src" / "gcnt" / BUILD_FILE
            if target.exists():  # a hard link to the checkout's file: replaced, not written through
                target.unlink()
            target.write_text(record)


setup(cmdclass={"build_py": BuildPy, "sdist": Sdist})
