"""The ``gcnt`` command line without traps: options and overrides in any order, run directories
found (or a did-you-mean), ``gcnt eval --video`` leaving a run as it was, a finished run's
evaluation kept on resume, the end-of-training summary and quiet logs, and every method building
on both quick starts."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from cli_helpers import error_line, tiny_td3_recipe

from gcnt.cli import COMMANDS, build_parser
from gcnt.cli import main as gcnt
from gcnt.run.directory import RunDir

ROOT = Path(__file__).parents[1]
QUICKSTARTS = (
    ROOT / "recipes" / "quickstart.yaml",
    ROOT / "recipes" / "unimal" / "quickstart.yaml",
)


@pytest.fixture(scope="module")
def recipe_file(tmp_path_factory) -> Path:
    """The tiny recipe with a progress bar asked for and one robot to evaluate."""
    path = tmp_path_factory.mktemp("recipe") / "tiny.yaml"
    return tiny_td3_recipe(path, progress=True, eval_robots=["hopper_3"])


def _files(run: Path) -> dict[str, bytes]:
    return {str(p.relative_to(run)): p.read_bytes() for p in sorted(run.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------ options and overrides mixed


@pytest.mark.parametrize(
    "argv",
    [
        ["train", "R.yaml", "--seeds", "0,1", "a=1", "b=2"],
        ["train", "--seeds", "0,1", "R.yaml", "a=1", "b=2"],
        ["train", "R.yaml", "a=1", "--seeds", "0,1", "b=2"],
        ["bench-learn", "R.yaml", "--seeds", "0,1", "a=1", "b=2"],
        ["bench-learn", "R.yaml", "a=1", "--seeds", "0,1", "--min-gain", "5", "b=2"],
        ["bench-train", "R.yaml", "a=1", "--updates", "3", "b=2"],
    ],
)
def test_options_and_overrides_mix_in_any_order(argv):
    args = build_parser(only=argv[0]).parse_args(argv)
    assert args.recipe == "R.yaml" and args.overrides == ["a=1", "b=2"]
    assert getattr(args, "seeds", "0,1") == "0,1"


def test_resume_takes_overrides_after_options():
    args = build_parser(only="train").parse_args(["train", "--resume", "RUN", "eval.episodes=3"])
    assert args.resume == "RUN" and [args.recipe, *args.overrides] == ["eval.episodes=3"]


def test_sweep_keeps_sorting_its_own_words():
    argv = ["sweep", "R.yaml", "--seeds", "0-2", "a=1"]
    assert build_parser(only="sweep").parse_args(argv).items == argv[1:]


@pytest.mark.parametrize("command", [None, *COMMANDS])
def test_every_help_prints(command, capsys):
    argv = ["--help"] if command is None else [command, "--help"]
    with pytest.raises(SystemExit) as stop:
        gcnt(argv)
    assert stop.value.code == 0 and "usage: gcnt" in capsys.readouterr().out


def test_bench_train_defaults_to_the_quick_start(tmp_path, monkeypatch):
    from gcnt.commands.bench_train import recipe_and_overrides

    quickstart = str(ROOT / "recipes/quickstart.yaml")  # the packaged one, from any folder
    monkeypatch.chdir(tmp_path)
    args = build_parser(only="bench-train").parse_args(["bench-train"])
    assert recipe_and_overrides(args.recipe, args.overrides) == (quickstart, [])
    args = build_parser(only="bench-train").parse_args(["bench-train", "a.b=1", "c=2"])
    assert recipe_and_overrides(args.recipe, args.overrides) == (quickstart, ["a.b=1", "c=2"])
    assert recipe_and_overrides("R.yaml", ["a=1"]) == ("R.yaml", ["a=1"])


def test_packaged_recipes_by_name_from_any_folder(tmp_path, monkeypatch):
    from gcnt.recipes import RecipeError, find_recipe, load_recipe, packaged_recipe_names

    monkeypatch.chdir(tmp_path)
    walker = ROOT / "recipes/smpenv/walker.yaml"
    for spec in ("smpenv/walker", "smpenv/walker.yaml", "recipes/smpenv/walker.yaml"):
        assert find_recipe(spec) == walker
    assert "quickstart" in packaged_recipe_names() and "smpenv/_td3" not in packaged_recipe_names()
    assert load_recipe("quickstart").task == load_recipe(ROOT / "recipes/quickstart.yaml").task
    (tmp_path / "quickstart.yaml").write_text(
        "seed: 3\nbase: " + str(ROOT / "recipes/quickstart.yaml")
    )
    assert find_recipe("quickstart.yaml") == Path("quickstart.yaml")  # a file of the user's wins
    with pytest.raises(RecipeError, match="did you mean 'smpenv/walker'"):
        find_recipe("smpenv/walkr")


# ------------------------------------------------------------------ run directories


def test_a_misspelt_run_directory_gets_the_real_one(tmp_path, monkeypatch, capsys):
    from gcnt.recipes import load_recipe

    monkeypatch.chdir(tmp_path)
    recipe = load_recipe(QUICKSTARTS[0], ["task=Walker++"])
    real = RunDir.for_recipe(recipe).path  # where `gcnt train` would write it
    assert real == Path("runs/Walkerpp/td3-gcnt/seed0")
    (real / "checkpoints").mkdir(parents=True)
    for argv in (
        ["eval", "runs/Walker++/td3-gcnt/seed0"],
        ["train", "--resume", "runs/Walker++/td3-gcnt/seed0"],
    ):
        line = error_line(capsys, argv)
        assert "runs/Walker++/td3-gcnt/seed0 does not exist" in line
        assert "did you mean 'runs/Walkerpp/td3-gcnt/seed0'" in line
    line = error_line(capsys, ["eval", "elsewhere/seed0"])
    assert "elsewhere/seed0 does not exist" in line and "did you mean" not in line
    # the analysis commands read run or sweep directories the same way (and say it in one line)
    capsys.readouterr()
    assert gcnt(["curves", "runs/Walker++"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "runs/Walker++ does not exist; did you mean 'runs/Walkerpp'?" in err
    assert err.startswith("gcnt curves: error: ")  # the one form of every command's error


def test_a_robot_of_another_benchmark_is_one_line(trained, capsys):
    line = error_line(capsys, ["eval", str(trained), "--robots", "unimal_0000"])
    assert "'unimal_0000' is a unimal robot" in line and "smpenv run" in line
    line = error_line(capsys, ["train", "recipes/quickstart.yaml", "env.robots=[unimal_0000]"])
    assert "env.robots: robot 'unimal_0000' is a unimal robot" in line


# ------------------------------------------------------------------ a run's files left alone


def test_eval_video_records_each_robot_and_leaves_the_run_as_it_was(
    trained, tmp_path, monkeypatch, capsys
):
    import shutil

    from gcnt.rl import evaluate

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    before = _files(run)
    filmed = []

    def fake_render(recipe, policy, path, *, robot=None, steps=300):
        filmed.append(robot.name)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"mp4")
        return path

    monkeypatch.setattr(evaluate, "render_policy", fake_render)
    assert gcnt(["eval", str(run), "--video", "--robots", "train", "test"]) == 0
    assert filmed == ["hopper_3", "hopper_4"]
    after = _files(run)
    assert sorted(set(after) - set(before)) == [
        "videos/hopper_3-step40.mp4",
        "videos/hopper_4-step40.mp4",
    ]
    assert {k: after[k] for k in before} == before  # recipe, evaluations, metrics untouched


def test_resuming_a_finished_run_keeps_its_recipe_and_evaluation(trained, tmp_path):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    before = _files(run)
    assert "eval/step40.json" in before
    assert gcnt(["train", "--resume", str(run), "eval.episodes=2", "eval.video=true"]) == 0
    assert _files(run) == before


# ------------------------------------------------------------------ progress, summary, logs


def test_the_bar_ends_after_the_last_update_and_a_summary_follows(
    recipe_file, tmp_path, monkeypatch, capsys
):
    from gcnt.recipes import load_recipe
    from gcnt.rl import loop

    run = tmp_path / "run"
    seen = []  # metrics rows written when the bar moves

    class Bar:
        def update(self, n):
            seen.append(len(RunDir(run).read_metrics()))

        def set_postfix(self, **_):
            pass

        def close(self):
            pass

    assert loop.progress_bar(load_recipe(recipe_file), 40, 0).disable  # stderr: not a terminal
    monkeypatch.setattr(loop, "progress_bar", lambda *a: Bar())
    assert gcnt(["train", str(recipe_file), f"run_dir={run}"]) == 0
    rows = RunDir(run).read_metrics()
    assert seen[-1] == len(rows) and rows[-1]["env_steps"] == 40  # the last batch was logged
    err = capsys.readouterr().err
    assert "\r" not in err
    assert f"finished {run}: 40 env steps" in err and "env steps/s" in err
    assert "final evaluation hopper_3 (training robot): " in err and "± nan" not in err
    assert logging.getLogger("torchrl").getEffectiveLevel() >= logging.WARNING


# ------------------------------------------------------------------ every method, both quick starts


#: methods a quick start refuses (one line): sr/mlp: one MLP per robot (the quick starts train
#: several); modumorph/gcnt_hn (their hypernetworks) and gcnt_gcn_context (its GCN) read the
#: static limb context UNIMAL robots carry, which SMPENV robots do not have
REFUSED = {
    "smpenv": {"sr", "mlp", "modumorph", "gcnt_hn", "gcnt_gcn_context"},
    "unimal": {"sr", "mlp"},
}


@pytest.mark.parametrize("quickstart", QUICKSTARTS, ids=list(REFUSED))
def test_every_method_builds_with_the_quick_start_sizes(quickstart, request):
    """The quick starts shrink d_model: widths derived from it (ModuMorph's context and
    hypernetwork widths, SWAT's traversal widths) follow, SMP takes its own sizes from
    ``network.method_kwargs``, so every method that can run on the benchmark builds its actor and
    critic; the others are refused in one line (a RecipeError)."""
    from gcnt.nn.registry import NETWORKS
    from gcnt.recipes import RecipeError, load_recipe
    from gcnt.rl.factories import make_env, make_net, train_robots
    from gcnt.rl.loop import check_network, prepare

    refused = REFUSED[request.node.callspec.id]
    base = load_recipe(quickstart)
    env = make_env(base, train_robots(base))
    try:
        for name in NETWORKS:
            if name in refused:
                with pytest.raises(RecipeError):
                    prepare(load_recipe(quickstart, [f"network.name={name}"]))
                continue
            recipe = load_recipe(quickstart, [f"network.name={name}"])
            check_network(recipe)
            for role in (f"{recipe.algo}_actor", f"{recipe.algo}_critic"):
                net = make_net(recipe, env, role)
                assert sum(p.numel() for p in net.parameters()) > 0, (name, role)
    finally:
        env.close()
    assert refused < set(NETWORKS)


def test_modumorph_widths_follow_d_model_unless_given():
    from gcnt.nn.config import GCNTConfig, ModuMorphConfig

    assert ModuMorphConfig.preset("unimal").attn_context_widths == (128, 128, 128)
    cfg = ModuMorphConfig.preset("unimal", d_model=32)
    assert cfg.attn_context_widths == (32, 32, 32) and cfg.hn_width == 32
    cfg = ModuMorphConfig.preset("unimal", d_model=32, hn_width=8, attn_context_widths=(12, 32))
    assert cfg.attn_context_widths == (12, 32) and cfg.hn_width == 8
    with pytest.raises(ValueError, match="must end with d_model=32"):
        ModuMorphConfig.preset("unimal", d_model=32, attn_context_widths=(128,))
    assert GCNTConfig.preset("unimal", d_model=16).hn_width == 16


def test_a_recipe_error_is_reported_before_torch_is_imported():
    """``gcnt train`` checks the recipe first: a misspelt key is refused in one line without
    importing torch (about a second instead of ten)."""
    import subprocess
    import sys

    code = (
        "import sys; from gcnt.cli import main; "
        "rc = main(['train', 'recipes/quickstart.yaml', 'td3.bogus=1']); "
        "print(rc, 'torch' in sys.modules)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert done.stdout.split() == ["2", "False"], done.stderr[-2000:]
    lines = [line for line in done.stderr.splitlines() if line.startswith("gcnt ")]
    assert len(lines) == 1 and "td3.bogus" in lines[0] and "Traceback" not in done.stderr
