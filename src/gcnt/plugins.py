"""Plugins: your own modules, imported before gcnt does anything, so that what they register
(``register_network``, ``register_benchmark``, ``register_algorithm`` with its recipe section,
``register_catalogue``) is known to every command and every process gcnt starts.

A plugin is named by a module (``my_pkg.methods``, importable from the Python path: installed, or
on PYTHONPATH) or a ``.py`` file (imported from that file alone: neither its folder nor the
current folder is put on the Python path, so a stray ``pandas.py`` beside it is never imported in
place of the real one). Code is imported only from what the user names in the command itself,
all of them added together:

* the recipe key ``plugins: [my_pkg.methods]`` of a recipe file given to ``gcnt train`` or
  ``gcnt sweep`` (a relative file path is relative to the recipe file);
* ``gcnt --plugin my_pkg.methods COMMAND ...`` (repeatable; anywhere on the command line);
* the variable ``GCNT_PLUGINS=my_pkg.methods,other.mod`` (separated by commas or colons);
* the entry-point group ``gcnt.plugins`` of an installed package (``[project.entry-points.
  "gcnt.plugins"] my_methods = "my_pkg.methods"``; a function named there is called once).

A run records the identity of each plugin it was trained with (its module or file name and the
sha256 of its source, :func:`identities`; never the path of a file), never to import it again: a run or a sweep received
from someone else runs no code of theirs. A command that rebuilds a run's networks and needs a
name no imported code registers stops in one line naming the recorded plugin, its hash and
``--plugin`` (:func:`check_recorded`); a named plugin whose source differs from the recorded one
is a warning naming both hashes. A plugin that cannot be imported, raises, exits or is
interrupted while it is imported is one error naming it.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import importlib.util
import logging
import os
import re
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

#: the variable naming plugins (separated by commas or colons)
ENV_VAR = "GCNT_PLUGINS"
#: the entry-point group of installed packages' plugins
ENTRY_POINT_GROUP = "gcnt.plugins"

#: the largest plugin source hashed (a module is kilobytes)
MAX_SOURCE_BYTES = 64 << 20

_MODULE = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")

#: plugin (as named) -> {"plugin", "via", "file", "name", "sha256"}: every plugin imported here
_loaded: dict[str, dict[str, Any]] = {}
#: the plugins of this command (``--plugin``, GCNT_PLUGINS, a recipe given to train or sweep)
_session: list[str] = []


class PluginError(ValueError):
    """A plugin that cannot be imported, or a run's plugin that was not named; the message
    names it and says where it was named or how to name it."""


def normalize(spec: str, base: str | Path | None = None) -> str:
    """A plugin as a command names it: a module name as it is, a ``.py`` file (or any path with
    a folder in it) as an absolute path (``base``: the folder a relative path is relative to,
    default the current one)."""
    text = str(spec).strip()
    if not text:
        raise PluginError("an empty plugin name")
    if text.endswith(".py") or "/" in text or os.sep in text:
        path = Path(text).expanduser()
        if not path.is_absolute():
            path = Path(base or Path.cwd()) / path
        return str(path.resolve())
    if not _MODULE.fullmatch(text):
        raise PluginError(
            f"plugin {text!r} is neither a module name (my_pkg.methods) nor a .py file"
        )
    return text


def split(text: str | None) -> list[str]:
    """The plugins of a GCNT_PLUGINS value: separated by commas or colons."""
    return [t.strip() for t in re.split(r"[,:]", text or "") if t.strip()]


def load(specs: Iterable[str], via: str = "", base: str | Path | None = None) -> list[str]:
    """Import each plugin of ``specs`` once per process; their normalized forms
    (:func:`normalize`). ``via`` says where they were named (for errors and provenance)."""
    out = []
    for spec in specs:
        name = normalize(spec, base)
        if name not in _loaded:
            file = _import(name, via)
            _loaded[name] = {
                "plugin": name,
                "via": via,
                "file": file,
                "name": Path(name).name if _is_file(name) else name,
                "sha256": source_hash(file),
            }
        out.append(name)
    return list(dict.fromkeys(out))


def _is_file(name: str) -> bool:
    return name.startswith(os.sep) or name.endswith(".py")


def _import(name: str, via: str) -> str | None:
    """Import plugin ``name`` (a module name or an absolute .py path); the file it came from.
    Whatever the plugin's code does while it is imported (raises, ``sys.exit``, Ctrl-C) is a
    PluginError naming it."""
    where = f" (named by {via})" if via else ""
    try:
        if _is_file(name):
            return _import_file(Path(name), name, where)
        return _file(importlib.import_module(name))
    except PluginError:
        raise
    except BaseException as e:  # noqa: BLE001 - the plugin's own code: exits and Ctrl-C too
        raise PluginError(f"plugin {name}{where} cannot be imported: {_reason(e)}") from None


def _import_file(path: Path, name: str, where: str) -> str:
    """Import the file ``path`` as the module of its stem, from that file only (the Python path
    is left as it is); the module is entered in ``sys.modules`` so that what it defines can be
    pickled to worker processes, which import the same file first (a recipe's plugins)."""
    if not path.is_file():
        raise PluginError(f"plugin {name}{where}: no such file")
    module = path.stem
    if not _MODULE.fullmatch(module):
        raise PluginError(f"plugin {name}{where}: {module!r} is not a module name; rename it")
    known = sys.modules.get(module)
    if known is not None:
        if _file(known) == str(path):
            return str(path)
        raise PluginError(
            f"plugin {name}{where}: a module named {module!r} is already imported from "
            f"{_file(known) or 'elsewhere'}; rename the file"
        )
    spec = importlib.util.spec_from_file_location(module, path)
    if spec is None or spec.loader is None:
        raise PluginError(f"plugin {name}{where}: not a Python file")
    imported = importlib.util.module_from_spec(spec)
    sys.modules[module] = imported
    try:
        spec.loader.exec_module(imported)
    except BaseException:
        sys.modules.pop(module, None)
        raise
    return str(path)


def _reason(e: BaseException) -> str:
    if isinstance(e, SystemExit):
        return f"it called sys.exit({e.code!r})"
    if isinstance(e, KeyboardInterrupt):
        return "interrupted (KeyboardInterrupt)"
    text = f"{type(e).__name__}: {e}"
    if isinstance(e, ModuleNotFoundError):
        text += " (install it, put its folder on PYTHONPATH, or name its .py file)"
    return " ".join(text.split())


def _file(module: Any) -> str | None:
    file = getattr(module, "__file__", None)
    return str(Path(file).resolve()) if file else None


def source_hash(file: str | Path | None) -> str | None:
    """The sha256 of a plugin's source file (None where it has none)."""
    if not file:
        return None
    from gcnt.files import read_regular

    try:
        data = read_regular(file, MAX_SOURCE_BYTES, "a plugin's source is a Python file", OSError)
    except OSError:
        return None
    return hashlib.sha256(data).hexdigest()


def load_entry_points() -> list[str]:
    """Import the ``gcnt.plugins`` entry points of the installed packages (a function an entry
    point names is called once)."""
    out = []
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        key = f"entry point {ep.name} = {ep.value}"
        if key in _loaded:
            continue
        try:
            obj = ep.load()
            if callable(obj) and not isinstance(obj, type):
                obj()
        except BaseException as e:  # noqa: BLE001 - the plugin's own code: exits and Ctrl-C too
            raise PluginError(
                f"plugin {ep.value} (entry point {ep.name!r} of group {ENTRY_POINT_GROUP}) "
                f"cannot be imported: {_reason(e)}"
            ) from None
        file = _file(sys.modules.get(ep.module))
        _loaded[key] = {
            "plugin": ep.value,
            "via": f"entry point {ep.name}",
            "file": file,
            "name": ep.module,
            "sha256": source_hash(file),
        }
        out.append(ep.value)
    return out


def start_session(cli: Iterable[str] = ()) -> list[str]:
    """What a ``gcnt`` command imports before it runs: the installed packages' entry points,
    then GCNT_PLUGINS, then ``--plugin``. The last two are the command's own plugins, which
    the processes it starts (a sweep's runs, a collector's workers) import too."""
    global _session
    _session = []
    load_entry_points()
    named = load(split(os.environ.get(ENV_VAR)), via=ENV_VAR)
    named += load(cli, via="--plugin")
    _session = list(dict.fromkeys(named))
    return list(_session)


def add_to_session(names: Iterable[str]) -> None:
    """Plugins a recipe given to this command named (already imported: :func:`load`)."""
    global _session
    _session = list(dict.fromkeys([*_session, *names]))


def end_session() -> None:
    """The command is over: its plugins stay imported, but are no longer its own."""
    global _session
    _session = []


def session() -> list[str]:
    """This command's own plugins (``--plugin``, GCNT_PLUGINS, a given recipe's)."""
    return list(_session)


def with_session(plugins: Iterable[str]) -> list[str]:
    """``plugins`` (a recipe's) followed by this command's own ones not among them."""
    return list(dict.fromkeys([*plugins, *_session]))


def loaded() -> list[dict[str, Any]]:
    """Every plugin this process imported: ``{"plugin", "via", "file", "name", "sha256"}``."""
    return [dict(v) for v in _loaded.values()]


def identities(via: bool = False) -> list[dict[str, Any]]:
    """What a run records of the plugins imported while it trains: each one's ``name`` (module,
    or file name) and the ``sha256`` of its source (``via``: also where it was named, as a
    session's provenance records it). Never a path; never imported from the record."""
    keys = ("name", "sha256", "via") if via else ("name", "sha256")
    return [{k: v[k] for k in keys} for v in _loaded.values()]


def shared_names(specs: Iterable[str]) -> list[str]:
    """Plugins as a run's ``recipe.yaml`` lists them (its ``plugins:`` key): module names as
    they are, files by their name alone (the folder is the author's machine's)."""
    return [Path(s).name if _is_file(s) else s for s in specs]


def recorded_identity(entry: Any) -> dict[str, Any] | None:
    """A recorded plugin as ``{"name", "sha256"}``: a run's record holds mappings; runs written
    before identities were recorded list the path or module they named (no hash)."""
    if isinstance(entry, Mapping) and isinstance(entry.get("name"), str):
        sha = entry.get("sha256")
        return {"name": entry["name"], "sha256": sha if isinstance(sha, str) else None}
    if isinstance(entry, str) and entry.strip():
        text = entry.strip()
        return {"name": Path(text).name if _is_file(text) else text, "sha256": None}
    return None


def check_recorded(recorded: Iterable[Any], run: str | Path, needed: Iterable[str]) -> None:
    """Check the plugins ``run`` recorded against those this process imported.

    A recorded plugin is matched by the hash of its source, else by its name (then a warning
    names both hashes where they differ). ``needed``: what the run names that no imported code
    registers (its method, benchmark or algorithm); if any, an unmatched recorded plugin is a
    PluginError naming it, its hash and ``--plugin``. Nothing is ever imported from the record.
    """
    needed = list(needed)
    have = list(_loaded.values())
    missing = []
    for entry in recorded:
        ident = recorded_identity(entry)
        if ident is None:
            continue
        if ident["sha256"] and any(h["sha256"] == ident["sha256"] for h in have):
            continue
        same = [h for h in have if h["name"] == ident["name"]]
        if same:
            if ident["sha256"] and same[0]["sha256"] != ident["sha256"]:
                log.warning(
                    "%s was trained with plugin %s sha256 %s; the one named here (%s) has "
                    "sha256 %s",
                    run,
                    ident["name"],
                    _short(ident["sha256"]),
                    same[0]["plugin"],
                    _short(same[0]["sha256"]),
                )
            continue
        missing.append(ident)
    if needed and missing:
        first = missing[0]
        sha = f" (sha256 {_short(first['sha256'])})" if first["sha256"] else ""
        raise PluginError(
            f"{run} names {', '.join(needed)}, which no code imported here registers; it was "
            f"trained with the plugin {first['name']}{sha}, which this command did not name "
            f"(gcnt never imports a run's plugins): pass it with `gcnt --plugin "
            f"PATH_OR_MODULE ...` (or {ENV_VAR}); from Python, call "
            f"`gcnt.plugins.load([PATH_OR_MODULE])` first"
        )


def _short(sha: str | None) -> str:
    return sha[:16] if sha else "unknown"
