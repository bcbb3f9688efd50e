"""``compile.compile: auto`` (the default): which runs compile and which stay eager, decided by the
run's planned updates against the measured break-even (structural: no compiling, no timing), and
recorded runs keeping the reading they trained with."""

from pathlib import Path

import pytest
import yaml

from gcnt.envs.stepper import usable_cpus
from gcnt.recipes import CompileConfig, RecipeError, load_recipe, recipe_from_dict
from gcnt.rl.accelerate import choose_compile, compile_step
from gcnt.rl.td3.learner import COMPILE_BREAK_EVEN, one_update_thread, resolve_compile

ROOT = Path(__file__).parents[1]
QUICK = ROOT / "recipes/quickstart.yaml"
STUDY = ROOT / "recipes/studies/walker.yaml"
PAPER = ROOT / "recipes/smpenv/walker.yaml"


def test_auto_is_the_default_and_a_bool_stays_a_bool():
    assert load_recipe(QUICK).compile.compile == "auto"
    assert load_recipe(QUICK, ["compile.compile=true"]).compile.compile is True
    assert load_recipe(QUICK, ["compile.compile=false"]).compile.compile is False
    with pytest.raises(RecipeError, match="compile"):
        load_recipe(QUICK, ["compile.compile=sometimes"])


def test_choose_compile_follows_the_break_even():
    auto = CompileConfig()
    assert choose_compile(auto, "cpu", 999, 1000)[0] is False
    assert choose_compile(auto, "cpu", 1000, 1000)[0] is True
    compiled, why = choose_compile(auto, "cpu", 5000, 1000)
    assert compiled and "5,000" in why and "1,000" in why
    # a recipe's bool wins whatever the run's length
    assert choose_compile(CompileConfig(compile=True), "cpu", 1, 1000)[0] is True
    assert choose_compile(CompileConfig(compile=False), "cpu", 10**9, 1000)[0] is False
    # not measured off the CPU; the eager two-thread critics asked for
    assert choose_compile(auto, "cuda", 10**9, 1000)[0] is False
    assert choose_compile(CompileConfig(twin_threads=True), "cpu", 10**9, 1000)[0] is False


def test_the_quick_start_stays_eager_and_long_runs_compile():
    from gcnt.rl.factories import train_robots

    quick = load_recipe(QUICK)
    run, why = resolve_compile(quick, len(train_robots(quick)))
    assert run.compile.compile is False and "eager" in why
    assert quick.compile.compile == "auto"  # the recipe given keeps its reading
    # the paper's 10M steps on Walker++ (6 robots in its train split: any count compiles)
    paper = load_recipe(PAPER)
    run, why = resolve_compile(paper, 6)
    assert run.compile.compile is True
    # on 2 to 4 cores the compiled update has one thread against eager's two critic threads
    assert ("compile.compile=false" in why) == one_update_thread(paper)
    # eager's critics on one thread (twin_threads=false): nothing to warn of
    one = load_recipe(PAPER, ["compile.twin_threads=false"])
    assert "compile.compile=false" not in resolve_compile(one, 6)[1]
    # the paper's networks (GCNT's actor: 413k parameters) are bound by their arithmetic: on
    # 2 to 4 cores they stay eager, whatever the run's length; the quick start's would compile
    run, why = resolve_compile(paper, 6, params=413_140)
    arithmetic = 2 <= usable_cpus() <= 4
    assert run.compile.compile is not arithmetic
    assert ("bound by its arithmetic" in why) is arithmetic
    assert resolve_compile(paper, 6, params=14_260)[0].compile.compile is True
    # study 1's Walker++ runs (4 robots) stay eager at their 12,000 steps, compile at 100,000
    study = load_recipe(STUDY)
    assert resolve_compile(study, 4)[0].compile.compile is False
    study.collector.total_frames = 100_000
    assert resolve_compile(study, 4)[0].compile.compile is True
    # a run just past / just short of the break-even, each schedule
    for schedule, robots in (("paper", 4), ("mixed", 3)):
        r = load_recipe(
            QUICK,
            [
                f"td3.schedule={schedule}",
                "td3.update_during_random=true",
                "td3.updates_per_step=1.0",
            ],
        )
        per_step = 1 / robots if schedule == "mixed" else 1
        frames = int(COMPILE_BREAK_EVEN[schedule] / per_step)
        r.collector.total_frames = frames + robots
        assert resolve_compile(r, robots)[0].compile.compile is True
        r.collector.total_frames = frames - robots
        assert resolve_compile(r, robots)[0].compile.compile is False


def test_planned_updates_count_the_schedule():
    c = load_recipe(QUICK).td3  # mixed, 2,000 random steps over all robots, no update then
    assert c.planned_updates(24_000, 3) == pytest.approx(22_000 / 3)
    p = load_recipe(PAPER).td3  # paper schedule, updates from the first round
    assert p.planned_updates(10_000_000, 6) == pytest.approx(10_000_000)
    s = load_recipe(STUDY).td3
    assert s.planned_updates(12_000, 4) == pytest.approx(10_000)


def test_auto_left_unresolved_is_eager():
    """An algorithm without a rule (PPO) gets the function itself for ``auto``."""

    def f(x):
        return x + 1

    assert compile_step(f, CompileConfig()) is f


def test_a_recorded_run_keeps_its_compile_reading(tmp_path):
    """A run recorded before ``auto`` (no ``compile.compile`` key) reads eager, as it ran; one
    recorded with a bool keeps it."""
    from gcnt.run.directory import RunDir

    source = ROOT / "tests/data/td3_run_b52e8ec"
    data = yaml.safe_load((source / "recipe.yaml").read_text())
    assert data["compile"]["compile"] is False
    for name, section in (("no_key", None), ("true", True)):
        run = tmp_path / name
        run.mkdir()
        for f in source.iterdir():
            if f.is_file():
                (run / f.name).write_bytes(f.read_bytes())
        d = yaml.safe_load((source / "recipe.yaml").read_text())
        if section is None:
            del d["compile"]["compile"]
        else:
            d["compile"]["compile"] = section
        (run / "recipe.yaml").write_text(yaml.safe_dump(d, sort_keys=False))
        recipe = RunDir(run).load_recipe(anywhere=True)
        assert recipe.compile.compile is (section is True)
        # recorded before the key: torch's default products, as it ran
        assert recipe.compile.matmul_precision == "highest"
    # a recipe file without the key (not a recorded run) takes today's default
    fresh = recipe_from_dict({"env": {"robots": ["hopper_3"]}})
    assert fresh.compile.compile == "auto" and fresh.compile.matmul_precision == "auto"


def test_matmul_precision_follows_the_probe(monkeypatch):
    """``compile.matmul_precision: auto``: medium on a CPU whose products keep float32 accuracy
    under it, highest where they would round to bfloat16 and off the CPU; a named one as named."""
    from gcnt.rl import accelerate

    auto = CompileConfig()
    for keeps, chosen in ((True, "medium"), (False, "highest")):
        monkeypatch.setattr(accelerate, "medium_keeps_float32", lambda k=keeps: k)
        assert accelerate.choose_matmul_precision(auto, "cpu")[0] == chosen
        assert accelerate.choose_matmul_precision(auto, "cuda:0")[0] == "highest"
        named = CompileConfig(matmul_precision="high")
        assert accelerate.choose_matmul_precision(named, "cpu")[0] == "high"
    with pytest.raises(RecipeError, match="matmul_precision"):
        load_recipe(QUICK, ["compile.matmul_precision=low"])


def test_the_precision_probe_leaves_torch_as_it_was():
    import torch

    from gcnt.rl.accelerate import medium_keeps_float32

    before = torch.get_float32_matmul_precision()
    medium_keeps_float32.cache_clear()
    assert isinstance(medium_keeps_float32(), bool)
    assert torch.get_float32_matmul_precision() == before


def test_a_run_records_what_it_chose(trained):
    """A run keeps ``auto`` in its recipe and records the resolved choices: a tiny run stays
    eager; its products' precision is the probe's."""
    from gcnt.rl.accelerate import choose_matmul_precision
    from gcnt.run.directory import RunDir

    recipe = RunDir(trained).load_recipe()
    assert recipe.compile.compile == "auto" and recipe.compile.matmul_precision == "auto"
    assert recipe.resolved["compile"] is False
    assert recipe.resolved["matmul_precision"] == choose_matmul_precision(recipe.compile, "cpu")[0]


def test_a_compiled_step_logs_its_first_call(caplog):
    """The whole compile time (forward and the backward AOTAutograd compiles at the first
    backward) is the step's first call: logged once, kept in ``compile_s``; eager: no wrapper."""
    import logging

    from gcnt.rl.accelerate import compile_seconds, timed_first_call

    def step(x):
        return x * 2

    assert timed_first_call(step, CompileConfig(compile=False), "s") is step
    timed = timed_first_call(step, CompileConfig(compile=True), "TD3 critic step")
    with caplog.at_level(logging.INFO, logger="gcnt.rl.accelerate"):
        assert timed(2) == 4 and timed(3) == 6
    lines = [r.getMessage() for r in caplog.records if "TD3 critic step" in r.getMessage()]
    assert len(lines) == 1 and "first call" in lines[0]
    assert compile_seconds(timed) >= 0 and timed.compile_s is not None


def test_prepare_names_both_choices(recipe_file):
    """The lines a run logs when training starts: the products' precision and TD3's compile
    choice, each with its reason."""
    from gcnt.rl.loop import prepare

    prepared = prepare(load_recipe(recipe_file))
    prepared.env.close()
    assert len(prepared.choices) == 2
    assert prepared.choices[0].startswith("float32 matrix products: ")
    assert prepared.choices[1].startswith("TD3 update compile.compile=auto: eager, the run plans")
