import dataclasses
from pathlib import Path

import pytest

from gcnt.recipes import RecipeError, load_recipe, recipe_from_dict

RECIPES = sorted(Path(__file__).parents[1].joinpath("recipes").rglob("*.yaml"))


@pytest.mark.parametrize("path", RECIPES, ids=lambda p: str(p.relative_to(p.parents[1])))
def test_every_recipe_file_validates(path):
    from gcnt.recipes import algorithm_section

    recipe = load_recipe(path)
    config = recipe.algo_config  # the active section, validated
    assert type(config) is algorithm_section(recipe.algo)
    assert recipe.to_dict()[recipe.algo] == dataclasses.asdict(config)


def test_paper_td3_settings_in_the_smpenv_recipes():
    r = load_recipe("recipes/smpenv/walker.yaml")
    t = r.td3
    assert (t.lr, t.gamma, t.tau, t.policy_delay) == (1e-4, 0.99, 0.046, 2)
    assert (t.policy_noise, t.noise_clip, t.max_grad_norm) == (0.2, 0.5, 0.1)
    assert (t.batch_size, t.init_random_frames) == (100, 10_000)
    assert t.exploration_noise == 0.126 and r.collector.total_frames == 10_000_000
    assert load_recipe("recipes/smpenv/cwhh.yaml").collector.total_frames == 20_000_000


def test_dotted_overrides_are_typed():
    r = load_recipe(
        "recipes/smpenv/walker.yaml",
        ["network.name=swat", "seed=2", "td3.lr=3e-4", "network.kwargs.d_model=64"],
    )
    assert (r.network.name, r.seed, r.td3.lr) == ("swat", 2, 3e-4)
    assert r.network.kwargs == {"d_model": 64}
    assert isinstance(r.td3.lr, float)


def test_base_is_merged_section_by_section():
    r = load_recipe("recipes/smpenv/ablations/humanoid_no_gcn.yaml")
    assert r.network.name == "gcnt_no_gcn"
    assert r.task == "Humanoid++" and r.td3.tau == 0.046


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("td3.lrr=1", "unknown recipe key 'td3.lrr'; did you mean 'lr'?"),
        ("seeds=1", "did you mean 'seed'?"),
        ("collecter.total_frames=5", "did you mean 'collector'"),
        ("td3.schedule=fast", "'fast' is not one of 'paper', 'mixed'"),
        ("seed=abc", "seed: expected int"),
        ("td3=3", "expected a mapping"),
        ("seed", "must look like section.key=value"),
        ("algo=tdd3", "unknown algorithm 'tdd3'; did you mean 'td3'?"),
        ("td3.gamma=2", "gamma must be in [0, 1]"),
        ("collector.total_frames=-100", "total_frames must be >= 1"),
    ],
)
def test_bad_keys_and_values_name_the_culprit(override, message):
    with pytest.raises(RecipeError) as e:
        load_recipe("recipes/smpenv/walker.yaml", [override])
    assert message in str(e.value)
    assert "walker.yaml" in str(e.value)


def test_misspelt_key_in_a_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("env:\n  robot: [walker_7_main]\n")
    with pytest.raises(
        RecipeError, match=r"bad.yaml: unknown recipe key 'env.robot'; did you mean 'robots'"
    ):
        load_recipe(bad)


def test_malformed_yaml_and_base_cycle(tmp_path):
    (tmp_path / "a.yaml").write_text("base: b.yaml\n")
    (tmp_path / "b.yaml").write_text("base: a.yaml\n")
    with pytest.raises(RecipeError, match="cycle"):
        load_recipe(tmp_path / "a.yaml")
    (tmp_path / "c.yaml").write_text("env: [unclosed\n")
    with pytest.raises(RecipeError, match="not valid YAML"):
        load_recipe(tmp_path / "c.yaml")


def test_defaults_round_trip():
    r = recipe_from_dict({})
    assert recipe_from_dict(r.to_dict()) == r


def test_only_the_active_algorithm_section_is_validated():
    data = {"algo": "td3", "td3": {"lr": 1e-3}, "ppo": {"not_a_key": 1}}
    r = recipe_from_dict(data)
    assert r.td3.lr == 1e-3 and r.sections["ppo"] == {"not_a_key": 1}
    assert recipe_from_dict(r.to_dict()).to_dict() == r.to_dict()


def test_a_misspelt_key_is_pointed_at_gcnts_name_for_a_known_alias_first():
    from gcnt.recipes import RecipeError, load_recipe

    quick = Path(__file__).parents[1] / "recipes/quickstart.yaml"
    for given, hint in (("td3.learning_rat", "did you mean 'lr'"),
                        ("td3.learning_rate", "did you mean 'lr'"),
                        ("td3.discount", "did you mean 'gamma'"),
                        ("td3.gama", "did you mean 'gamma'")):  # fmt: skip
        with pytest.raises(RecipeError, match=hint):
            load_recipe(quick, [f"{given}=1"])


def test_a_recipes_base_may_name_a_shipped_recipe(tmp_path):
    mine = tmp_path / "myrecipes" / "mine.yaml"
    mine.parent.mkdir()
    mine.write_text("base: quickstart\nseed: 3\n")
    r = load_recipe(mine)
    assert r.seed == 3 and r.task == "quickstart" and r.collector.total_frames == 24000
    mine.write_text("base: smpenv/walker.yaml\n")
    assert load_recipe(mine).task == "Walker++"
    # a file of that name beside the recipe wins over the shipped one
    (mine.parent / "quickstart").write_text("task: local\n")
    mine.write_text("base: quickstart\n")
    assert load_recipe(mine).task == "local"
    mine.write_text("base: no_such_recipe\n")
    with pytest.raises(RecipeError, match="no_such_recipe"):
        load_recipe(mine)
