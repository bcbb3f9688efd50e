"""Plugins: your own modules, imported before gcnt does anything, so that what they register
(``register_network``, ``register_benchmark``, ``register_algorithm`` with its recipe section,
``register_catalogue``) is known to every command and every process gcnt starts.

A plugin is named by a module (``my_pkg.methods``, importable from the current folder or the
Python path) or a ``.py`` file (its folder is put on the Python path, so that worker processes
import it by name too). Four ways name one, all of them added together:

* the recipe key ``plugins: [my_pkg.methods]`` (a relative file path is relative to the recipe
  file);
* ``gcnt --plugin my_pkg.methods COMMAND ...`` (repeatable; anywhere on the command line);
* the variable ``GCNT_PLUGINS=my_pkg.methods,other.mod`` (separated by commas or colons);
* the entry-point group ``gcnt.plugins`` of an installed package (``[project.entry-points.
  "gcnt.plugins"] my_methods = "my_pkg.methods"``; a function named there is called once).

A run records the plugins it was trained with in its recipe (``plugins:``), so that ``gcnt eval``,
``--resume``, ``--init-from`` (whose run records its source's plugins too), a sweep's runs (on this
machine or on Slurm) and the analysis commands import them again; ``provenance.json`` records the
file each came from. A plugin that cannot be imported is one error naming it.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

#: the variable naming plugins (separated by commas or colons)
ENV_VAR = "GCNT_PLUGINS"
#: the entry-point group of installed packages' plugins
ENTRY_POINT_GROUP = "gcnt.plugins"

_MODULE = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")

#: plugin (as recorded) -> {"plugin", "via", "file"}: every plugin this process imported
_loaded: dict[str, dict[str, Any]] = {}
#: the plugins of this command (``--plugin`` and GCNT_PLUGINS), recorded by the runs it starts
_session: list[str] = []


class PluginError(ValueError):
    """A plugin that cannot be imported; the message names it and says where it was named."""


def normalize(spec: str, base: str | Path | None = None) -> str:
    """A plugin as runs record it: a module name as it is, a ``.py`` file (or any path with a
    folder in it) as an absolute path (``base``: the folder a relative path is relative to,
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
    """Import each plugin of ``specs`` once per process; their recorded forms
    (:func:`normalize`). ``via`` says where they were named (for errors and provenance)."""
    out = []
    for spec in specs:
        name = normalize(spec, base)
        if name not in _loaded:
            _loaded[name] = {"plugin": name, "via": via, "file": _import(name, via)}
        out.append(name)
    return list(dict.fromkeys(out))


def _import(name: str, via: str) -> str | None:
    """Import plugin ``name`` (a module name or an absolute .py path); the file it came from."""
    where = f" (named by {via})" if via else ""
    if name.startswith(os.sep) or name.endswith(".py"):
        path = Path(name)
        if not path.is_file():
            raise PluginError(f"plugin {name}{where}: no such file")
        folder, module = str(path.parent), path.stem
        if not _MODULE.fullmatch(module):
            raise PluginError(f"plugin {name}{where}: {module!r} is not a module name; rename it")
        known = sys.modules.get(module)
        if known is not None and _file(known) != str(path):
            raise PluginError(
                f"plugin {name}{where}: a module named {module!r} is already imported from "
                f"{_file(known) or 'elsewhere'}; rename the file"
            )
        if folder not in sys.path:
            sys.path.append(folder)  # worker processes (spawn) import it by name too
        found = importlib.util.find_spec(module)
        if found is None or found.origin != str(path):
            raise PluginError(
                f"plugin {name}{where}: the module name {module!r} is taken by "
                f"{found.origin if found else 'another module'}; rename the file"
            )
    else:
        module = name
        if "" not in sys.path and os.getcwd() not in sys.path:
            sys.path.append(os.getcwd())  # as `python -m` does: modules of the current folder
    try:
        imported = importlib.import_module(module)
    except Exception as e:  # anything the plugin's own code raises while it is imported
        raise PluginError(f"plugin {name}{where} cannot be imported: {_reason(e)}") from e
    return _file(imported)


def _reason(e: BaseException) -> str:
    text = f"{type(e).__name__}: {e}"
    if isinstance(e, ModuleNotFoundError):
        text += (
            " (install it, run from the folder that holds it, put that folder on PYTHONPATH, "
            "or name its .py file)"
        )
    return text


def _file(module: Any) -> str | None:
    file = getattr(module, "__file__", None)
    return str(Path(file).resolve()) if file else None


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
        except Exception as e:
            raise PluginError(
                f"plugin {ep.value} (entry point {ep.name!r} of group {ENTRY_POINT_GROUP}) "
                f"cannot be imported: {_reason(e)}"
            ) from e
        module = sys.modules.get(ep.module)
        _loaded[key] = {"plugin": ep.value, "via": f"entry point {ep.name}", "file": _file(module)}
        out.append(ep.value)
    return out


def start_session(cli: Iterable[str] = ()) -> list[str]:
    """What a ``gcnt`` command imports before it runs: the installed packages' entry points,
    then GCNT_PLUGINS, then ``--plugin``. The last two are the command's own plugins, which
    the runs it starts record (:func:`with_session`)."""
    global _session
    _session = []
    load_entry_points()
    named = load(split(os.environ.get(ENV_VAR)), via=ENV_VAR)
    named += load(cli, via="--plugin")
    _session = list(dict.fromkeys(named))
    return list(_session)


def end_session() -> None:
    """The command is over: its plugins stay imported, but are no longer its runs' to record."""
    global _session
    _session = []


def session() -> list[str]:
    """This command's own plugins (``--plugin``, GCNT_PLUGINS)."""
    return list(_session)


def with_session(plugins: Iterable[str]) -> list[str]:
    """``plugins`` (a recipe's) followed by this command's own ones not among them."""
    return list(dict.fromkeys([*plugins, *_session]))


def loaded() -> list[dict[str, Any]]:
    """Every plugin this process imported: ``{"plugin", "via", "file"}`` (provenance)."""
    return [dict(v) for v in _loaded.values()]
