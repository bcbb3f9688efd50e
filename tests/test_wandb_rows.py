"""What an offline W&B run holds, read back from its ``run-*.wandb`` file with W&B's own reader
(``wandb leet inspect``, no network): one history row per log step with the evaluation in the
row of its step, the evaluation video, the final evaluation in the summary, the run's record in
its config and its recipe among its files."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gcnt import plugins
from gcnt.cli import main
from gcnt.morphology import smpenv_robot
from gcnt.rl.run_logger import FINAL_EVAL, robot_hash
from gcnt.run.directory import RunDir


def _records(run: Path) -> list[dict]:
    wandb = shutil.which("wandb") or str(Path(sys.executable).parent / "wandb")
    (folder,) = (run / "wandb").glob("offline-run-*")
    out = subprocess.run(
        [wandb, "leet", "inspect", "--json", str(folder)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout.splitlines()
    return [json.loads(x) for x in out if x.startswith("{")]


@pytest.mark.slow
def test_an_offline_wandb_run_has_one_row_per_log_step_the_video_and_the_summary(
    tmp_path: Path, recipe_file: Path, monkeypatch
) -> None:
    monkeypatch.setenv("WANDB_CONFIG_DIR", str(tmp_path / "wandb-config"))
    run = tmp_path / "run"
    argv = ["train", str(recipe_file), f"run_dir={run}", "logger.backend=wandb",
            "eval.interval=20", "eval.video=true"]  # fmt: skip
    assert main(argv) == 0
    records = _records(run)
    history = [r["history"]["item"] for r in records if r["type"] == "history"]
    rows = RunDir(run).read_metrics()

    # one W&B row per metrics.jsonl row, each at its env steps, all of the row's values in it
    assert [h["step"] for h in history] == [r["env_steps"] for r in rows] == [20, 40]
    for h, row in zip(history, rows, strict=True):
        assert h["train_return/step"] == row["env_steps"]
        assert h["loss_critic"] == pytest.approx(row["loss_critic"], rel=1e-12)
        # the evaluation of that step in the same row (the one at 20 and the final one)
        evaluation = json.loads((run / "eval" / f"step{row['env_steps']}.json").read_text())
        assert h["eval_return/step"] == row["env_steps"]
        for name, res in evaluation["robots"].items():
            assert h[f"eval_return/{name}"] == pytest.approx(res["mean"], rel=1e-12)
        means = [res["mean"] for res in evaluation["robots"].values()]
        assert h["eval_return/mean"] == pytest.approx(sum(means) / len(means), rel=1e-12)
        # each evaluation's video joins its row, and the file is among the run's files
        assert h["eval_video._type"] == "video-file"
        folder = next((run / "wandb").glob("offline-run-*"))
        assert (folder / "files" / h["eval_video.path"]).stat().st_size > 0

    # the final evaluation per robot in the run's summary
    final = json.loads((run / "eval" / "step40.json").read_text())["robots"]
    (summary,) = [r["summary"]["update"][FINAL_EVAL] for r in records
                  if r["type"] == "summary" and FINAL_EVAL in r["summary"].get("update", {})]  # fmt: skip
    assert summary["env_steps"] == 40 and set(summary) == {"env_steps", *final}
    for name, res in final.items():
        assert summary[name]["mean"] == pytest.approx(res["mean"], rel=1e-12)
        assert summary[name]["episodes"] == res["episodes"]

    # the run's record: its recipe, robots (name: hash of the MJCF), code; recipe and provenance
    # among the run's files
    config = next(r["run"] for r in records if r["type"] == "run")["config"]["update"]
    assert config["robots"] == {"hopper_3": robot_hash(smpenv_robot("hopper_3"))}
    # the plugins this process imported (earlier tests' included), as the run's provenance has them
    assert config["code"]["plugins"] == plugins.identities(via=True)
    assert config["collector"]["total_frames"] == 40
    # the recipe's env section as the recipe has it, in every config record (torchrl's package
    # listing would replace it)
    envs = [r["config"]["update"]["env"] for r in records
            if r["type"] == "config" and "env" in r["config"].get("update", {})]  # fmt: skip
    for env in [config["env"], *envs]:
        assert env["benchmark"] == "smpenv" and env["robots"] == ["hopper_3"]
    saved = {f["path"] for r in records if r["type"] == "files" for f in r["files"]["files"]}
    assert {"recipe.yaml", "provenance.json"} <= saved


@pytest.mark.slow
def test_the_wandb_video_shows_every_training_robot(tmp_path: Path, recipe_file: Path, monkeypatch):
    """Three training robots: the evaluation video W&B holds tiles them in a 2 x 2 grid, each
    tile a scene, the fourth black."""
    imageio = pytest.importorskip("imageio.v2")
    monkeypatch.setenv("WANDB_CONFIG_DIR", str(tmp_path / "wandb-config"))
    run = tmp_path / "run"
    argv = ["train", str(recipe_file), f"run_dir={run}", "logger.backend=wandb",
            "env.robots=[hopper_3, hopper_5, walker_2_main]", "eval.video=true",
            "collector.total_frames=90"]  # fmt: skip
    assert main(argv) == 0
    history = [r["history"]["item"] for r in _records(run) if r["type"] == "history"]
    (path,) = {h["eval_video.path"] for h in history if "eval_video.path" in h}
    folder = next((run / "wandb").glob("offline-run-*"))
    reader = imageio.get_reader(str(folder / "files" / path))
    frame = reader.get_data(0)
    h, w = frame.shape[0] // 2, frame.shape[1] // 2
    tiles = [frame[r : r + h, c : c + w] for r in (0, h) for c in (0, w)]
    assert all(t.std() > 0 for t in tiles[:3]) and tiles[3].max() <= 16
