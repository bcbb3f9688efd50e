"""Single-robot baselines (SR-fair, SR-top; paper figure 7): ``gcnt sweep --per-robot`` makes one
run per robot, ``gcnt curves`` averages a seed's robots before the seeds, recipe labels name the
lines, and a one-robot network on several robots is refused."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gcnt import sweep as S
from gcnt.analysis import curves
from gcnt.analysis.runs import find_runs
from gcnt.cli import main
from gcnt.recipes import RecipeError, load_recipe, recipe_from_dict, save_recipe

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "recipes" / "quickstart.yaml"
SR_FAIR = ROOT / "recipes" / "unimal" / "sr_fair.yaml"
SR_TOP = ROOT / "recipes" / "unimal" / "sr_top.yaml"
HOPPERS = ["hopper_3", "hopper_4", "hopper_5"]


# ----------------------------------------------------------------------------- the grid


def test_per_robot_expands_one_run_per_robot_of_the_split(tmp_path: Path) -> None:
    specs = S.expand(
        [QUICKSTART],
        tmp_path / "sw",
        methods=["mlp", "gcnt"],
        seeds=[0, 1],
        overrides=["collector.total_frames=3000"],
        per_robot="Hopper++:train",
    )
    assert len(specs) == 2 * 3 * 2
    assert [(s.method, s.robot, s.seed) for s in specs[:6]] == [
        (m, r, s) for m in ["mlp"] for r in HOPPERS for s in (0, 1)
    ]
    s = specs[3]  # mlp, hopper_4, seed 1
    assert s.id == "quickstart/td3-mlp/hopper_4/seed1"
    assert s.run_dir == str((tmp_path / "sw" / s.id).resolve())
    assert s.overrides[:5] == [
        "collector.total_frames=3000",
        'env.robots=["hopper_4"]',
        "env.test_robots=[]",
        "network.name=mlp",
        "seed=1",
    ]
    assert 'logger.name="quickstart-td3-mlp-hopper_4-seed1"' in s.overrides
    # the overrides train that robot alone
    r = load_recipe(QUICKSTART, s.overrides)
    assert (r.env.robots, r.env.test_robots, r.network.name, r.seed) == (["hopper_4"], [], "mlp", 1)
    assert r.run_dir == s.run_dir
    # the train command: the overrides, then no plugin from the recipe file (a sweep's runs get
    # its command's plugins by --plugin only)
    argv = S.commands(s)[0][1]
    assert argv[-len(s.overrides) - 1 : -1] == s.overrides and argv[-1] == S.spec.NO_RECIPE_PLUGINS


def test_per_robot_takes_a_list_and_labels_keep_sr_fair_and_sr_top_apart(tmp_path: Path) -> None:
    specs = S.expand(
        [SR_FAIR, SR_TOP], tmp_path / "sr", seeds=[0], per_robot="unimal_0000,unimal_0001"
    )
    assert [s.id for s in specs] == [
        "unimal-ft/ppo-sr-fair/unimal_0000/seed0",
        "unimal-ft/ppo-sr-fair/unimal_0001/seed0",
        "unimal-ft/ppo-sr-top/unimal_0000/seed0",
        "unimal-ft/ppo-sr-top/unimal_0001/seed0",
    ]
    assert {s.method for s in specs} == {"sr"} and {s.task for s in specs} == {"UNIMAL-FT"}
    assert 'logger.name="UNIMAL-FT-ppo-SR-top-unimal_0001-seed0"' in specs[-1].overrides
    # another world: the world and its task name, as the recipes' comments say
    mt = S.expand(
        [SR_FAIR],
        tmp_path / "mt",
        seeds=[2],
        overrides=["env.world=mt", "task=UNIMAL-MT"],
        per_robot=["unimal_0003"],
    )
    assert [s.id for s in mt] == ["unimal-mt/ppo-sr-fair/unimal_0003/seed2"]
    r = load_recipe(SR_FAIR, mt[0].overrides)
    assert (r.env.world, r.task, r.label, r.env.robots) == (
        "mt",
        "UNIMAL-MT",
        "SR-fair",
        ["unimal_0003"],
    )


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(overrides=["env.robots=[hopper_3]"]), "drop 'env.robots=[hopper_3]'"),
        (dict(overrides=["mlp:env.test_robots=[]"]), "--per-robot sets env.robots"),
        (dict(evals=["test"]), "no test robots"),
        (dict(per_robot="Hopper++:trian"), "did you mean 'train'"),
        (dict(per_robot=" , "), "give a robot split"),
    ],
)
def test_per_robot_refuses_what_cannot_work(kwargs, message, tmp_path: Path) -> None:
    kwargs = {"per_robot": "Hopper++:train", "methods": ["mlp"], **kwargs}
    with pytest.raises(S.SweepError, match=message.replace("[", r"\[").replace("]", r"\]")):
        S.expand([QUICKSTART], tmp_path, **kwargs)


def test_sweep_command_per_robot_writes_the_robot_in_the_manifest(tmp_path: Path, capsys) -> None:
    sweep = tmp_path / "sw"
    argv = ["sweep", str(QUICKSTART), "--per-robot", "hopper_3,hopper_5", "--methods", "mlp"]
    assert main([*argv, "--seeds", "0-1", "--dir", str(sweep), "--dry-run"]) == 0
    data = json.loads((sweep / S.MANIFEST).read_text())
    assert [(r["id"], r["robot"]) for r in data["runs"]] == [
        ("quickstart/td3-mlp/hopper_3/seed0", "hopper_3"),
        ("quickstart/td3-mlp/hopper_3/seed1", "hopper_3"),
        ("quickstart/td3-mlp/hopper_5/seed0", "hopper_5"),
        ("quickstart/td3-mlp/hopper_5/seed1", "hopper_5"),
    ]
    assert S.Manifest.load(sweep).runs[2].robot == "hopper_5"
    # without --per-robot the same method on the recipe's three robots is refused, in one line
    capsys.readouterr()
    assert main(["sweep", str(QUICKSTART), "--methods", "mlp", "--dir", str(sweep)]) == 2
    err = capsys.readouterr().err.strip()
    assert "network 'mlp' is one MLP per robot" in err and "--per-robot" in err
    assert "\n" not in err


def test_a_manifest_without_robots_still_loads(tmp_path: Path) -> None:
    old = {
        "created": "2025-01-01T00:00:00",
        "runs": [
            {
                "id": "walkerpp/td3-gcnt/seed0",
                "run_dir": str(tmp_path / "walkerpp/td3-gcnt/seed0"),
                "recipe": str(QUICKSTART),
                "task": "Walker++",
                "algo": "td3",
                "method": "gcnt",
                "seed": 0,
                "overrides": ["seed=0"],
                "state": "done",
            }
        ],
    }
    (tmp_path / S.MANIFEST).write_text(json.dumps(old))
    m = S.Manifest.load(tmp_path)
    assert m.runs[0].robot is None and m.runs[0].state == "done"
    m.save()
    assert json.loads((tmp_path / S.MANIFEST).read_text())["runs"][0]["robot"] is None


# ----------------------------------------------------------------------------- refusal


def test_a_one_robot_network_on_several_robots_is_refused() -> None:
    with pytest.raises(RecipeError) as e:
        load_recipe(ROOT / "recipes/smpenv/walker.yaml", ["network.name=mlp"])
    msg = str(e.value)
    assert "walker.yaml" in msg and "network 'mlp'" in msg and "4 robots" in msg
    assert "gcnt sweep RECIPE --per-robot SPLIT" in msg and "Walker++:train" in msg
    assert "\n" not in msg
    with pytest.raises(RecipeError, match=r"network 'sr' .* 100 robots"):
        load_recipe(SR_FAIR, ["env.robots=[Unimal:train]"])
    with pytest.raises(RecipeError, match=r"2 robots.*--per-robot hopper_3,hopper_4"):
        load_recipe(QUICKSTART, ["network.name=sr", "env.robots=[hopper_3, hopper_4]"])
    # one robot is SR; other networks share one policy over many robots
    assert load_recipe(SR_FAIR).env.robots == ["unimal_0000"]
    assert load_recipe(QUICKSTART, ["network.name=mlp", "env.robots=[hopper_4]"]).network.name
    assert load_recipe(ROOT / "recipes/smpenv/walker.yaml", ["network.name=swat"])


def test_a_recipe_a_run_wrote_still_loads() -> None:
    """A run's recipe.yaml (``resolved`` set) is what was trained: evaluating it stays possible."""
    data = load_recipe(QUICKSTART).to_dict()
    data["network"] = {"name": "mlp", "kwargs": {}}
    data["resolved"] = {"frames_per_batch": 15}
    assert recipe_from_dict(data).network.name == "mlp"
    del data["resolved"]
    with pytest.raises(RecipeError, match="3 robots"):
        recipe_from_dict(data)


def test_train_refuses_before_writing_anything(tmp_path: Path, capsys) -> None:
    run = tmp_path / "run"
    argv = ["train", str(QUICKSTART), "network.name=sr", f"run_dir={run}"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "network 'sr' is one MLP per robot, but env.robots names 3 robots" in err
    assert "\n" not in err and not run.exists()


def test_label_is_a_typed_recipe_key() -> None:
    assert load_recipe(QUICKSTART).label is None
    assert load_recipe(SR_TOP).label == "SR-top"
    with pytest.raises(RecipeError, match="label: expected str"):
        load_recipe(QUICKSTART, ["label=[1]"])
    with pytest.raises(RecipeError, match="label must not be empty"):
        load_recipe(QUICKSTART, ["label=' '"])


# ----------------------------------------------------------------------------- aggregation

#: slope per robot (return per 1000 steps) and offset per (seed, robot): every curve is linear,
#: so interpolation is exact and the expected numbers are closed-form
SLOPES = {"hopper_3": 1.0, "hopper_4": 2.0, "hopper_5": 3.0}
OFFSETS = {
    0: {"hopper_3": 0.0, "hopper_4": 10.0, "hopper_5": 20.0},
    1: {"hopper_3": 30.0, "hopper_4": 40.0, "hopper_5": 80.0},
}
#: each robot logs at its own steps; seed 0's robots all cover 500..3000, seed 1's 0..3000
STEPS = {
    0: {
        "hopper_3": [0, 1000, 2000, 3000],
        "hopper_4": [0, 1500, 3000],
        "hopper_5": [500, 1200, 3500],
    },
    1: {r: [0, 1000, 2000, 3000] for r in SLOPES},
}


def write_run(path: Path, overrides: list[str], rows: list[dict]) -> Path:
    """A run directory as ``gcnt train`` leaves it: the resolved recipe and metrics.jsonl."""
    recipe = load_recipe(QUICKSTART, [*overrides, f"run_dir={path}"])
    recipe.resolved = {"frames_per_batch": 15}
    (path / "checkpoints").mkdir(parents=True)
    save_recipe(recipe, path / "recipe.yaml")
    (path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def sr_value(seed: int, robot: str, step: float) -> float:
    return SLOPES[robot] * step / 1000 + OFFSETS[seed][robot]


@pytest.fixture
def sr_and_universal(tmp_path: Path) -> tuple[Path, Path]:
    sr, universal = tmp_path / "sr", tmp_path / "universal"
    for seed, per_robot in STEPS.items():
        for robot, steps in per_robot.items():
            rows = [
                {
                    "env_steps": s,
                    "train_return/mean": sr_value(seed, robot, s),
                    f"train_return/{robot}": sr_value(seed, robot, s),
                    "updates": s // 10,
                }
                for s in steps
            ]
            over = [f"env.robots=[{robot}]", "network.name=mlp", "label=SR-fair", f"seed={seed}"]
            write_run(sr / f"quickstart/td3-sr-fair/{robot}/seed{seed}", over, rows)
        # the universal method of the same task: one run per seed over the three robots
        rows = [{"env_steps": s, "train_return/mean": 100.0 + seed} for s in (0, 3000)]
        write_run(universal / f"quickstart/td3-gcnt/seed{seed}", [f"seed={seed}"], rows)
    return sr, universal


def test_per_robot_runs_are_averaged_over_robots_then_over_seeds(sr_and_universal) -> None:
    runs = find_runs(sr_and_universal)
    assert {r.label for r in runs} == {"SR-fair", "gcnt"}
    rows = curves.learning_curves(runs, points=6)
    assert {r["task"] for r in rows} == {"quickstart"}  # one panel
    assert [r["method"] for r in rows[::6]] == ["gcnt", "SR-fair"]
    sr = [r for r in rows if r["method"] == "SR-fair"]
    # the grid every seed covers: seed 0's robots cover 500..3000
    assert [r["env_steps"] for r in sr] == [500, 1000, 1500, 2000, 2500, 3000]
    for row in sr:
        x = row["env_steps"]
        per_seed = [float(np.mean([sr_value(s, r, x) for r in SLOPES])) for s in (0, 1)]
        assert per_seed == pytest.approx([0.002 * x + 10.0, 0.002 * x + 50.0], rel=1e-12)
        assert row["mean"] == pytest.approx(0.002 * x + 30.0, rel=1e-12)
        assert row["stderr"] == pytest.approx(20.0, rel=1e-12)  # |50 - 10| / 2
        assert (row["seeds"], row["robots"]) == (2, 3)
    assert sr[-1]["mean"] == pytest.approx(36.0, rel=1e-12)
    gcnt = [r for r in rows if r["method"] == "gcnt"]
    assert all((r["seeds"], r["robots"]) == (2, 1) for r in gcnt)
    assert gcnt[-1]["mean"] == pytest.approx(100.5) and gcnt[-1]["stderr"] == pytest.approx(0.5)


def test_mean_over_robots_is_exact_at_every_robots_log_step() -> None:
    a = (np.array([0.0, 10.0]), np.array([0.0, 10.0]))
    b = (np.array([0.0, 5.0, 10.0, 20.0]), np.array([0.0, 10.0, 0.0, 7.0]))
    grid, mean = curves.mean_over_robots([a, b])
    assert grid.tolist() == [0.0, 5.0, 10.0] and mean.tolist() == [0.0, 7.5, 5.0]
    grid, mean = curves.mean_over_robots([a])
    assert grid is a[0] and mean is a[1]


def test_curves_command_on_two_directories(sr_and_universal, tmp_path: Path, capsys) -> None:
    out = tmp_path / "fig"
    assert main(["curves", *map(str, sr_and_universal), "--points", "6", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "SR-fair" in text and "seeds 2 x 3 robots" in text
    lines = (out / "curves.csv").read_text().splitlines()
    assert lines[0] == "task,method,env_steps,mean,stderr,seeds,robots,logged,length_mean"
    assert lines[-1].startswith("quickstart,SR-fair,3000,36.0") and lines[-1].endswith(",2,3,1,")
    assert (out / "curves.png").read_bytes()[:4] == b"\x89PNG"
