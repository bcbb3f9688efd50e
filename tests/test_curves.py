"""``gcnt curves``: rows at the logged env steps (a common grid only where seeds log at different
steps), the training evaluations' return as a curve (``--metric eval``), the end of the random
phase from the recipe, per-robot runs averaged per seed, and ``null`` in metrics read as missing.

Run directories are written as runs write them: ``recipe.yaml`` (with ``resolved:``),
``metrics.jsonl`` through ``RunDir.log_metrics`` and ``eval/step<N>.json`` through
``write_eval``.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest
import yaml

from gcnt.analysis import curves
from gcnt.analysis.runs import default_out, find_runs
from gcnt.cli import main
from gcnt.rl.evaluate import summarize, write_eval
from gcnt.run.directory import RunDir

TRAIN = ["walker_2_main", "walker_4_main"]
TEST = ["walker_3_main"]


def make_run(
    root: Path,
    method: str,
    seed: int,
    steps: list[int],
    value,
    *,
    robots: list[str] | None = None,
    random_frames: int = 600,
    deterministic: bool = True,
    total_frames: int | None = None,
) -> Path:
    """A run logging ``value(step)`` as its training return and evaluating at every step."""
    robots = robots or TRAIN
    path = root / method / "_".join(robots) / f"seed{seed}"
    path.mkdir(parents=True)
    recipe = {
        "task": "Walker++",
        "algo": "td3",
        "seed": seed,
        "env": {"benchmark": "smpenv", "robots": robots, "test_robots": TEST},
        "collector": {"total_frames": total_frames or steps[-1]},
        "network": {"name": method},
        "td3": {"init_random_frames": 500},
        "eval": {"deterministic": deterministic},
        "resolved": {"init_random_frames": random_frames},
    }
    (path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    run = RunDir(path)
    for s in steps:
        run.log_metrics({"env_steps": s, "train_return/mean": value(s), "loss_actor": math.nan})
        results = {r: summarize([10 * value(s)] * 2) for r in robots}
        results[TEST[0]] = summarize([-1000.0] * 2)  # a test robot: not in the curve
        meta = {"robots_spec": robots + TEST, "episodes": 2, "deterministic": deterministic}
        write_eval(path / "eval" / f"step{s}.json", results, s, meta)
    return path


def read_csv(path: Path) -> list[dict]:
    return list(csv.DictReader(path.open()))


def test_rows_are_the_logged_steps(tmp_path: Path) -> None:
    for seed in (0, 1):
        make_run(tmp_path, "gcnt", seed, [600, 1200, 1800, 2400], lambda s, k=seed: s / 100 + k)
    rows = curves.learning_curves(find_runs([tmp_path]))
    assert [r["env_steps"] for r in rows] == [600, 1200, 1800, 2400]
    assert all(r["logged"] == 2 and r["seeds"] == 2 for r in rows)
    assert rows[-1]["mean"] == pytest.approx(24.5) and rows[-1]["stderr"] == pytest.approx(0.5)


def test_seeds_logging_at_different_steps_meet_on_the_union_of_their_steps(
    tmp_path: Path,
) -> None:
    make_run(tmp_path, "gcnt", 0, [500, 1000, 2000, 3000], lambda s: s / 100)
    # a seed of the same budget still running
    make_run(tmp_path, "gcnt", 1, [800, 1600, 2400], lambda s: s / 100 + 1, total_frames=3000)
    rows = curves.learning_curves(find_runs([tmp_path]))
    # from the later first step (800) to the earlier last one (2400)
    assert [(r["env_steps"], r["logged"]) for r in rows] == [
        (800, 1),
        (1000, 1),
        (1600, 1),
        (2000, 1),
        (2400, 1),
    ]
    # both are linear: the mean is exact at every row
    assert [r["mean"] for r in rows] == pytest.approx([r["env_steps"] / 100 + 0.5 for r in rows])


def test_eval_metric_is_the_training_robots_evaluation_return(tmp_path: Path) -> None:
    for seed in (0, 1):
        make_run(tmp_path, "gcnt", seed, [600, 1200], lambda s, k=seed: s / 100 + k)
    runs = find_runs([tmp_path])
    rows = curves.learning_curves(runs, "eval")
    # 10 x the training return on the training robots; the test robot (-1000) left out
    assert [(r["env_steps"], r["mean"]) for r in rows] == [(600, 65.0), (1200, 125.0)]
    one = curves.learning_curves(runs, f"eval/{TEST[0]}")
    assert one[0]["mean"] == -1000.0
    label = curves.metric_label(runs, "eval")
    assert "evaluation return" in label and "deterministic actions, 2 episodes" in label
    assert curves.metric_label(runs, "train_return/mean").startswith("training return")
    # the run's own random phase (resolved, rounded to whole batches), not td3's setting
    assert curves.random_phase(runs) == {"Walker++": [600]}


def test_per_robot_runs_are_averaged_per_seed(tmp_path: Path) -> None:
    """Two seeds x two single-robot runs: each seed is the mean over its robots first."""
    for seed in (0, 1):
        for k, robot in enumerate(TRAIN):
            make_run(tmp_path, "sr", seed, [600, 1200], lambda s, a=seed + 2 * k: a, robots=[robot])
    rows = curves.learning_curves(find_runs([tmp_path]))
    # seed 0: mean(0, 2) = 1; seed 1: mean(1, 3) = 2; over seeds 1.5 ± 0.5
    assert [(r["seeds"], r["robots"], r["logged"]) for r in rows] == [(2, 2, 2)] * 2
    assert rows[0]["mean"] == pytest.approx(1.5) and rows[0]["stderr"] == pytest.approx(0.5)


def test_curves_command_eval_metric_and_null_metrics(tmp_path: Path, capsys) -> None:
    for seed in (0, 1):
        make_run(tmp_path, "gcnt", seed, [600, 1200, 1800], lambda s: s / 100)
    # loss_actor was NaN at every step: logged as null, read as missing
    line = (tmp_path / "gcnt" / "_".join(TRAIN) / "seed0" / "metrics.jsonl").read_text()
    assert '"loss_actor": null' in line and "NaN" not in line
    assert main(["curves", str(tmp_path), "--metric", "loss_actor"]) == 2
    assert main(["curves", str(tmp_path), "--metric", "eval"]) == 0
    assert "evaluation return" in capsys.readouterr().out
    rows = read_csv(tmp_path / "figures" / "curves.csv")
    assert [r["env_steps"] for r in rows] == ["600", "1200", "1800"]
    assert (tmp_path / "figures" / "curves.png").read_bytes()[:4] == b"\x89PNG"
    # an even grid only when asked for
    assert main(["curves", str(tmp_path), "--points", "5"]) == 0
    assert len(read_csv(tmp_path / "figures" / "curves.csv")) == 5
    assert main(["curves", str(tmp_path), "--points", "1"]) == 2


def test_a_run_directory_given_alone_gets_its_outputs_beside_it(tmp_path: Path, monkeypatch):
    """curves and zeroshot on one run directory write <run>-figures beside it, nothing into it;
    a folder of runs keeps <dir>/figures."""
    from test_variants import gcnt_eval

    run = make_run(tmp_path / "received", "gcnt", 0, [600, 1200], lambda s: s / 100)
    gcnt_eval(run, {TEST[0]: 5.0})
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    assert main(["curves", str(run)]) == 0
    assert main(["zeroshot", str(run)]) == 0
    beside = run.with_name("seed0-figures")
    assert (beside / "curves.csv").is_file() and (beside / "zeroshot.md").is_file()
    assert sorted(p.relative_to(run) for p in run.rglob("*")) == before
    monkeypatch.chdir(run)  # named as "."
    assert default_out(["."]) == beside
    assert default_out([tmp_path / "received"]) == tmp_path / "received" / "figures"
    assert default_out([run, run]) == Path("figures")


def test_a_non_finite_return_is_a_gap_with_a_warning_not_a_line_across(tmp_path, capsys):
    """A diverged seed's NaN return must not be interpolated away: the mean is NaN there (a
    gap in the figure, an empty cell in the CSV) and the run and step are named."""
    make_run(tmp_path, "gcnt", 0, [600, 1200, 1800], lambda s: s / 100)
    make_run(tmp_path, "gcnt", 1, [600, 1200, 1800], lambda s: math.nan if s == 1200 else s / 100)
    assert main(["curves", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "seed1" in err and "not finite at 1 logged step(s) (1200)" in err
    rows = read_csv(tmp_path / "figures" / "curves.csv")
    by_step = {r["env_steps"]: r["mean"] for r in rows}
    assert math.isnan(float(by_step["1200"]))
    assert float(by_step["600"]) == pytest.approx(6.0) and float(by_step["1800"]) == 18.0


def test_a_folder_it_cannot_write_is_one_error_line(tmp_path, capsys, monkeypatch):
    """A read-only run directory (simulated: tests may run as root, which writes anywhere) or a
    full disk while writing the figures is one line that says how to write elsewhere."""
    import errno

    make_run(tmp_path, "gcnt", 0, [600, 1200], lambda s: s / 100)

    def read_only(rows, path):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(curves, "write_csv", read_only)
    capsys.readouterr()
    assert main(["curves", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "curves.csv: cannot write (Permission denied); --out DIR writes elsewhere" in err


def test_names_keys_that_name_nothing_shown_are_an_error_with_a_suggestion(tmp_path, capsys):
    from cli_helpers import error_line

    make_run(tmp_path, "gcnt", 0, [600, 1200], lambda s: s / 100)
    out = ["--out", str(tmp_path / "fig")]
    line = error_line(capsys, ["curves", str(tmp_path), "--names", "GCNT=Ours", *out])
    assert "--names GCNT: no method, task or robot set here is called 'GCNT'" in line
    assert "did you mean 'gcnt'?" in line and not (tmp_path / "fig").exists()
    line = error_line(capsys, ["zeroshot", str(tmp_path), "--names", "Walker+=W", *out])
    assert "did you mean 'Walker++'?" in line
    # what is shown: its method and task, by id, folder spelling or with an addition
    names = "gcnt=Ours,Walkerpp=Walker,gcnt [td3.lr=0.001]=Ours-lr,td3:gcnt=Ours-TD3"
    assert main(["curves", str(tmp_path), "--names", names, *out]) == 0
    # a names file may serve several figures: any method or task of the default tables
    shared = tmp_path / "names.yaml"
    shared.write_text("gcnt: Ours\nmetamorph_star: MM*\nCWHH++: CWHH\n")
    assert main(["curves", str(tmp_path), "--names", str(shared), *out]) == 0
    shared.write_text("gcnt: Ours\nmetamorph_str: MM*\n")
    line = error_line(capsys, ["curves", str(tmp_path), "--names", str(shared), *out])
    assert "--names metamorph_str" in line and "did you mean 'metamorph_star'" in line


def test_per_seed_rows_hold_every_runs_own_points_and_episode_lengths(tmp_path: Path) -> None:
    for seed in (0, 1):
        path = make_run(tmp_path, "gcnt", seed, [600, 1200], lambda s, k=seed: s / 100 + k)
        run = RunDir(path)
        run.log_metrics({"env_steps": 1800, "train_return/mean": 30.0 + seed,
                         "train_length/mean": 100.0 + seed})  # fmt: skip
    assert main(["curves", str(tmp_path), "--per-seed"]) == 0
    rows = read_csv(tmp_path / "figures" / "curves.seeds.csv")
    assert [(r["seed"], r["env_steps"]) for r in rows] == [
        ("0", "600"), ("0", "1200"), ("0", "1800"), ("1", "600"), ("1", "1200"), ("1", "1800")
    ]  # fmt: skip
    assert rows[4]["train_return/mean"] == "13.0" and rows[5]["train_length/mean"] == "101.0"
    assert rows[0]["train_length/mean"] == "" and rows[0]["method"] == "gcnt"


def test_the_mean_episode_length_stands_beside_the_return(tmp_path: Path, capsys) -> None:
    """``gcnt curves`` of the exploring return gives each point the seeds' mean episode length
    (logged with it), in its CSV and on its summary line; empty where none was logged."""
    for seed in (0, 1):
        path = make_run(tmp_path, "gcnt", seed, [600, 1200], lambda s, k=seed: s / 100 + k)
        RunDir(path).log_metrics({"env_steps": 1800, "train_return/mean": 30.0 + seed,
                                  "train_length/mean": 100.0 + 2 * seed})  # fmt: skip
    capsys.readouterr()
    assert main(["curves", str(tmp_path)]) == 0
    assert (
        "at      1800 steps: 30.5 ± 0.5 (1 s.e.), episodes of 101 steps" in capsys.readouterr().out
    )
    rows = read_csv(tmp_path / "figures" / "curves.csv")
    assert [r["length_mean"] for r in rows] == ["", "", "101.0"]
