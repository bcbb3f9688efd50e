"""Every file gcnt reads and did not just write goes through one guarded reader
(:mod:`gcnt.files`): a FIFO, a device or a file too large, too deep or of the wrong kind is one
line naming it, never a hang, a ``MemoryError`` or a traceback, and a small file costs little
memory whatever the cap."""

from __future__ import annotations

import ast
import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
from source_scan import calls, unguarded
from source_scan import mode as mode_of

from gcnt.data_folders import MORPHOLOGIES_ENV
from gcnt.files import MAX_DEPTH, MiB, read_json, read_regular, read_yaml
from gcnt.morphology.catalogues import refresh_catalogues
from gcnt.run.provenance import PROVENANCE_FILE, add_session

#: reads outside gcnt.files that are allowed, and why: (module, function, call)
ALLOWED = {
    # the kernel's own files, not the user's
    ("rl/config_check.py", "memory_limit", "read_text"),
    # YAML of a string (a value typed on the command line, a dict copied), not of a file
    ("recipes.py", "_apply_override", "yaml.load"),
    ("recipes.py", "recipe_from_dict", "yaml.safe_load"),
    ("recipes.py", "recorded_recipe", "yaml.safe_load"),
    # a handle from open_regular, or an archive member of an import (capped by its header)
    ("run/directory.py", "load_checkpoint", "torch.load"),
    ("rl/td3/replay.py", "load", "torch.load"),
    ("morphology/unimal/imported.py", "_read_member", "open"),
}


def _read_call(node: ast.Call) -> str | None:
    f = node.func
    if isinstance(f, ast.Attribute):
        owner = f.value.id if isinstance(f.value, ast.Name) else None
        if f.attr in ("read_text", "read_bytes"):
            return f.attr
        if (owner, f.attr) in {("json", "load"), ("yaml", "safe_load"), ("yaml", "load")}:
            return f"{owner}.{f.attr}"
        if (owner, f.attr) in {("torch", "load"), ("np", "load"), ("numpy", "load")}:
            return f"{owner}.{f.attr}"
        if f.attr == "open" and owner not in ("os", "zipfile", "tarfile"):
            mode = mode_of(node, 0)
            return None if mode and any(c in mode for c in "wax") else "open"
    if isinstance(f, ast.Name) and f.id == "open":
        mode = mode_of(node, 1)
        if node.args and isinstance(node.args[0], ast.Name) and node.args[0].id == "fd":
            return None  # an already opened descriptor (gcnt.files)
        return None if mode and any(c in mode for c in "wax") else "open"
    return None


def test_every_read_of_a_file_goes_through_the_guarded_reader():
    unguarded_calls = unguarded(_read_call, ALLOWED)
    assert not unguarded_calls, (
        "read through gcnt.files.read_regular/read_text/read_json/read_yaml:\n"
        + ("\n".join(unguarded_calls))
    )


def test_the_scan_sees_plain_reads():
    code = (
        "def f(p):\n    return p.read_text()\n"
        "def g(p):\n    return yaml.safe_load(open(p))\n"
        "def h(p):\n    with p.open() as f:\n        return json.load(f)\n"
        "def w(p):\n    p.open('w')\n"
    )
    assert [(f, c) for f, c, _ in calls(ast.parse(code), _read_call)] == [
        ("f", "read_text"),
        ("g", "yaml.safe_load"),
        ("g", "open"),
        ("h", "open"),
        ("h", "json.load"),
    ]


def test_a_small_file_is_read_without_reserving_the_cap(tmp_path):
    """Under an address-space limit below the cap, a file of a few bytes still reads."""
    import resource

    small = tmp_path / "metrics.jsonl"
    small.write_text('{"env_steps": 1, "x": 2.0}\n' * 60)
    limit = 3 << 30  # below the 4 GiB cap of a metrics log

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    code = (
        "import sys; from gcnt.run.metrics import read_metrics; "
        "print(len(read_metrics(sys.argv[1])))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(small)],
        preexec_fn=cap,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    assert out.returncode == 0 and out.stdout.split() == ["60"], out.stderr[-500:]


def test_the_reader_reads_what_is_there_and_refuses_more(tmp_path):
    path = tmp_path / "f"
    path.write_bytes(b"x" * (5 * MiB + 3))  # more than one chunk
    assert read_regular(path, 6 * MiB, "a file", ValueError) == b"x" * (5 * MiB + 3)
    with pytest.raises(ValueError, match="larger than"):
        read_regular(path, 5 * MiB, "a file", ValueError)
    path.write_bytes(b"")
    assert read_regular(path, 10, "a file", ValueError) == b""


def test_yaml_and_json_nested_too_deep_are_one_line(tmp_path):
    deep = tmp_path / "deep"
    for text in ("[" * 60_000 + "]" * 60_000, "[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1)):
        deep.write_text(text)
        for read in (read_json, read_yaml):
            with pytest.raises(ValueError, match=f"deep: nested deeper than {MAX_DEPTH} levels"):
                read(deep, MiB, "a file", ValueError)
    deep.write_text("[" * (MAX_DEPTH - 1) + "]" * (MAX_DEPTH - 1))
    assert read_json(deep, MiB, "a file", ValueError) is not None


def test_deeply_nested_provenance_does_not_stop_a_resume(tmp_path, caplog):
    path = tmp_path / PROVENANCE_FILE
    path.write_text("[" * 200_000 + "]" * 200_000)  # 400 kB
    with caplog.at_level(logging.WARNING):
        add_session(tmp_path, {"gcnt_version": "x"})
    assert json.loads(path.read_text()) == {"sessions": [{"gcnt_version": "x"}]}
    assert (tmp_path / (PROVENANCE_FILE + ".unreadable")).stat().st_size == 400_000
    assert any("nested deeper" in r.getMessage() for r in caplog.records)


# ------------------------------------------------------------------ split files


@pytest.fixture
def morph(tmp_path, monkeypatch) -> Path:
    folder = tmp_path / "morphologies"  # a robot-set folder read beside gcnt's own robots
    folder.mkdir()
    monkeypatch.setenv(MORPHOLOGIES_ENV, str(folder))
    refresh_catalogues()
    yield folder
    refresh_catalogues()


#: in a process of its own, under an address-space limit and a timeout: for each hostile
#: ``catalogue.yaml`` (a FIFO, a link to /dev/zero, a sparse 3 GB file) in a morphologies
#: folder, robots still resolve and the folder is left out with one warning
_HOSTILE = """
import logging, os, sys
from pathlib import Path
from gcnt.morphology.catalogues import refresh_catalogues, resolve_robots
warned = []
logging.getLogger("gcnt").addHandler(type("H", (logging.Handler,), {"emit":
    lambda self, r: warned.append(r.getMessage())})())
root = Path(sys.argv[1])
for kind in ("fifo", "device", "sparse"):
    evil = root / f"Evil{kind}"
    (evil / "train" / "xml").mkdir(parents=True)
    target = evil / "catalogue.yaml"
    if kind == "fifo":
        os.mkfifo(target)
    elif kind == "device":
        target.symlink_to("/dev/zero")
    else:
        with open(target, "wb") as f:
            f.truncate(3 << 30)
    refresh_catalogues()
    warned.clear()
    names = [r.name for r in resolve_robots(["hopper_3", "CWHH++:test"])]
    left_out = [w for w in warned if "left out" in w and str(evil) in w]
    print(kind, names[0], len(left_out), flush=True)
    os.unlink(target)
    os.rmdir(evil / "train" / "xml"), os.rmdir(evil / "train"), os.rmdir(evil)
"""


def test_a_hostile_catalogue_file_is_left_out_with_a_warning(morph):
    import resource

    def cap() -> None:
        limit = 3 << 30
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    try:
        out = subprocess.run(
            [sys.executable, "-c", _HOSTILE, str(morph)],
            preexec_fn=cap,
            capture_output=True,
            text=True,
            timeout=180,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
        )
    except subprocess.TimeoutExpired as e:
        pytest.fail(f"resolving robots hung on a hostile catalogue.yaml: {e.stdout!r}")
    assert out.stdout.splitlines() == [
        "fifo hopper_3 1",
        "device hopper_3 1",
        "sparse hopper_3 1",
    ], out.stderr[-800:]


@pytest.mark.parametrize(
    "code, hint",
    [("ENOSPC", "; free space"), ("EROFS", "; work on a copy in a folder you can write")],
)
def test_a_failed_write_names_its_file_and_a_fitting_remedy(code, hint, tmp_path, capsys):
    """A full disk fails in ``write`` with an error that names no file: the line names it; a
    read-only disk is not told to free space."""
    import builtins
    import errno

    from cli_helpers import error_line

    import gcnt.files

    quick = Path(__file__).parents[1] / "recipes" / "quickstart.yaml"

    class Full:  # a file on a full (or read-only) disk: the write fails
        def __init__(self, f):
            self.f = f

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, data):
            raise OSError(getattr(errno, code), os.strerror(getattr(errno, code)))

    def failing(file, mode="r", *args, **kwargs):  # the writer's temporary file fails
        f = builtins.open(file, mode, *args, **kwargs)
        return Full(f) if "w" in mode else f

    monkeypatch = pytest.MonkeyPatch()
    monkeypatch.setattr(gcnt.files, "open", failing, raising=False)
    try:
        line = error_line(capsys, ["sweep", str(quick), "--dir", str(tmp_path / "sw"), "--dry-run"])
    finally:
        monkeypatch.undo()
    assert f"{tmp_path / 'sw' / 'manifest'}" in line and line.endswith(hint), line
    assert "free space" not in line or code == "ENOSPC"
