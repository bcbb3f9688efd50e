"""A run's directory: resolved recipe, metrics, checkpoints, eval results, videos.

Nothing here depends on W&B being reachable: ``metrics.jsonl`` (one JSON line per log step) is the
local record, and W&B (offline by default) or CSV logging mirrors it through torchrl's loggers.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gcnt.recipes import Recipe, RecipeError, load_recipe, save_recipe

log = logging.getLogger(__name__)

RECIPE_FILE = "recipe.yaml"
METRICS_FILE = "metrics.jsonl"
CHECKPOINT = "checkpoints/last.pt"


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable or does not fit the run's networks."""


class RunDirError(ValueError):
    """A run directory that cannot be made or written (a file in the way, no permission)."""


class RunDir:
    def __init__(self, path: str | Path):
        self.path = Path(path)

    @classmethod
    def for_recipe(cls, recipe: Recipe) -> RunDir:
        """The recipe's ``run_dir``, or a fresh ``runs/<benchmark>/<method>/seed<seed>[-N]``."""
        if recipe.run_dir:
            return cls(recipe.run_dir)
        method = f"{recipe.algo}-{recipe.network.name}"
        base = Path("runs") / _slug(recipe.task) / method / f"seed{recipe.seed}"
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

    @property
    def buffers_dir(self) -> Path:
        """Where an algorithm may checkpoint large data (replay buffers)."""
        return self.path / "checkpoints" / "buffers"

    def create(self, recipe: Recipe) -> None:
        """Make the directory and write the recipe; an existing run is never overwritten."""
        if self.checkpoint_path.exists() or self.recipe_path.exists() or self.metrics_path.exists():
            raise FileExistsError(
                f"{self.path} already holds a run; continue it with `gcnt train --resume "
                f"{self.path}` or choose another run_dir=..."
            )
        try:
            (self.path / "checkpoints").mkdir(parents=True, exist_ok=True)
            self.save_recipe(recipe)
        except OSError as e:
            raise RunDirError(
                f"run_dir {self.path}: cannot create the run directory ({e.strerror or e}"
                f"{': ' + str(e.filename) if e.filename else ''})"
            ) from None

    def save_recipe(self, recipe: Recipe) -> None:
        """Write the resolved recipe (atomically: a killed run keeps the previous file)."""
        recipe.run_dir = str(self.path)
        self.path.mkdir(parents=True, exist_ok=True)
        tmp = self.recipe_path.with_suffix(".tmp")
        save_recipe(recipe, tmp)
        os.replace(tmp, self.recipe_path)

    def load_recipe(self, overrides: list[str] | None = None) -> Recipe:
        if not self.recipe_path.exists():
            raise FileNotFoundError(f"{self.path}: no {RECIPE_FILE}; is this a gcnt run directory?")
        return load_recipe(self.recipe_path, overrides)

    # --- metrics
    def log_metrics(self, row: dict[str, Any]) -> None:
        with self.metrics_path.open("a") as f:
            f.write(metrics_line(row))

    def read_metrics(self) -> list[dict[str, Any]]:
        """The logged rows; ``null`` (a non-finite value) reads back as NaN."""
        if not self.metrics_path.exists():
            return []
        lines = self.metrics_path.read_text().splitlines()
        return [read_metrics_row(json.loads(line)) for line in lines if line]

    def set_aside_metrics(self) -> Path | None:
        """Rename the metrics of a run restarted from scratch (killed before its first
        checkpoint) to ``metrics.restartN.jsonl``, so that nothing logged is lost or mixed in."""
        if not self.metrics_path.exists():
            return None
        n = 1
        while (aside := self.path / f"metrics.restart{n}.jsonl").exists():
            n += 1
        os.replace(self.metrics_path, aside)
        return aside

    def truncate_metrics(self, env_steps: int) -> None:
        """Drop lines logged after the checkpoint a resumed run starts from."""
        rows = [r for r in self.read_metrics() if r.get("env_steps", 0) <= env_steps]
        tmp = self.metrics_path.with_suffix(".tmp")
        tmp.write_text("".join(metrics_line(r) for r in rows))
        os.replace(tmp, self.metrics_path)

    # --- checkpoints
    def save_checkpoint(self, state: dict[str, Any]) -> None:
        """Atomic write: a run killed while saving keeps its previous checkpoint."""
        state = {**state, "rng": rng_state()}
        tmp = self.checkpoint_path.with_suffix(".tmp")
        tmp.parent.mkdir(parents=True, exist_ok=True)
        torch.save(state, tmp)
        os.replace(tmp, self.checkpoint_path)
        log.debug("checkpoint at %s env steps", state.get("env_steps"))

    def has_checkpoint(self) -> bool:
        return self.checkpoint_path.exists()

    def load_checkpoint(self, map_location: str | torch.device = "cpu") -> dict[str, Any]:
        """The last checkpoint; a missing or unreadable file is a CheckpointError naming it."""
        if not self.checkpoint_path.exists():
            raise CheckpointError(f"{self.path}: no checkpoint ({CHECKPOINT})")
        try:
            state = torch.load(self.checkpoint_path, map_location=map_location, weights_only=False)
        except Exception as e:  # torch raises many kinds for a truncated or foreign file
            raise CheckpointError(
                f"{self.checkpoint_path}: not a readable gcnt checkpoint ({type(e).__name__}: "
                f"{str(e).splitlines()[0] if str(e) else 'no detail'})"
            ) from None
        if not isinstance(state, dict) or "env_steps" not in state:
            raise CheckpointError(f"{self.checkpoint_path}: not a gcnt checkpoint")
        return state


def strict_json(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, ±inf) replaced by None, so that ``json.dumps``
    writes ``null`` (strict JSON has no ``NaN``); dicts, lists and tuples are copied."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict_json(v) for v in value]
    return value


def metrics_line(row: dict[str, Any]) -> str:
    """One ``metrics.jsonl`` line: strict JSON (non-finite values as ``null``), keys sorted."""
    return json.dumps(strict_json(row), sort_keys=True, allow_nan=False) + "\n"


def read_metrics_row(row: Any) -> Any:
    """A metrics row as read from JSON, with ``null`` values back as NaN (what was logged)."""
    if not isinstance(row, dict):
        return row
    return {k: math.nan if v is None else v for k, v in row.items()}


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
    """Restore :func:`rng_state` (a CUDA state only where CUDA is available)."""
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed)
    random.seed(seed)


def check_logger(recipe: Recipe) -> None:
    """W&B online logging needs credentials: a RecipeError before a run starts, not W&B's
    traceback after its directory exists."""
    cfg = recipe.logger
    if cfg.backend != "wandb" or cfg.mode != "online":
        return
    import wandb

    try:
        ok = wandb.login(verify=False, prompt=False)
    except Exception as e:  # an API key of a malformed shape
        raise RecipeError(f"logger.mode=online: W&B cannot log in ({e})") from None
    if not ok:
        raise RecipeError(
            "logger.mode=online but W&B has no API key: run `wandb login` or set WANDB_API_KEY, "
            "or log offline (logger.mode=offline) and `wandb sync` later"
        )


def make_logger(recipe: Recipe, run: RunDir, *, concurrent: bool = False):
    """torchrl logger per the recipe (None for backend "none"). ``concurrent``: other runs of
    this process log at the same time (each W&B run is then created beside the others)."""
    cfg = recipe.logger
    method = recipe.network.name
    name = cfg.name or f"{recipe.task}-{recipe.algo}-{method}-seed{recipe.seed}"
    if cfg.backend == "none":
        return None
    if cfg.backend == "csv":
        from torchrl.record.loggers import CSVLogger

        return CSVLogger(exp_name=name, log_dir=str(run.path / "csv"))
    from torchrl.record.loggers import WandbLogger

    os.environ.setdefault("WANDB_SILENT", "true")
    project = cfg.project or f"gcnt-{_slug(recipe.env.benchmark)}"
    group = cfg.group or f"{recipe.task}-{recipe.algo}-{method}"
    return WandbLogger(
        exp_name=name,
        offline=cfg.mode == "offline",
        save_dir=str(run.path),
        project=project,
        group=group,
        config={**recipe.to_dict(), "method": method},
        # stable across processes, so a resumed run continues the same W&B run
        id=_slug(f"{name}-{hashlib.md5(str(run.path.resolve()).encode()).hexdigest()[:8]}"),
        resume="allow",
        **({"reinit": "create_new"} if concurrent else {}),
    )


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in text.replace("+", "p"))
