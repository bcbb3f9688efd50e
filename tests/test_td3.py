"""TD3 pipeline: the per-robot target, buffers, every recipe end to end (tiny), resume, eval."""

import json
import shutil
from pathlib import Path

import pytest
import torch
from reference_td3 import PerRobotTD0
from tensordict import TensorDict

from gcnt.cli import main as gcnt
from gcnt.morphology import morphologies_dir
from gcnt.recipes import load_recipe
from gcnt.rl.factories import train_robots
from gcnt.rl.loop import train
from gcnt.rl.td3.loss import masked_mean, td_target
from gcnt.run.directory import RunDir

ROOT = Path(__file__).parents[1]
RECIPES = sorted(
    p
    for p in (ROOT / "recipes").rglob("*.yaml")
    if not p.name.startswith("_") and load_recipe(p).algo == "td3"  # PPO: tests/test_ppo.py
)

TINY = [
    "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}",
    "env.max_episode_steps=15",
    "td3.init_random_frames=40",
    "td3.steps_per_batch=5",
    "td3.batch_size=8",
    "td3.buffer_size_per_robot=2000",
    "logger.backend=none",
    "logger.progress=false",
    "logger.log_interval=40",
    "eval.episodes=1",
    "eval.robots=[hopper_3]",
    "td3.updates_per_step=0.25",
    "eval.interval=0",
    "checkpoint_interval=60",
]


def tiny(path, run_dir, *extra, frames=None):
    recipe = load_recipe(path, [*TINY, f"run_dir={run_dir}", *extra])
    n = len(train_robots(recipe))
    # a few update phases whatever the robot count: random steps, then ~4 lockstep chunks
    recipe.td3.init_random_frames = 5 * n if recipe.td3.random_counted == "total" else 5
    recipe.collector.total_frames = frames or 20 * n
    return recipe


def test_robot_mean_td_target_on_a_terminated_and_a_truncated_row():
    """The ``robot_mean`` rule of ``td_target``, float64: a truncated row bootstraps from the
    mean over real limbs of min(Q1', Q2'); a terminated row is the reward alone; padding (limb 2)
    never enters. torchrl's TD(0) estimator with the same per-robot value agrees."""
    q1 = torch.tensor([[1.0, 2.0, 100.0], [4.0, 8.0, -50.0]], dtype=torch.float64).unsqueeze(-1)
    q2 = torch.tensor([[3.0, 0.5, -100.0], [2.0, 9.0, 70.0]], dtype=torch.float64).unsqueeze(-1)
    mask = torch.tensor([[1, 1, 0], [1, 1, 0]]).bool()
    reward = torch.tensor([[1.0], [2.0]], dtype=torch.float64)
    terminated = torch.tensor([[False], [True]])  # row 0: truncated (done, not terminated)
    target = td_target(reward, terminated, (q1, q2), mask, 0.5, "robot_mean")
    assert target.dtype == torch.float64 and target.shape == (2, 1)
    # row 0: min per limb (1, 0.5) -> mean 0.75; row 1: the reward alone
    assert target.flatten().tolist() == [1.0 + 0.5 * 0.75, 2.0]

    est = PerRobotTD0(gamma=0.5, value_network=None)
    est.set_keys(value=("limbs", "state_action_value"))
    td = TensorDict(
        {
            "limbs": {"mask": mask},
            "next": {
                "limbs": {"state_action_value": torch.minimum(q1, q2)},
                "reward": reward,
                "done": torch.tensor([[True], [True]]),
                "terminated": terminated,
            },
        },
        batch_size=[2],
    )
    assert torch.equal(est.value_estimate(td).flatten(), target.flatten())


def test_masked_mean_is_the_batch_mean_of_per_robot_means_over_real_limbs():
    values = torch.tensor([[1.0, 3.0, 1000.0], [4.0, 4.0, 4.0]], dtype=torch.float64)
    mask = torch.tensor([[True, True, False], [True, True, True]])
    assert masked_mean(values, mask).item() == (2.0 + 4.0) / 2


def _random_phase_run(tmp_path, name, *extra):
    """Two hoppers, 20 random steps per robot, a log row every collector batch (10 steps)."""
    recipe = load_recipe(
        ROOT / "recipes/smpenv/hopper.yaml",
        [
            *TINY,
            "env.robots=[hopper_3,hopper_4]",
            "td3.init_random_frames=20",
            "td3.updates_per_step=1.0",
            "td3.schedule=mixed",
            "collector.total_frames=70",
            "logger.log_interval=10",
            f"run_dir={tmp_path / name}",
            *extra,
        ],
    )
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    train(recipe, run)
    return run.load_recipe(), run.read_metrics()


def test_random_phase_is_per_robot_with_updates_from_the_first_round(tmp_path):
    """The SWAT/AMORPHEUS reading (the default): ``init_random_frames`` per training robot
    (2 x 20 = 40 random steps), and updates on the random phase's data as soon as every robot
    holds a batch."""
    recipe, rows = _random_phase_run(tmp_path, "originals")
    assert recipe.resolved["init_random_frames"] == 40
    during = [r for r in rows if r["env_steps"] <= 40]
    assert during and during[-1]["updates"] > 0
    assert rows[-1]["updates"] > during[-1]["updates"]


def test_random_phase_over_all_robots_without_updates_when_asked(tmp_path):
    """gcnt's earlier reading, kept as an option: 20 random steps over all robots, no update
    before they are done."""
    recipe, rows = _random_phase_run(
        tmp_path, "total", "td3.random_counted=total", "td3.update_during_random=false"
    )
    assert recipe.resolved["init_random_frames"] == 20
    assert all(r["updates"] == 0 for r in rows if r["env_steps"] < 20)
    assert rows[-1]["updates"] > 0


def test_a_random_phase_of_the_whole_run_counted_per_robot_is_refused(tmp_path, capsys):
    code = gcnt(
        [
            "train",
            str(ROOT / "recipes/smpenv/hopper.yaml"),
            *TINY,
            "env.robots=[hopper_3,hopper_4]",
            "td3.init_random_frames=40",
            "collector.total_frames=60",
            f"run_dir={tmp_path / 'run'}",
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and "td3.init_random_frames (40 x 2 robots" in err[-1]
    assert not (tmp_path / "run").exists()


def test_a_recorded_run_without_the_random_phase_keys_keeps_its_reading():
    """A run recorded before ``random_counted`` and ``update_during_random`` existed resumes as
    it trained: random steps over all robots, no update during them."""
    recipe = RunDir(ROOT / "tests/data/td3_run_b52e8ec").load_recipe(anywhere=True)
    assert (recipe.td3.random_counted, recipe.td3.update_during_random) == ("total", False)
    assert load_recipe(ROOT / "recipes/smpenv/walker.yaml").td3.random_counted == "per_robot"


@pytest.mark.parametrize("path", RECIPES, ids=lambda p: str(p.relative_to(ROOT / "recipes")))
def test_every_recipe_trains_a_few_steps(path, tmp_path):
    recipe = tiny(path, tmp_path / "run")
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    train(recipe, run)
    rows = run.read_metrics()
    assert rows[-1]["env_steps"] >= recipe.collector.total_frames
    assert rows[-1]["updates"] > 0 and any("loss_critic" in r for r in rows)
    assert run.checkpoint_path.exists()
    assert list((run.path / "eval").glob("step*.json"))
    assert run.load_recipe().resolved["frames_per_batch"] > 0  # derived sizes written back


@pytest.mark.parametrize("method", ["amorpheus", "swat", "smp", "gcnt_no_dist", "mlp"])
def test_methods_selectable_by_override(method, tmp_path):
    # SR's MLP is one network per robot: it trains one robot (several are refused)
    one = ["env.robots=[walker_7_main]"] if method == "mlp" else []
    recipe = tiny(
        ROOT / "recipes/smpenv/walker.yaml", tmp_path / "run", f"network.name={method}", *one
    )
    if method in ("smp", "mlp"):
        recipe.network.kwargs = {}
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    train(recipe, run)
    assert run.read_metrics()[-1]["updates"] > 0


def test_paper_and_mixed_schedules_count_every_stored_step(tmp_path):
    for schedule in ("paper", "mixed"):
        recipe = tiny(ROOT / "recipes/smpenv/hopper.yaml", tmp_path / schedule)
        recipe.td3.schedule = schedule
        run = RunDir(recipe.run_dir)
        run.create(recipe)
        train(recipe, run)
        last = run.read_metrics()[-1]
        # 3 robots x 5 lockstep steps per chunk: every stored transition counted
        assert last["env_steps"] % 15 == 0 and last["env_steps"] >= recipe.collector.total_frames


def test_resume_continues_the_step_count_and_metrics(tmp_path):
    run_dir = tmp_path / "run"
    recipe = tiny(ROOT / "recipes/smpenv/hopper.yaml", run_dir, frames=90)
    run = RunDir(run_dir)
    run.create(recipe)
    train(recipe, run)  # "killed" after 90 steps: its checkpoint is at 90
    first = run.read_metrics()
    state = run.load_checkpoint()
    assert state["env_steps"] == 90
    # a metrics line written after the checkpoint (the run died later) is dropped on resume, and
    # an evaluation of that stretch is set aside
    run.log_metrics({"env_steps": 105, "updates": 0})
    (run_dir / "eval" / "step105.json").write_text('{"env_steps": 105, "robots": {}}')
    assert gcnt(["train", "--resume", str(run_dir), "collector.total_frames=150"]) == 0
    assert (run_dir / "eval" / "superseded" / "step105.json").exists()
    assert not (run_dir / "eval" / "step105.json").exists()
    rows = run.read_metrics()
    assert rows[: len(first)] == first
    assert [r["env_steps"] for r in rows[len(first) :]] == [120, 150]
    assert run.load_checkpoint()["learner"]["updates"] > state["learner"]["updates"]
    # a learning rate given on resume is the one the optimisers use from then on
    from gcnt.rl.factories import make_env, train_robots
    from gcnt.rl.td3.learner import TD3Learner

    lower = run.load_recipe(["td3.lr=1e-5"])
    env = make_env(lower, train_robots(lower))
    learner = TD3Learner(lower, env)
    learner.load_state_dict(run.load_checkpoint()["learner"])
    env.close()
    assert {g["lr"] for o in (learner.actor_opt, learner.critic_opt) for g in o.param_groups} == {
        1e-5
    }
    # resuming a finished run does not train past its total
    assert gcnt(["train", "--resume", str(run_dir), "collector.total_frames=150"]) == 0
    assert run.load_checkpoint()["env_steps"] == 150 and run.read_metrics() == rows
    # the resumed run refuses to be created again over itself
    assert gcnt(["train", str(ROOT / "recipes/smpenv/hopper.yaml"), f"run_dir={run_dir}"]) == 2


def test_eval_on_a_robot_file_never_seen_in_training(tmp_path, capsys):
    run_dir = tmp_path / "run"
    recipe = tiny(ROOT / "recipes/smpenv/hopper.yaml", run_dir)
    run = RunDir(run_dir)
    run.create(recipe)
    train(recipe, run)
    unseen = tmp_path / "my_walker.xml"
    shutil.copy(morphologies_dir() / "smpenv" / "walker_6_main.xml", unseen)
    out = tmp_path / "eval.json"
    assert (
        gcnt(
            [
                "eval",
                str(run_dir),
                "--robots",
                str(unseen),
                "hopper_4",
                "--episodes",
                "3",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    results = json.loads(out.read_text())["robots"]
    assert set(results) == {"my_walker", "hopper_4"}
    assert results["my_walker"]["episodes"] == 3
    assert "my_walker" in capsys.readouterr().out


def test_misspelt_recipe_key_fails_with_a_clear_message(capsys):
    assert gcnt(["train", str(ROOT / "recipes/smpenv/walker.yaml"), "td3.lrr=1"]) == 2
    assert "unknown recipe key 'td3.lrr'; did you mean 'lr'?" in capsys.readouterr().err


def test_default_run_dirs_never_overwrite_a_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    recipe = load_recipe(ROOT / "recipes/quickstart.yaml")
    first = RunDir.for_recipe(recipe)
    assert first.path == Path("runs/quickstart/td3-gcnt/seed0")
    first.create(recipe)
    recipe.run_dir = None
    assert RunDir.for_recipe(recipe).path == Path("runs/quickstart/td3-gcnt/seed0-1")


def test_eval_video_is_written(tmp_path):
    recipe = tiny(ROOT / "recipes/smpenv/hopper.yaml", tmp_path / "run", "eval.video=true")
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    train(recipe, run)
    videos = list((run.path / "videos").glob("step*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000
