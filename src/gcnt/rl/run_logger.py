"""What a run sends to its torchrl logger (W&B or CSV): one row per log step.

All of one env step's values (the training row, and the evaluation that ran at that step) go to
the logger in one ``log_metrics`` call, so that a W&B run has one history row per log step, each
metric plotted against env steps (torchrl's ``WandbLogger`` adds the step to every row). On
W&B, an evaluation's video joins its row, and the final evaluation per robot goes to the run's
summary.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gcnt.recipes import Recipe, RecipeError
from gcnt.run import provenance
from gcnt.run.directory import RunDir, folder_name

if TYPE_CHECKING:  # annotations only
    from gcnt.morphology import Robot

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


def check_logger(recipe: Recipe) -> None:
    """W&B's tags and online logging's credentials: a RecipeError before a run starts, not
    W&B's traceback after its directory exists."""
    cfg = recipe.logger
    if cfg.backend != "wandb":
        return
    for tag in cfg.tags:
        if not 1 <= len(tag) <= MAX_TAG:
            raise RecipeError(
                f"logger.tags: {tag!r} has {len(tag)} characters; W&B takes 1 to {MAX_TAG}"
            )
    if cfg.mode != "online":
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


#: W&B's longest tag
MAX_TAG = 64


def make_logger(
    recipe: Recipe, run: RunDir, robots: Sequence[Robot] = (), *, concurrent: bool = False
) -> RunLogger | None:
    """The run's torchrl logger per the recipe, fed one row per log step
    (:class:`gcnt.rl.run_logger.RunLogger`; None for backend "none"). ``concurrent``: other runs
    of this process log at the same time (each W&B run is then created beside the others).

    A W&B run is tagged ``seed:N`` (and ``logger.tags``); its config is the recipe, the method,
    the training ``robots`` (name: hash of the robot's MJCF) and the code of the running process
    (gcnt version, commit, uncommitted changes, plugin files). A resumed run
    continues the same W&B run (:func:`wandb_id`), but W&B writes each session to a folder of
    its own (``<run>/wandb/offline-run-<start time>-<id>``, whatever ``resume`` says); ``wandb
    sync`` uploads a run's folders into that one W&B run, in the order they were started."""
    cfg = recipe.logger
    method = recipe.network.name
    name = cfg.name or f"{recipe.task}-{recipe.algo}-{method}-seed{recipe.seed}"
    if cfg.backend == "none":
        return None
    if cfg.backend == "csv":
        from torchrl.record.loggers import CSVLogger

        return RunLogger(CSVLogger(exp_name=name, log_dir=str(run.inside("csv"))))
    from torchrl.record.loggers import WandbLogger

    os.environ.setdefault("WANDB_SILENT", "true")
    project = cfg.project or f"gcnt-{folder_name(recipe.env.benchmark)}"
    group = cfg.group or f"{recipe.task}-{recipe.algo}-{method}"
    logger = WandbLogger(
        exp_name=name,
        offline=cfg.mode == "offline",
        # also to wandb.init itself: W&B keeps the settings of its first use in a process, so
        # torchrl's WANDB_MODE variable alone does not make a later run offline
        mode=cfg.mode,
        save_dir=str(run.path),
        project=project,
        group=group,
        tags=list(dict.fromkeys([*cfg.tags, f"seed:{recipe.seed}"])),
        config={
            **recipe.to_dict(),
            "method": method,
            "code": _code(run),
            "robots": {r.name: robot_hash(r) for r in robots},
        },
        id=wandb_id(run, name),
        resume="allow",
        # torchrl would write the Python packages into config["env"], over the recipe's env
        # section (benchmark, robots, world); the run's code is in config["code"]
        log_env_packages=False,
        **({"reinit": "create_new"} if concurrent else {}),
    )
    return RunLogger(logger)


def robot_hash(robot: Robot) -> str:
    """A short hash of a robot's MJCF text: equal robots, equal hashes, whatever their files."""
    return hashlib.sha256(robot.xml.encode()).hexdigest()[:16]


def wandb_id(run: RunDir, name: str) -> str:
    """The W&B run id of ``run``: the one its earlier trainings used (W&B names each session's
    ``run-<id>.wandb`` file after it), so that a resumed run continues the same W&B run even
    after its directory was moved or its ``logger.name`` changed; for a new run, ``name`` and
    a hash of the directory's path."""
    for f in sorted(run.inside("wandb").glob("*run-*/run-*.wandb")):
        return f.stem[len("run-") :]
    return folder_name(f"{name}-{hashlib.md5(str(run.path.resolve()).encode()).hexdigest()[:8]}")


def _code(run: RunDir) -> dict[str, Any]:
    """gcnt version, commit, uncommitted changes and plugins (name, sha256) of the run's latest
    session (empty where the run has no readable provenance)."""
    try:
        sessions = provenance.read_sessions(run.path)
    except provenance.ProvenanceError:
        sessions = []
    last = sessions[-1] if sessions else {}
    return {k: last[k] for k in ("gcnt_version", "git_commit", "git_dirty", "plugins") if k in last}
