"""gcnt as a package: a wheel built from the checkout, installed into a new virtual environment
outside it, runs its commands from any folder with the robots and recipes it ships, and keeps the
user's robot sets in the user's data folder.

The new environment takes gcnt from the wheel and every other package from the environment that
runs the tests (a ``.pth`` line after its own site-packages), so the test needs no network."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest
from cli_helpers import ROOT, TINY_SWEEP_OVERRIDES

import gcnt
from gcnt.run import provenance as P

#: what a build of the package reads from the checkout
SOURCES = (
    "pyproject.toml",
    "setup.py",
    "README.md",
    "LICENSE",
    "src",
    "recipes",
    "morphologies",
    "constraints.txt",
)


def _build_wheel(tmp_path: Path, commit: bool = False) -> Path:
    """The wheel of a copy of the checkout (a build writes build/ and *.egg-info beside it);
    ``commit``: the copy made a git repository of one commit first."""
    copy = tmp_path / "checkout"
    copy.mkdir()
    for name in SOURCES:
        src = ROOT / name
        if src.is_dir():
            ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.pyc")
            shutil.copytree(src, copy / name, symlinks=True, ignore=ignore)
        else:
            shutil.copy(src, copy / name)
    if commit:
        _git(copy, "init", "-q")
        _git(copy, "add", "-A")
        _git(copy, "commit", "-q", "-m", "the copy")
    wheels = tmp_path / "wheels"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    build = [*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", str(wheels)]
    subprocess.run([*build, str(copy)], check=True, cwd=tmp_path, capture_output=True)
    (wheel,) = wheels.glob("gcnt-*.whl")
    return wheel


def _git(repo: Path, *args: str) -> str:
    identity = ["-c", "user.name=t", "-c", "user.email=t@example.org", "-c", "commit.gpgsign=false"]
    return subprocess.run(
        ["git", *identity, "-C", str(repo), *args], capture_output=True, text=True, check=True
    ).stdout.strip()


@pytest.mark.skipif(shutil.which("git") is None, reason="no git binary")
def test_a_wheel_built_from_a_git_checkout_names_its_commit(tmp_path):
    """The wheel carries the commit it was built from; provenance (and so captions and the W&B
    config) reads it where the installed package is in no git checkout."""
    wheel = _build_wheel(tmp_path, commit=True)
    head = _git(tmp_path / "checkout", "rev-parse", "HEAD")
    site = tmp_path / "site"  # the wheel unpacked: gcnt as installed, outside any checkout
    with zipfile.ZipFile(wheel) as z:
        z.extractall(site)
    record = json.loads((site / "gcnt" / P.BUILD_FILE).read_text())
    assert record == {"commit": head, "dirty": False}
    show = "import json; from gcnt.run import provenance as P; print(json.dumps(P.collect(['x'])))"
    env = {**os.environ, "PYTHONPATH": str(site)}
    done = subprocess.run(
        [sys.executable, "-c", show], cwd=tmp_path, env=env, capture_output=True, text=True,
        check=True,
    )  # fmt: skip
    session = json.loads(done.stdout)
    assert (session["git_commit"], session["git_dirty"]) == (head, False), session
    assert session["git_note"] == "recorded by the build of gcnt"
    assert P.code_label(session) == head[:7]
    # an sdist of the checkout with a tracked file changed: its tree carries the record, so a
    # wheel built from it (no git there) names the commit, dirty
    copy = tmp_path / "checkout"
    (copy / "README.md").write_text((copy / "README.md").read_text() + "changed\n")
    sdist = "import sys; from setuptools import build_meta as b; print(b.build_sdist(sys.argv[1]))"
    made = subprocess.run(
        [sys.executable, "-c", sdist, str(tmp_path / "sdist")], cwd=copy, capture_output=True,
        text=True, check=True,
    ).stdout.split()[-1]  # fmt: skip
    with tarfile.open(tmp_path / "sdist" / made) as tar:
        tar.extractall(tmp_path / "unpacked", filter="data")
    (tree,) = (tmp_path / "unpacked").iterdir()
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", "wheel", "--no-deps"]
    build = [*pip, "--no-build-isolation", "--no-index", "-w", str(tmp_path / "from-sdist")]
    subprocess.run([*build, str(tree)], check=True, cwd=tmp_path, capture_output=True)
    (wheel,) = (tmp_path / "from-sdist").glob("gcnt-*.whl")
    with zipfile.ZipFile(wheel) as z:
        assert json.loads(z.read(f"gcnt/{P.BUILD_FILE}")) == {"commit": head, "dirty": True}


def _venv_with(wheel: Path, where: Path) -> Path:
    """A new virtual environment with gcnt installed from ``wheel``; its ``bin/`` folder."""
    venv.create(where, with_pip=False)
    python = where / "bin" / "python"
    purelib = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    shared = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    Path(purelib, "shared-packages.pth").write_text("\n".join(sorted(shared)) + "\n")
    install = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    install += ["--python", str(python), "install", "--no-deps", "--no-index", str(wheel)]
    subprocess.run(install, check=True, capture_output=True)
    return where / "bin"


@pytest.mark.slow
def test_a_wheel_runs_robots_train_and_eval_outside_the_checkout(tmp_path):
    wheel = _build_wheel(tmp_path)
    bin_ = _venv_with(wheel, tmp_path / "venv")
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "GCNT_MORPHOLOGIES")}
    env |= {"XDG_DATA_HOME": str(tmp_path / "xdg"), "WANDB_MODE": "disabled"}

    def gcnt_(*argv: str) -> str:
        done = subprocess.run(
            [bin_ / "gcnt", *argv], cwd=work, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, (argv, done.stderr[-2000:])
        return done.stdout

    where = subprocess.run(
        [bin_ / "python", "-c", "import gcnt; print(gcnt.__file__)"],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert where.startswith(str(tmp_path / "venv")), where  # the wheel's gcnt, not the checkout's
    assert gcnt_("--version").strip() == f"gcnt {gcnt.__version__}"
    # the versions gcnt is tested with travel in the wheel, beside this environment's
    report = gcnt_("--version", "--verbose").splitlines()
    tested = P.tested_versions()
    assert tested["torch"] and tested["torchrl"] and "pytest" not in tested  # no dev tools
    for name, version in tested.items():
        (row,) = [line.split() for line in report if line.split()[:1] == [name]]
        assert row[1] == version and row[2].split("+")[0] == P._version(name).split("+")[0]
    shipped = Path(where).parent / "data" / "constraints.txt"
    assert shipped.is_file() and not shipped.is_symlink() and str(shipped) in report[-1]
    listing = gcnt_("robots")
    assert "Walker++:train" in listing and "Unimal:test" in listing
    assert f"your robot sets (GCNT_MORPHOLOGIES, added to gcnt's): {tmp_path}/xdg/gcnt/" in listing
    tiny = [*TINY_SWEEP_OVERRIDES, "collector.total_frames=220", "logger.backend=none"]
    gcnt_("train", "quickstart", *tiny, "run_dir=by-name")
    # a recipe file of the user's, starting from a packaged one by its path
    packaged = Path(where).parent / "data" / "recipes" / "quickstart.yaml"
    assert packaged.is_file()
    (work / "mine.yaml").write_text(f"base: {packaged}\nseed: 3\n")
    gcnt_("train", "mine.yaml", *tiny, "run_dir=by-path")
    out = gcnt_("eval", "by-name", "--robots", "test", "--episodes", "1")
    assert "hopper_4" in out
    assert (work / "by-path" / "checkpoints" / "last.pt").is_file()
    assert not (tmp_path / "xdg").exists()  # nothing written to the user's data folder

    # the shipped notebook runs on the installed package, outside the checkout, and removes
    # its temporary folder
    pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    executed = tmp_path / "executed.ipynb"
    done = subprocess.run(
        [bin_ / "python", "-c", RUN_NOTEBOOK, str(NOTEBOOK), str(work), str(executed)],
        cwd=work, env=env | {"TMPDIR": str(tmp)}, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    text = _stream_text(executed)
    assert f"from {Path(where).parent}" in text  # the wheel's gcnt in the notebook's kernel
    assert "finished: True" in text
    assert list(tmp.glob("gcnt-quickstart-*")) == []  # its run's temporary folder is gone


NOTEBOOK = ROOT / "notebooks" / "quickstart.ipynb"
#: run by the installed environment's Python: execute a notebook (its kernel: that Python) in a
#: folder, write the executed notebook
RUN_NOTEBOOK = """\
import sys
import nbclient, nbformat
nb = nbformat.read(sys.argv[1], as_version=4)
resources = {"metadata": {"path": sys.argv[2]}}
nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources=resources).execute()
nbformat.write(nb, sys.argv[3])
"""


def _stream_text(path: Path) -> str:
    """The printed output of an executed notebook's cells."""
    import json

    cells = json.loads(path.read_text())["cells"]
    outputs = [o for c in cells if c["cell_type"] == "code" for o in c.get("outputs", [])]
    return "".join("".join(o.get("text", "")) for o in outputs if o["output_type"] == "stream")


def test_version_verbose_lists_the_tested_versions_beside_these(capsys) -> None:
    from gcnt.cli import main

    assert main(["--version", "--verbose"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"gcnt {gcnt.__version__}"
    (torch_row,) = [line.split() for line in lines if line.split()[:1] == ["torch"]]
    assert torch_row[1] == P.tested_versions()["torch"] == _pinned("torch")


def _pinned(name: str) -> str:
    """The version constraints.txt pins ``name`` to."""
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.startswith(f"{name}=="):
            return line.split("==")[1].strip()
    raise AssertionError(f"{name} is not pinned")
