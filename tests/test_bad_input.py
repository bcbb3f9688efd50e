"""Bad input, divergence and data safety (issue 13): every mistake in what a user gives gcnt (a
robot file, recipe, override, device, checkpoint or directory) is one line naming the culprit and
exit code 2, before any training starts, and nothing already on disk is lost.

One test (or parametrised group) per class of the issue: tracebacks around clear messages,
errors that named nothing, values accepted silently, data lost, files outside the robot's folder,
new morphologies (not bad input), noise.
"""

from __future__ import annotations

import json
import math
import random
import shutil
from pathlib import Path

import pytest
import torch
from cli_helpers import error_line, tiny_td3_recipe

from gcnt.cli import main as gcnt
from gcnt.morphology import morphologies_dir
from gcnt.run.directory import RunDir

ROOT = Path(__file__).parents[1]
DATA = Path(__file__).parent / "data" / "bad_robots"
WALKER = (morphologies_dir() / "smpenv" / "walker_7_main.xml").read_text()


@pytest.fixture(scope="module")
def recipe_file(tmp_path_factory) -> Path:
    """The tiny recipe without test robots (a fixed-size network must still train on it)."""
    return tiny_td3_recipe(tmp_path_factory.mktemp("recipe") / "tiny.yaml", test_robots=())


def walker(tmp_path: Path, name: str, old: str = "", new: str = "") -> Path:
    """walker_7_main with one edit, written as ``tmp_path/name``."""
    if old:
        assert WALKER.count(old) >= 1, old
    path = tmp_path / name
    path.write_text(WALKER.replace(old, new, 1) if old else WALKER)
    return path


def copy_run(run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(run, out)
    return out


# ------------------------------------------------------------------ 1. tracebacks -> one line

BAD_ROBOTS = {
    # name: (edit of walker_7_main (old, new) or raw bytes, words the message must contain)
    "empty": (b"", "not valid XML"),
    "binary": (bytes(range(256)) * 2, "not a text file"),
    "two_roots": (
        (
            "  </worldbody>",
            '    <body name="torso2"><geom type="sphere" size=".1"/></body>\n  </worldbody>',
        ),
        "found 2",
    ),
    "no_motor": (
        ('<motor name="right3_joint" class="/" gear="100" joint="right3_joint"/>', ""),
        "'right3_joint' of limb 'right3' has no motor",
    ),
    "nan_size": (('size="0.0448"', 'size="nan"'), "left2_geom"),
    "negative_size": (('size="0.0448"', 'size="-0.0448"'), "left2_geom"),
    "negative_mass": (
        ('<geom name="left1_geom" class="/"', '<geom name="left1_geom" class="/" mass="-1"'),
        "left1_geom",
    ),
    "nan_position": (
        ('<body name="left2" pos="0 0 -0.48">', '<body name="left2" pos="0 0 nan">'),
        "left2",
    ),
    "nan_gear": (
        ('gear="100" joint="left1_joint"', 'gear="nan" joint="left1_joint"'),
        "left1_joint",
    ),
    "infinite_range": (('range="-1.309 1.309"', 'range="-inf inf"'), "left1_joint"),
    "slide_limb": (
        ('name="left2_joint" class="/" type="hinge"', 'name="left2_joint" class="/" type="slide"'),
        "not a hinge",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_ROBOTS))
def test_a_bad_robot_file_is_one_line_naming_it_and_no_run_directory(
    case, tmp_path, recipe_file, trained, capsys, monkeypatch
):
    edit, words = BAD_ROBOTS[case]
    path = tmp_path / f"walker_{case}.xml"
    if isinstance(edit, bytes):
        path.write_bytes(edit)
    else:
        walker(tmp_path, path.name, *edit)
    monkeypatch.chdir(tmp_path)  # the default run directory would be under runs/
    line = error_line(capsys, ["train", str(recipe_file), f"env.robots=[{path}]"])
    assert str(path) in line and words in line, line
    assert not (tmp_path / "runs").exists()  # robots are built before the run directory
    before = sorted((trained / "eval").iterdir())
    line = error_line(capsys, ["eval", str(trained), "--robots", str(path)])
    assert str(path) in line and words in line, line
    assert sorted((trained / "eval").iterdir()) == before


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ("network.name=gcnn", "network: unknown network 'gcnn'; did you mean 'gcnt'"),
        ("network.kwargs={d_mdl: 3}", "unknown GCNTConfig field 'd_mdl'; did you mean 'd_model'"),
        ("network.kwargs={d_model: 16, heads: 3}", "not divisible by heads 3"),
        ("network.preset=big", "unknown preset 'big'"),
        ("env.robots=[]", "env.robots is empty"),
        ("eval.robots=[hoper_3]", "unknown robot 'hoper_3'; did you mean 'hopper_3'"),
        ("run_dir={tmp}/a_file/run", "cannot create the run directory"),
    ],
)
def test_recipe_mistakes_found_when_building_are_one_line(
    override, words, tmp_path, recipe_file, capsys
):
    (tmp_path / "a_file").write_text("")
    argv = ["train", str(recipe_file), override.replace("{tmp}", str(tmp_path))]
    if not override.startswith("run_dir"):
        argv.append(f"run_dir={tmp_path / 'run'}")
    assert words in error_line(capsys, argv)
    assert not (tmp_path / "run").exists()


def test_a_checkpoint_that_does_not_fit_an_edited_recipe(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    recipe = run / "recipe.yaml"
    recipe.write_text(recipe.read_text().replace("d_model: 16", "d_model: 32"))
    before = (run / "checkpoints" / "last.pt").read_bytes()
    line = error_line(capsys, ["eval", str(run), "--robots", "hopper_3", "--episodes", "1"])
    assert "last.pt" in line and "does not fit" in line
    line = error_line(capsys, ["train", "--resume", str(run), "collector.total_frames=60"])
    assert "last.pt" in line and "does not fit" in line
    assert (run / "checkpoints" / "last.pt").read_bytes() == before
    # an override that changes the network on resume is refused and not written back
    line = error_line(
        capsys, ["train", "--resume", str(trained), "network.name=mlp", "collector.total_frames=60"]
    )
    assert "last.pt" in line and "does not fit" in line  # MLP at its preset's sizes
    assert "name: gcnt" in (trained / "recipe.yaml").read_text()


# ------------------------------------------------------------------ 2. errors that name the culprit


@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty", "random"])
def test_an_unreadable_checkpoint_is_named(damage, trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    ckpt = run / "checkpoints" / "last.pt"
    data = ckpt.read_bytes()
    ckpt.write_bytes(
        {
            "truncated": data[: len(data) // 2],
            "garbage": b"\x00junk" * 50,
            "empty": b"",
            "random": random.Random(0).randbytes(4096),
        }[damage]
    )
    for argv in (["eval", str(run), "--robots", "hopper_3"], ["train", "--resume", str(run)]):
        line = error_line(capsys, argv)
        assert str(ckpt) in line and "not a readable gcnt checkpoint" in line
        assert "weights_only" not in line  # never torch's advice to load it unsafely


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ("td3.lr=nan", "td3: lr must be a positive finite number, got nan"),
        ("td3.lr=[1,", "override 'td3.lr=[1,': the value is not valid YAML"),
        ("td3.max_grad_norm=.nan", "max_grad_norm must be finite"),
        ("device=tpu", "device must be cpu, cuda or cuda:N"),
    ],
)
def test_value_errors_name_the_key(override, words, tmp_path, recipe_file, capsys):
    line = error_line(capsys, ["train", str(recipe_file), override, f"run_dir={tmp_path}/run"])
    assert words in line and "tiny.yaml" in line
    assert not (tmp_path / "run").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_cuda_on_a_machine_without_gpu(tmp_path, recipe_file, capsys):
    line = error_line(capsys, ["train", str(recipe_file), "device=cuda", f"run_dir={tmp_path}/r"])
    assert "device='cuda' but no CUDA GPU is available here" in line


def test_online_logging_without_a_wandb_key(tmp_path, recipe_file, capsys, monkeypatch):
    for var in ("WANDB_API_KEY", "WANDB_IDENTITY_TOKEN_FILE"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("NETRC", str(tmp_path / "netrc"))
    monkeypatch.setenv("WANDB_CONFIG_DIR", str(tmp_path / "wandb-config"))
    line = error_line(
        capsys,
        [
            "train",
            str(recipe_file),
            "logger.backend=wandb",
            "logger.mode=online",
            f"run_dir={tmp_path}/run",
        ],
    )
    assert "logger.mode=online but W&B has no API key" in line
    assert not (tmp_path / "run").exists()


def test_a_fixed_size_network_on_a_larger_robot(tmp_path, recipe_file, capsys):
    """SR's flat MLP takes as many limbs as it was trained with: evaluating it on a larger robot
    is refused naming the robot (in eval, and in training before any step)."""
    run = tmp_path / "mlp"
    mlp = ["network.name=mlp", "network.kwargs={}"]
    line = error_line(
        capsys, ["train", str(recipe_file), *mlp, "eval.robots=[walker_7_main]", f"run_dir={run}"]
    )
    assert "robot 'walker_7_main' has 7 limbs; network 'mlp' was built for at most 3" in line
    assert not run.exists()
    assert (
        gcnt(["train", str(recipe_file), *mlp, "collector.total_frames=25", f"run_dir={run}"]) == 0
    )
    line = error_line(capsys, ["eval", str(run), "--robots", "walker_7_main", "--episodes", "1"])
    assert "robot 'walker_7_main' has 7 limbs; network 'mlp' was built for at most 3" in line


# ------------------------------------------------------------------ 3. accepted silently before


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ("collector.total_frames=-100", "collector.total_frames must be >= 1, got -100"),
        ("td3.init_random_frames=40", "init_random_frames (40) must be below collector.total_fr"),
        ("td3.buffer_total_size=0", "buffer_total_size must be >= 1, got 0"),
        ("td3.buffer_total_size=4", "batch_size 8 is larger than the replay buffer"),
        ("td3.gamma=2", "gamma must be in [0, 1], got 2.0"),
        ("td3.batch_size=0", "batch_size must be >= 1, got 0"),
        ("td3.steps_per_batch=0", "steps_per_batch must be >= 1, got 0"),
        ("td3.policy_delay=0", "policy_delay must be >= 1"),
        ("td3.tau=0", "tau must be a positive finite number"),
        ("env.copies=0", "env.copies must be >= 1"),
        ("checkpoint_interval=0", "checkpoint_interval must be >= 1"),
        ("eval.episodes=-1", "eval.episodes and eval.interval must be >= 0"),
    ],
)
def test_meaningless_values_are_refused_when_the_recipe_is_loaded(
    override, words, tmp_path, recipe_file, capsys
):
    line = error_line(capsys, ["train", str(recipe_file), override, f"run_dir={tmp_path}/run"])
    assert words in line
    assert not (tmp_path / "run").exists()


def test_an_empty_recipe_file_trains_nothing(tmp_path, capsys):
    empty = tmp_path / "empty.yaml"
    empty.write_text("# nothing yet\n")
    line = error_line(capsys, ["train", str(empty), f"run_dir={tmp_path}/run"])
    assert "empty.yaml: the recipe is empty" in line
    only_base = tmp_path / "base_only.yaml"  # sets things, but no robots: nothing to train on
    only_base.write_text(f"base: {ROOT}/recipes/smpenv/_td3.yaml\n")
    assert "env.robots is empty" in error_line(
        capsys, ["train", str(only_base), f"run_dir={tmp_path}/run"]
    )
    assert not (tmp_path / "run").exists()


def test_eval_with_zero_episodes_writes_nothing(trained, capsys):
    before = sorted((trained / "eval").iterdir())
    assert "--episodes must be >= 1, got 0" in error_line(
        capsys, ["eval", str(trained), "--episodes", "0"]
    )
    assert sorted((trained / "eval").iterdir()) == before


# ------------------------------------------------------------------ 4. data safety


def test_a_diverging_run_stops_and_keeps_its_last_good_checkpoint(tmp_path, recipe_file, capsys):
    run = tmp_path / "run"
    line = error_line(
        capsys,
        [
            "train",
            str(recipe_file),
            "td3.lr=1e30",
            "td3.max_grad_norm=0",
            "td3.update_during_random=false",  # a checkpoint before the first update
            "collector.total_frames=200",
            f"run_dir={run}",
        ],
    )
    assert "training diverged at" in line and "is nan" in line
    assert f"the last good checkpoint ({run / 'checkpoints' / 'last.pt'}) was kept" in line
    state = RunDir(run).load_checkpoint()
    weights = [t for t in state["policy"]["actor"].values() if t.is_floating_point()]
    assert weights and all(bool(torch.isfinite(t).all()) for t in weights)
    assert all(math.isfinite(v) for r in RunDir(run).read_metrics() for v in r.values())


def test_only_losses_stop_a_run_not_diagnostics_that_may_be_nan(tmp_path):
    from gcnt.rl.loop import TrainingDivergedError, _check_losses

    run = RunDir(tmp_path / "run")
    _check_losses(
        run,
        {"loss_critic": 1.0, "explained_variance": math.nan, "value_clip_fraction": math.nan},
        10,
        1,
    )
    with pytest.raises(TrainingDivergedError, match="loss_policy is inf at update 3"):
        _check_losses(run, {"loss_policy": math.inf}, 10, 3)


@pytest.mark.parametrize(
    "value, finite",
    [(0.5, True), (math.nan, False), (math.inf, False), (-math.inf, False), (3e38, True)],
)
def test_the_finiteness_check_decides_per_element(value, finite):
    """The divergence check's fused norm is only a fast path: a NaN or inf anywhere is caught,
    and finite weights whose norm overflows float32 (3e38 squared) are still finite."""
    from gcnt.rl.loop import _all_finite

    w = torch.zeros(4, 3)
    w[1, 2] = value
    state = {"actor": {"w": w, "b": torch.ones(3, dtype=torch.float64), "n": torch.arange(3)}}
    assert _all_finite(state) is finite
    assert _all_finite({"empty": [torch.zeros(0), torch.arange(2)]})


def test_a_nan_injected_after_a_checkpoint_stops_the_run_which_resumes_from_it(
    tmp_path, recipe_file, capsys, monkeypatch
):
    from gcnt.rl.td3.learner import TD3

    process = TD3.process

    def modules(obj, depth=2):
        for value in vars(obj).values():
            if isinstance(value, torch.nn.Module):
                yield value
            elif depth and hasattr(value, "__dict__") and type(value).__module__.startswith("gcnt"):
                yield from modules(value, depth - 1)

    def poisoned(self, data, env_steps):
        if env_steps > 20:  # after the first checkpoint: every weight turns NaN
            with torch.no_grad():
                for module in modules(self):
                    for p in module.parameters():
                        p.fill_(math.nan)
        yield from process(self, data, env_steps)

    run = tmp_path / "run"
    monkeypatch.setattr(TD3, "process", poisoned)
    line = error_line(capsys, ["train", str(recipe_file), f"run_dir={run}"])
    assert "training diverged at" in line and "the last good checkpoint" in line
    assert RunDir(run).load_checkpoint()["env_steps"] == 20
    monkeypatch.setattr(TD3, "process", process)
    assert gcnt(["train", "--resume", str(run)]) == 0
    state = RunDir(run).load_checkpoint()
    assert state["env_steps"] >= 40
    assert all(
        bool(torch.isfinite(t).all())
        for t in state["policy"]["actor"].values()
        if t.is_floating_point()
    )


def test_a_run_killed_before_its_first_checkpoint_is_never_overwritten(
    tmp_path, recipe_file, capsys
):
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(recipe_file, run / "recipe.yaml")
    (run / "metrics.jsonl").write_text('{"env_steps": 20, "updates": 1}\n')
    files = {p.name: p.read_bytes() for p in run.iterdir()}
    line = error_line(capsys, ["train", str(recipe_file), f"run_dir={run}"])
    assert "already holds a run" in line and "--resume" in line
    assert {p.name: p.read_bytes() for p in run.iterdir()} == files
    # resuming it trains from the start; the killed attempt's metrics are kept aside
    assert gcnt(["train", "--resume", str(run), "collector.total_frames=25"]) == 0
    assert (run / "metrics.restart1.jsonl").read_bytes() == files["metrics.jsonl"]
    assert all("env_steps_per_s" in row for row in RunDir(run).read_metrics())  # new rows only


def test_every_evaluation_is_kept(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    before = {p.name for p in (run / "eval").iterdir()}
    for extra in (["--seed", "1"], ["--seed", "2"], ["--seed", "1", "--stochastic"]):
        assert gcnt(["eval", str(run), "--robots", "hopper_3", "--episodes", "1", *extra]) == 0
    new = {p.name for p in (run / "eval").iterdir()} - before
    assert len(new) == 3 and all(n.startswith("hopper_3-step") for n in new), new
    for name in new:
        assert json.loads((run / "eval" / name).read_text())["robots"]["hopper_3"]["episodes"] == 1


def test_a_bad_robot_leaves_no_directory_and_default_names_do_not_drift(
    tmp_path, recipe_file, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    bad = walker(tmp_path, "walker_bad.xml", 'size="0.0448"', 'size="-1"')
    for _ in range(2):
        error_line(capsys, ["train", str(recipe_file), f"env.robots=[{bad}]"])
    assert not (tmp_path / "runs").exists()
    assert RunDir.for_recipe(_tiny(recipe_file)).path.name == "seed0"


def _tiny(recipe_file: Path):
    from gcnt.recipes import load_recipe

    return load_recipe(recipe_file)


def test_resuming_a_finished_run_trains_nothing(trained, tmp_path):
    run = copy_run(trained, tmp_path)
    rows = RunDir(run).read_metrics()
    state = RunDir(run).load_checkpoint()
    assert gcnt(["train", "--resume", str(run)]) == 0
    assert RunDir(run).read_metrics() == rows
    assert RunDir(run).load_checkpoint()["env_steps"] == state["env_steps"]


# ------------------------------------------------------------------ 5. files outside the folder


def test_includes_resolve_against_the_robot_folder_not_the_current_directory(tmp_path, monkeypatch):
    from gcnt.morphology import load_robot

    decoy = tmp_path / "parts"  # what a cwd-relative include would pick up
    decoy.mkdir()
    (decoy / "defaults.xml").write_text(
        '<mujoco><default><geom rgba="1 0 0 1"/></default></mujoco>'
    )
    monkeypatch.chdir(tmp_path)
    robot = load_robot(DATA / "includes" / "walker_split.xml")
    assert robot.body_names == ("torso", "left1", "left2", "right1", "right2")
    assert robot.num_motors == 4
    model = robot.compile()  # self-contained: compiles from any directory
    assert model.geom_rgba[1].tolist() != [1.0, 0.0, 0.0, 1.0]
    assert model.dof_damping[-1] == pytest.approx(0.1)  # from parts/defaults.xml


def test_includes_that_leave_the_robot_folder_are_refused(tmp_path, recipe_file, capsys):
    outside = DATA / "includes" / "walker_outside.xml"
    line = error_line(
        capsys, ["train", str(recipe_file), f"env.robots=[{outside}]", f"run_dir={tmp_path}/run"]
    )
    assert str(outside) in line and "'../outside_legs.xml' leads out of the robot's folder" in line
    absolute = walker(
        tmp_path,
        "walker_abs.xml",
        "<worldbody>",
        f'<include file="{DATA / "outside_legs.xml"}"/><worldbody>',
    )
    line = error_line(
        capsys, ["train", str(recipe_file), f"env.robots=[{absolute}]", f"run_dir={tmp_path}/run"]
    )
    assert "is an absolute path" in line and str(absolute) in line
    assert not (tmp_path / "run").exists()


# ------------------------------------------------------------------ 6. a new morphology is not bad


NEW = sorted((DATA / "new_morphologies").glob("*.xml"))


@pytest.mark.parametrize("path", NEW, ids=lambda p: p.stem)
def test_unseen_morphologies_in_other_styles_load_and_evaluate_zero_shot(
    path, trained, tmp_path, capsys
):
    from gcnt.morphology import GLOBAL_TYPE_ID, load_robot

    robot = load_robot(path)
    # every limb is typed by its name or by its segment position along its chain
    depth = [0] * robot.num_limbs
    for i in range(1, robot.num_limbs):
        depth[i] = depth[int(robot.parents[i])] + 1
    assert robot.family_slots.tolist() == [min(d, 3) for d in depth]
    foot_or_deeper = [t for t, d in zip(robot.global_types, depth, strict=True) if d >= 3]
    assert all(t == GLOBAL_TYPE_ID["foot"] for t in foot_or_deeper)
    run = copy_run(trained, tmp_path)
    assert gcnt(["eval", str(run), "--robots", str(path), "--episodes", "1"]) == 0
    assert path.stem in capsys.readouterr().out


def test_what_the_model_cannot_represent_is_refused_saying_why(tmp_path, recipe_file, capsys):
    servo = DATA / "walker_position_servo.xml"
    line = error_line(
        capsys, ["train", str(recipe_file), f"env.robots=[{servo}]", f"run_dir={tmp_path}/run"]
    )
    assert "'left2_servo' is a servo" in line and "not a motor" in line
    two = walker(
        tmp_path,
        "walker_two_hinges.xml",
        '<joint name="left2_joint"',
        '<joint name="left2_x" axis="1 0 0"/><joint name="left2_joint"',
    )
    two.write_text(two.read_text().replace("</actuator>", '<motor joint="left2_x"/></actuator>'))
    line = error_line(
        capsys, ["train", str(recipe_file), f"env.robots=[{two}]", f"run_dir={tmp_path}/run"]
    )
    assert "limb 'left2' has 2 joints; family 'walker' allows at most 1" in line


# ------------------------------------------------------------------ 7. noise


def test_a_nan_action_raises_naming_the_robot():
    """A NaN action is a bug of the policy, not physics: the env raises (naming the robot) rather
    than ending the episode as a blow-up would; a diverging run stops before it acts (above)."""
    from gcnt.envs.smpenv import SMPEnv
    from gcnt.morphology.catalogues import resolve_robots

    env = SMPEnv(resolve_robots(["hopper_3", "walker_2_main"]), seed=0, num_threads=1)
    try:
        td = env.reset()
        action = (
            torch.zeros_like(td["limbs", "action"])
            if ("limbs", "action") in td.keys(True)
            else env.full_action_spec.zero()["limbs", "action"]
        )
        action[1, 1, 0] = math.nan
        td["limbs", "action"] = action
        with pytest.raises(
            ValueError,
            match=r"non-finite \(NaN/inf\) action for robot "
            r"'walker_2_main' \(sub-env 1\)",
        ):
            env.step(td)
    finally:
        env.close()


def test_training_and_test_robot_lists_that_overlap_name_the_robots(tmp_path, capsys):
    quickstart = str(Path(__file__).parents[1] / "recipes" / "quickstart.yaml")
    # a split and a name, a robot file and its catalogue name: the same robots
    hopper_3 = Path(__file__).parents[1] / "morphologies" / "smpenv" / "hopper_3.xml"
    overlap = f'env.test_robots=[hopper_5, "{hopper_3}", walker_2_main]'
    tiny = ["collector.total_frames=20", "td3.init_random_frames=10", "eval.episodes=0"]
    line = error_line(capsys, ["train", quickstart, overlap, *tiny, f"run_dir={tmp_path / 'r'}"])
    assert "env.robots and env.test_robots both list hopper_3, hopper_5" in line
    assert not (tmp_path / "r").exists()
