"""A run's directory: resolved recipe, metrics, checkpoints, eval results, videos, and
``provenance.json`` (the code, packages and command of each session: :mod:`gcnt.run.provenance`).

Nothing here depends on W&B being reachable: ``metrics.jsonl`` (one JSON line per log step) is the
local record, and W&B (offline by default) or CSV logging mirrors it through torchrl's loggers.
"""

from __future__ import annotations

import contextlib
import logging
import random
import shutil
from collections import OrderedDict
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from gcnt.files import GiB, append_text, open_regular, rename, save_torch, write_text
from gcnt.recipes import Recipe, save_recipe
from gcnt.run import provenance
from gcnt.run.layout import CHECKPOINT, METRICS_FILE, RECIPE_FILE
from gcnt.run.lock import RunBusyError, RunDirError, run_lock  # noqa: F401 (RunDirError: raised and caught as gcnt.run.directory's)
from gcnt.run.metrics import (  # noqa: F401 (strict_json, read_metrics_row: used from here)
    MetricsFileError,
    metrics_line,
    read_metrics,
    read_metrics_row,
    strict_json,
)
from gcnt.run.record import load_run_recipe

if TYPE_CHECKING:  # annotations only: the robots' module is not loaded with the run directory
    pass

log = logging.getLogger(__name__)

#: what training writes at an env step, ``<folder>/step<N><suffix>``: folder -> suffix
STEP_FILES = {"eval": ".json", "videos": ".mp4"}
#: the folder inside those for what a resumed run repeats (:meth:`RunDir.set_aside_after`)
SUPERSEDED = "superseded"
#: what gcnt writes into inside a run directory: folders (their nested folders too: a link
#: there would take the writes out as well), the checkpoint, and the log it appends to
WRITTEN = (
    "checkpoints",
    "checkpoints/buffers",
    CHECKPOINT,
    "eval",
    f"eval/{SUPERSEDED}",
    "videos",
    f"videos/{SUPERSEDED}",
    "robots",
    "robots/assets",
    "wandb",
    "csv",
    "figures",
    METRICS_FILE,
)


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable or does not fit the run's networks."""


class RunDir:
    def __init__(self, path: str | Path):
        self.path = Path(path)

    @classmethod
    def for_recipe(cls, recipe: Recipe) -> RunDir:
        """The recipe's ``run_dir``, or a fresh ``runs/<benchmark>/<method>/seed<seed>[-N]``."""
        if recipe.run_dir:
            return cls(recipe.run_dir)
        method = f"{recipe.algo}-{recipe.network.name}"
        base = Path("runs") / folder_name(recipe.task) / method / f"seed{recipe.seed}"
        path, n = base, 1
        while (path / CHECKPOINT).exists() or (path / RECIPE_FILE).exists():
            path, n = base.with_name(f"{base.name}-{n}"), n + 1
        return cls(path)

    # --- files
    @property
    def recipe_path(self) -> Path:
        return self.path / RECIPE_FILE

    @property
    def metrics_path(self) -> Path:
        return self.path / METRICS_FILE

    @property
    def checkpoint_path(self) -> Path:
        return self.path / CHECKPOINT

    def inside(self, name: str) -> Path:
        """``name`` (one of :data:`WRITTEN`) in the run directory, where gcnt writes: a
        RunDirError if it is a link or leads out of the run directory (what is written would
        land somewhere else: another run's checkpoint overwritten on resume)."""
        path = self.path / name
        if path.is_symlink() or (
            path.exists() and not path.resolve().is_relative_to(self.path.resolve())
        ):
            raise RunDirError(
                f"{path}: a link out of the run directory; gcnt writes only inside "
                f"{self.path} (remove the link)"
            )
        return path

    def check_links(self) -> None:
        """A RunDirError (:meth:`inside`) for the first of :data:`WRITTEN` that is a link: a
        command that writes into the run checks them all before any work."""
        for name in WRITTEN:
            self.inside(name)

    def eval_dir(self) -> Path:
        """``eval/`` of the run, where evaluations are written (see :meth:`inside`)."""
        return self.inside("eval")

    @property
    def buffers_dir(self) -> Path:
        """Where an algorithm may checkpoint large data (replay buffers; see :meth:`inside`)."""
        return self.inside("checkpoints/buffers")

    def create(self, recipe: Recipe) -> None:
        """Make the directory and write the recipe and the provenance of the process creating
        it; an existing run is never overwritten."""
        self.check_new()
        try:
            (self.path / "checkpoints").mkdir(parents=True, exist_ok=True)
            self.save_recipe(recipe)
            provenance.add_session(self.path)
        except OSError as e:
            raise RunDirError(
                f"run_dir {self.path}: cannot create the run directory ({e.strerror or e}"
                f"{': ' + str(e.filename) if e.filename else ''})"
            ) from None

    def record_session(self) -> None:
        """Add the running process (code, packages, machine, command) to ``provenance.json`` as
        a new session: a resumed run, so that the code of each session is known."""
        with _writing(self.path / provenance.PROVENANCE_FILE, "the provenance"):
            provenance.add_session(self.path)

    def check_new(self) -> None:
        """A FileExistsError (pointing to ``--resume``) where the directory holds a run."""
        if self.checkpoint_path.exists() or self.recipe_path.exists() or self.metrics_path.exists():
            raise FileExistsError(
                f"{self.path} already holds a run; continue it with `gcnt train --resume "
                f"{self.path}`"
                + ("" if self.checkpoint_path.exists() else " (no checkpoint yet: from step 0)")
                + " or choose another run_dir=..."
            )

    def save_recipe(self, recipe: Recipe) -> None:
        """Write the resolved recipe (atomically: a killed run keeps the previous file)."""
        recipe.run_dir = str(self.path)
        self.path.mkdir(parents=True, exist_ok=True)
        save_recipe(recipe, self.recipe_path)

    def load_recipe(self, overrides: list[str] | None = None, *, anywhere: bool = False) -> Recipe:
        """The run's recipe to go on with on this machine (:func:`gcnt.run.record.load_run_recipe`:
        ``anywhere`` for a run read, not trained on)."""
        if not self.recipe_path.exists():
            raise FileNotFoundError(f"{self.path}: no {RECIPE_FILE}; is this a gcnt run directory?")
        return load_run_recipe(self.recipe_path, overrides, anywhere=anywhere)

    # --- metrics
    def log_metrics(self, row: dict[str, Any]) -> None:
        with _writing(self.metrics_path, "the metrics"):
            append_text(self.metrics_path, metrics_line(row))

    def read_metrics(self) -> list[dict[str, Any]]:
        """The logged rows (:func:`gcnt.run.metrics.read_metrics`: ``null`` reads back as
        NaN, an incomplete last line is dropped with a warning); a damaged line before it is a
        RunDirError naming the file and line."""
        try:
            return read_metrics(self.metrics_path)
        except MetricsFileError as e:
            raise RunDirError(str(e)) from None

    def claim(self) -> bool:
        """Make the run directory (its parents as needed) in one atomic ``mkdir``: True where
        this process made it, False where it was there already (another start got there
        first, or an earlier one). Only what this process made may it remove
        (:meth:`discard_failed_start`)."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.path.mkdir()
        except FileExistsError:
            return False
        except OSError as e:
            raise RunDirError(
                f"run_dir {self.path}: cannot create the run directory ({e.strerror or e})"
            ) from None
        return True

    def discard_failed_start(self) -> bool:
        """Remove this directory, which a run that failed to start made (:meth:`claim`), if it
        left nothing of value (no checkpoint, no logged row, no evaluation), so that the same
        command can be run again once the cause is fixed; whether it was removed. It is
        removed holding its lock: a directory that another process trains now (a start that
        won the race for it) is left alone."""

        if not self.path.is_dir() or self.path.is_symlink():
            return False
        try:
            with run_lock(self.path):
                if self.has_checkpoint() or (self.path / "eval").exists():
                    return False
                if self.metrics_path.exists() and self.metrics_path.stat().st_size:
                    return False
                shutil.rmtree(self.path, ignore_errors=True)
        except (RunBusyError, RunDirError):
            return False
        return not self.path.exists()

    def set_aside_metrics(self) -> Path | None:
        """Rename the metrics of a run restarted from scratch (killed before its first
        checkpoint) to ``metrics.restartN.jsonl``, so that nothing logged is lost or mixed in."""
        if not self.metrics_path.exists():
            return None
        n = 1
        while (aside := self.path / f"metrics.restart{n}.jsonl").exists():
            n += 1
        with _writing(aside, "the metrics"):
            rename(self.metrics_path, aside)
        return aside

    def truncate_metrics(self, env_steps: int) -> None:
        """Drop lines logged after the checkpoint a resumed run starts from (and an incomplete
        last line)."""
        rows = [r for r in self.read_metrics() if r.get("env_steps", 0) <= env_steps]
        with _writing(self.metrics_path, "the metrics"):
            write_text(self.metrics_path, "".join(metrics_line(r) for r in rows))

    def step_file(self, folder: str, env_steps: int) -> Path:
        """Training's evaluation (``eval``) or video (``videos``) at ``env_steps``."""
        return self.inside(folder) / f"step{env_steps}{STEP_FILES[folder]}"

    def set_aside_after(self, env_steps: int) -> list[Path]:
        """Move the :meth:`step_file` files of steps past ``env_steps`` (a stretch of training
        that a resumed run repeats from its checkpoint, along another trajectory) into
        ``superseded/`` beside them, where no analysis reads them, never over a file there;
        returns their new paths."""
        moved = []
        for folder, suffix in STEP_FILES.items():
            path = self.inside(folder)
            late = sorted(
                f
                for f in (path.glob(f"step*{suffix}") if path.is_dir() else ())
                if f.stem[4:].isdigit() and int(f.stem[4:]) > env_steps
            )
            if not late:
                continue
            aside = self.inside(f"{folder}/{SUPERSEDED}")
            with _writing(aside, "what training wrote after the checkpoint"):
                aside.mkdir(exist_ok=True)
                for f in late:
                    target, n = aside / f.name, 1
                    while target.exists() or target.is_symlink():
                        target, n = aside / f"{f.stem}.{n}{f.suffix}", n + 1
                    rename(f, target)
                    moved.append(target)
        return moved

    # --- checkpoints
    def save_checkpoint(self, state: dict[str, Any]) -> None:
        """Atomic write: a run killed while saving keeps its previous checkpoint. NumPy arrays
        and scalars are stored as tensors and Python numbers (:func:`plain_state`), so that
        the file loads with ``torch.load(..., weights_only=True)``. A failed write (a full
        disk, no permission) removes the temporary file, keeps the previous checkpoint and is
        a RunDirError."""
        self.inside("checkpoints")
        state = plain_state({**state, "rng": rng_state()})
        kept = (
            f"the last good checkpoint {self.checkpoint_path} was kept"
            if self.checkpoint_path.exists()
            else "no checkpoint was written yet"
        )
        try:
            self.checkpoint_path.parent.mkdir(parents=True, exist_ok=True)
            save_torch(state, self.checkpoint_path)
        except (OSError, RuntimeError) as e:  # torch's zip writer reports a failed write as
            # a RuntimeError ("PytorchStreamWriter failed writing file ...")
            raise RunDirError(
                f"{self.checkpoint_path}: cannot write the checkpoint ({_reason(e)}); {kept}"
            ) from None
        log.debug("checkpoint at %s env steps", state.get("env_steps"))

    def has_checkpoint(self) -> bool:
        return self.checkpoint_path.exists()

    def load_checkpoint(self) -> dict[str, Any]:
        """The last checkpoint, read with ``torch.load(..., weights_only=True)``: tensors and
        plain Python types only, so that a checkpoint from someone else cannot run code. Its
        tensors stay on the CPU, whatever device the run trains on: each ``load_state_dict``
        places them (modules and optimisers onto their parameters' devices), and the RNG states
        and NumPy keys must be CPU tensors.
        (Checkpoints written before :func:`plain_state` hold NumPy arrays: NumPy's own array
        reconstruction, :data:`NUMPY_GLOBALS`, is allowed for them.) NumPy arrays saved by an
        algorithm's state come back as tensors, NumPy scalars as Python numbers. A missing,
        unreadable or refused file is a CheckpointError naming it."""
        path = self.checkpoint_path
        if not path.exists():
            raise CheckpointError(f"{self.path}: no checkpoint ({CHECKPOINT})")
        what = "a checkpoint is the file gcnt train writes"
        f = open_regular(path, MAX_CHECKPOINT_BYTES, what, CheckpointError)
        try:
            with f, torch.serialization.safe_globals(NUMPY_GLOBALS):
                state = torch.load(f, map_location="cpu", weights_only=True)
        except Exception as e:  # torch raises many kinds for a truncated or foreign file
            unsafe = _unsafe_globals(path)
            if unsafe:
                raise CheckpointError(
                    f"{path}: refused: loading it would call {', '.join(unsafe[:3])}"
                    f"{' and more' if len(unsafe) > 3 else ''}, which a gcnt checkpoint never "
                    "holds (it could run code); only load checkpoints from people you trust, "
                    "and only as gcnt wrote them"
                ) from None
            raise CheckpointError(
                f"{path}: not a readable gcnt checkpoint ({load_error_detail(e)})"
            ) from None
        if not isinstance(state, dict) or "env_steps" not in state:
            raise CheckpointError(f"{path}: not a gcnt checkpoint")
        check_checkpoint(state, path)
        return state


#: what loading a checkpoint's state into networks and optimisers raises where the state does
#: not fit them (a changed recipe) or was tampered with (a tensor of another shape, a list
#: where a mapping belongs, a missing key)
CHECKPOINT_MISFITS = (ValueError, RuntimeError, KeyError, TypeError, AttributeError, IndexError)

#: what each part of a checkpoint is, where it has one
_CHECKPOINT_PARTS = {"learner": dict, "policy": dict, "rng": dict, "env_steps": int}


def check_checkpoint(state: dict[str, Any], path: Path) -> None:
    """A CheckpointError naming ``path`` for a checkpoint no training writes: a part of the
    wrong type (``learner`` not a mapping, ``env_steps`` not a whole number), or weights or
    optimiser moments that are not finite (NaN, infinite): gcnt stops a diverged run before
    it checkpoints."""
    for key, kind in _CHECKPOINT_PARTS.items():
        value = state.get(key, kind())
        if not isinstance(value, kind) or isinstance(value, bool):
            raise CheckpointError(
                f"{path}: {key} is {type(value).__name__}, not {_KIND_NAMES[kind]}; not a "
                "checkpoint gcnt wrote"
            )
    if state["env_steps"] < 0:
        raise CheckpointError(f"{path}: env_steps is negative; not a checkpoint gcnt wrote")
    stack: list[tuple[str, Any]] = [(k, v) for k, v in state.items() if k != "rng"]
    while stack:
        name, value = stack.pop()
        if isinstance(value, dict):
            stack.extend((f"{name}.{k}", v) for k, v in value.items())
        elif isinstance(value, list | tuple):
            stack.extend((f"{name}.{i}", v) for i, v in enumerate(value))
        elif isinstance(value, torch.Tensor) and value.is_floating_point():
            if not bool(torch.isfinite(value).all()):
                raise CheckpointError(
                    f"{path}: {name} holds NaN or infinite values; a checkpoint gcnt writes "
                    "holds finite weights"
                )


_KIND_NAMES = {dict: "a mapping", int: "a whole number"}


def load_error_detail(e: Exception) -> str:
    """The first line of a ``torch.load`` error, without torch's advice to load with
    ``weights_only=False``: gcnt never loads a file that way (it could run code)."""
    lines = [line for line in str(e).splitlines() if line.strip()]
    first = lines[0] if lines else "no detail"
    if "weights_only" in first or "Weights only" in first:
        first = "not a file torch can read as tensors and plain values"
    return f"{type(e).__name__}: {first}"


#: the largest checkpoint read (networks, optimiser state and counters; the replay is a file of
#: its own): a paper-scale checkpoint is tens of MiB
MAX_CHECKPOINT_BYTES = 16 * GiB

#: NumPy's array and scalar reconstruction, allowed under ``weights_only=True`` for checkpoints
#: that hold NumPy arrays: they build an array or scalar from a dtype and raw bytes; an object
#: array's items go through the same restricted unpickler. Numeric dtypes only.
_multiarray = np._core.multiarray if hasattr(np, "_core") else np.core.multiarray
NUMPY_GLOBALS: list = [
    # each under the module name of NumPy 2 and of NumPy 1 (numpy._core, numpy.core)
    *(
        (f, f"numpy.{core}.multiarray.{f.__name__}")
        for f in (_multiarray._reconstruct, _multiarray.scalar)
        for core in ("_core", "core")
    ),
    np.ndarray,
    np.dtype,
    *(
        type(np.dtype(t))
        for t in ("bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32",
                  "uint64", "float16", "float32", "float64")
    ),
]  # fmt: skip


def _unsafe_globals(path: Path) -> list[str]:
    """The globals a checkpoint's pickle names beyond tensors, plain types and
    :data:`NUMPY_GLOBALS` (read from its opcodes, nothing is run); empty when none or the file
    is no readable torch checkpoint."""
    allowed = {
        g[1] if isinstance(g, tuple) else f"{g.__module__}.{g.__qualname__}" for g in NUMPY_GLOBALS
    }
    try:
        names = torch.serialization.get_unsafe_globals_in_checkpoint(path)
    except Exception:  # noqa: BLE001 - a truncated or foreign file: reported as unreadable
        return []
    return [n for n in names if n not in allowed]


def plain_state(value: Any) -> Any:
    """``value`` with NumPy arrays as tensors and NumPy scalars as Python numbers, through
    dicts, lists and tuples: what ``torch.load(..., weights_only=True)`` reads without
    allowing any NumPy code. Tensors are detached CPU tensors (a checkpoint written on a GPU
    loads anywhere; CPU tensors are kept as they are); other values are kept as they are."""
    if isinstance(value, torch.Tensor):
        if value.device.type == "cpu" and not value.requires_grad:
            return value
        return value.detach().cpu()
    if isinstance(value, np.ndarray):
        return torch.from_numpy(np.array(value, copy=True))
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, OrderedDict):
        return OrderedDict((k, plain_state(v)) for k, v in value.items())
    if isinstance(value, dict):
        return {k: plain_state(v) for k, v in value.items()}
    if type(value) in (list, tuple):
        return type(value)(plain_state(v) for v in value)
    return value


@contextlib.contextmanager
def _writing(path: Path, what: str) -> Iterator[None]:
    """An OSError while writing ``what`` to ``path`` as a one-line RunDirError."""
    try:
        yield
    except OSError as e:
        raise RunDirError(f"{path}: cannot write {what} ({_reason(e)})") from None


def _reason(e: BaseException) -> str:
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    return str(e).splitlines()[0] if str(e) else type(e).__name__


def rng_state() -> dict[str, Any]:
    """The process's global random state: torch (CPU, and every CUDA device once CUDA is in
    use: target noise and on-device replay draws come from there), NumPy and Python."""
    state = {
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),
        "python": random.getstate(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore :func:`rng_state`, as taken or as a checkpoint stores it (:func:`plain_state`:
    NumPy's key as a tensor); a CUDA state only where CUDA is available."""
    torch.set_rng_state(state["torch"])
    kind, key, *rest = state["numpy"]
    np.random.set_state((kind, np.asarray(key, dtype=np.uint32), *rest))
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed)
    random.seed(seed)


def folder_name(text: str) -> str:
    """``text`` as one folder name: ``Walker++`` -> ``Walkerpp``, other signs -> ``-``."""
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in text.replace("+", "p"))
