"""Every file gcnt writes goes through one guarded writer (:mod:`gcnt.files`): a temporary file
created exclusively beside the target, which replaces it only where it is absent or a regular
file; locks and logs opened without following a link or waiting on a FIFO. A link, a FIFO or a
device where gcnt writes is one line naming it, and what it points to is left as it was."""

from __future__ import annotations

import ast

import pytest
from source_scan import calls, unguarded
from source_scan import mode as mode_of

#: writes outside gcnt.files that are allowed, and why: (module, function, call)
ALLOWED = {
    # the shared-memory file of robot probabilities: tempfile's own exclusive file (mode 0600)
    # in /dev/shm, mapped by NumPy; no run, sweep, morphology or figure folder
    ("rl/ppo/robot_sampler.py", "shared_probs", "tempfile.mkstemp"),
    ("rl/ppo/robot_sampler.py", "shared_probs", "np.memmap"),
    # an import's own folder (made by mkdir, which never follows a link) moved into place
    ("morphology/unimal/imported.py", "_import_into", "rename"),
    # the video encoder writes the exclusive temporary file of gcnt.files.temp_path
    ("envs/render.py", "render_rollout", "imageio.get_writer"),
}

_CREATING_FLAGS = {"O_CREAT", "O_WRONLY", "O_RDWR", "O_APPEND", "O_TRUNC"}


def _owner(f: ast.Attribute) -> str | None:
    return f.value.id if isinstance(f.value, ast.Name) else None


def _write_call(node: ast.Call) -> str | None:
    f = node.func
    if isinstance(f, ast.Attribute):
        owner = _owner(f)
        if owner in ("files", "gcnt_files"):
            return None  # the guarded writer itself
        if f.attr in ("write_text", "write_bytes", "rename", "symlink_to", "hardlink_to"):
            return f.attr
        if f.attr == "replace" and len(node.args) == 1 and not node.keywords:
            return "replace"  # Path.replace(target); str.replace takes two arguments
        if (owner, f.attr) in {
            ("os", "replace"),
            ("os", "rename"),
            ("os", "renames"),
            ("os", "link"),
            ("os", "symlink"),
            ("os", "mkfifo"),
            ("os", "mknod"),
            ("torch", "save"),
            ("np", "save"),
            ("np", "savez"),
            ("np", "savez_compressed"),
            ("np", "savetxt"),
            ("tempfile", "mkstemp"),
            ("tempfile", "NamedTemporaryFile"),
            ("imageio", "get_writer"),
            ("imageio", "imwrite"),
            ("imageio", "mimwrite"),
            ("imageio", "mimsave"),
            ("logging", "FileHandler"),
        } or (owner == "shutil" and f.attr in ("copy", "copy2", "copyfile", "copytree", "move")):
            return f"{owner}.{f.attr}"
        if (owner, f.attr) == ("np", "memmap"):
            return None if mode_of(node, 2) == "r" else "np.memmap"
        if f.attr in ("savefig", "to_csv", "to_json", "to_parquet"):
            return _unless_file_object(node, f.attr)
        if f.attr == "open" and owner == "os":
            return "os.open" if _creating_flags(node) else None
        if f.attr == "open" and owner not in ("zipfile", "tarfile"):
            mode = mode_of(node, 0)
            return "open" if mode and any(c in mode for c in "wax+") else None
    if isinstance(f, ast.Name):
        if f.id == "open":
            mode = mode_of(node, 1)
            return "open" if mode and any(c in mode for c in "wax+") else None
        if f.id in ("FileHandler", "mkstemp", "NamedTemporaryFile", "copyfile", "copy2"):
            return f.id
    return None


def _unless_file_object(node: ast.Call, call: str) -> str | None:
    """``savefig(f, ...)`` into a file object of :func:`gcnt.files.writing` (named ``f``) is
    guarded; to a path it is not."""
    first = node.args[0] if node.args else None
    if isinstance(first, ast.Name) and first.id == "f":
        return None
    return call


def _creating_flags(node: ast.Call) -> bool:
    return any(
        isinstance(n, ast.Attribute) and n.attr in _CREATING_FLAGS
        for a in node.args[1:2]
        for n in ast.walk(a)
    )


def test_every_write_of_a_file_goes_through_the_guarded_writer():
    unguarded_calls = unguarded(_write_call, ALLOWED)
    assert not unguarded_calls, (
        "write through gcnt.files.write_text/write_bytes/writing/save_torch/append_text/"
        "open_append/open_lock/rename:\n" + "\n".join(unguarded_calls)
    )


def test_the_scan_sees_plain_writes():
    code = (
        "def a(p):\n    p.write_text('x')\n"
        "def b(p, t):\n    os.replace(t, p)\n"
        "def c(p):\n    with open(p, 'w') as f:\n        f.write('x')\n"
        "def d(p, s):\n    torch.save(s, p)\n"
        "def e(p):\n    p.open('a')\n"
        "def f(p):\n    os.open(p, os.O_RDWR | os.O_CREAT)\n"
        "def g(fig, p):\n    fig.savefig(p)\n"
        "def h(t, p):\n    t.replace(p)\n"
        "def ok(p, s):\n    s.replace('a', 'b'); open(p); os.open(p, os.O_RDONLY)\n"
        "def ok2(fig, f, p):\n    fig.savefig(f); files.write_text(p, 'x'); write_text(p, 'x')\n"
    )
    assert [(f, c) for f, c, _ in calls(ast.parse(code), _write_call)] == [
        ("a", "write_text"),
        ("b", "os.replace"),
        ("c", "open"),
        ("d", "torch.save"),
        ("e", "open"),
        ("f", "os.open"),
        ("g", "savefig"),
        ("h", "replace"),
    ]


def test_a_full_disk_while_writing_names_the_file(tmp_path, monkeypatch):
    """A write that fails mid-way (the disk fills at the write, the flush, or inside torch's
    writer) is an OSError naming the file gcnt was writing, which the CLI prints in its line."""
    import errno

    import torch

    from gcnt import files

    real = files.open_append

    def filling(path):
        f = real(path)

        def write(text):
            raise OSError(errno.ENOSPC, "No space left on device")

        f.write = write
        return f

    monkeypatch.setattr(files, "open_append", filling)
    log = tmp_path / "metrics.jsonl"
    with pytest.raises(OSError) as e:
        files.append_text(log, "{}\n")
    assert e.value.filename == str(log) and e.value.errno == errno.ENOSPC

    def torch_full(obj, f):
        raise RuntimeError(
            "[enforce fail at inline_container.cc] . PytorchStreamWriter failed writing file data/0: file write failed"
        )

    monkeypatch.setattr(torch, "save", torch_full)
    ckpt = tmp_path / "last.pt"
    with pytest.raises(OSError) as e:
        files.save_torch({"a": 1}, ckpt)
    assert e.value.filename == str(ckpt) and not ckpt.exists()
    assert not list(tmp_path.glob(".*last.pt"))  # the temporary file removed
