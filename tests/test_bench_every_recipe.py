"""``gcnt bench-train`` runs with its own defaults on every shipped recipe: a tiny budget (a few
updates and steps), the networks shrunk so that the loop stays short, and nothing else changed
in the recipe (its random phase, schedule and counting as shipped). A recipe whose robots must be
imported first (UNIMAL-100) is refused in one line naming the import. Run by ``make
test-bench`` (and CI), not by ``make test``: about a minute per ten recipes."""

from pathlib import Path

import pytest

from gcnt.cli import main

ROOT = Path(__file__).parents[1]
SHIPPED = sorted(p for p in (ROOT / "recipes").rglob("*.yaml") if not p.name.startswith("_"))
SMALL = [
    "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}",
    "network.method_kwargs={}",
]
#: PPO's batch at the recipe's size is the paper's (81,920 frames: tens of GB on a CPU)
SMALL_PPO = ["ppo.num_envs=4", "ppo.steps_per_env=16", "ppo.minibatch_size=32", "ppo.epochs=1"]


def _algo(path: Path) -> str:
    from gcnt.recipes import read_recipe_file, recipe_from_dict

    return recipe_from_dict(read_recipe_file(path), [], str(path)).algo


@pytest.mark.bench
@pytest.mark.parametrize("recipe", SHIPPED, ids=[str(p.relative_to(ROOT)) for p in SHIPPED])
def test_bench_train_runs_on_every_shipped_recipe_with_its_defaults(recipe, capsys):
    try:
        algo = _algo(recipe)
    except Exception as e:  # a recipe of imported robots: resolved only when they exist
        pytest.skip(f"{recipe.name}: {e}")
    overrides = [*SMALL, *(SMALL_PPO if algo == "ppo" else [])]
    flags = ["--updates", "2", "--steps", "20", "--warmup", "8", "--rounds", "1"]
    flags += ["--iterations", "2"]
    code = main(["bench-train", str(recipe), *overrides, *flags])
    out, err = capsys.readouterr()
    if "Unimal100" in recipe.read_text() and code == 2:
        assert "import-unimal" in err and len(err.strip().splitlines()) == 1
        return
    assert code == 0, err
    assert "bare" in out or "iteration" in out
