"""What a run sends to its torchrl logger (W&B or CSV): one row per log step.

All of one env step's values (the training row, and the evaluation that ran at that step) go to
the logger in one ``log_metrics`` call, so that a W&B run has one history row per log step, each
metric plotted against env steps (torchrl's ``WandbLogger`` adds the step to every row). On
W&B, an evaluation's video joins its row, and the final evaluation per robot goes to the run's
summary.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: the W&B summary key of the final evaluation (per robot: mean, stderr, episodes)
FINAL_EVAL = "final_eval"


class RunLogger:
    """A run's torchrl ``logger``, fed by the training loop through :meth:`add`; a row is
    sent when the next step's values arrive, at :meth:`flush` or at :meth:`close`."""

    def __init__(self, logger: Any) -> None:
        self.logger = logger
        self._step: int | None = None
        self._row: dict[str, Any] = {}

    @property
    def wandb(self) -> Any | None:
        """The W&B run (None for another backend)."""
        from torchrl.record.loggers import WandbLogger

        return self.logger.experiment if isinstance(self.logger, WandbLogger) else None

    def add(self, env_steps: int, values: dict[str, Any]) -> None:
        """Values of the row at ``env_steps`` (a row of an earlier step is sent first)."""
        if self._step is not None and env_steps != self._step:
            self.flush()
        self._step = env_steps
        self._row.update(values)

    def add_video(self, env_steps: int, path: Path, key: str = "eval_video") -> None:
        """An evaluation's video file into the row at ``env_steps`` (W&B only)."""
        if self.wandb is None:
            return
        import wandb

        self.add(env_steps, {key: wandb.Video(str(path), format=Path(path).suffix[1:])})

    def flush(self) -> None:
        """Send the row being gathered, if any."""
        if self._row:
            self.logger.log_metrics(self._row, step=self._step)
        self._step, self._row = None, {}

    def summarize(self, results: dict[str, dict], env_steps: int) -> None:
        """The final evaluation (``{robot: summary}``) into the W&B run's summary."""
        if self.wandb is None:
            return
        keep = ("mean", "stderr", "episodes")
        self.wandb.summary[FINAL_EVAL] = {
            "env_steps": env_steps,
            **{name: {k: res[k] for k in keep if k in res} for name, res in results.items()},
        }

    def save_files(self, *paths: Path, base: Path) -> None:
        """Files of the run directory (its recipe and provenance) among the W&B run's files."""
        if self.wandb is None:
            return
        for path in paths:
            if path.is_file():
                self.wandb.save(str(path), base_path=str(base), policy="now")

    def close(self) -> None:
        """Send the last row and end the W&B run."""
        self.flush()
        if self.wandb is not None:
            self.wandb.finish()
