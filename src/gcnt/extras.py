"""Optional parts of gcnt and the packages they need: ``pip install 'gcnt[slurm]'`` (sweeps on
Slurm through submitit) and ``gcnt[analysis]`` (t-SNE embeddings through scikit-learn);
``gcnt[all]`` is both, and ``make`` installs it. A command that needs a missing one says so in
one line (:class:`MissingExtraError`)."""

from __future__ import annotations

import importlib
from types import ModuleType

#: module -> (the extra that installs it, its package name)
EXTRAS = {
    "submitit": ("slurm", "submitit"),
    "sklearn": ("analysis", "scikit-learn"),
}


class MissingExtraError(ImportError):
    """A command needs an optional package that is not installed; the message names the extra."""


def require(module: str, what: str) -> ModuleType:
    """``module`` imported, or a :class:`MissingExtraError` saying which extra ``what`` needs."""
    try:
        return importlib.import_module(module)
    except ImportError:
        top = module.split(".")[0]
        extra, package = EXTRAS.get(top, ("all", top))
        raise MissingExtraError(
            f"{what} needs {package}, which is not installed: pip install 'gcnt[{extra}]'"
        ) from None
