"""Every robot file evaluated as it is: the 2-D files of dm_control and gymnasium run real SMPENV
episodes (their root joints start elsewhere than SMPENV's), evaluations report episode lengths
and warn about episodes that end at once, robot files of one model name are two robots, and
``gcnt eval`` refuses an empty robot list before loading torch."""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from gcnt.cli import main as gcnt
from gcnt.envs.smpenv import SMPEnv
from gcnt.envs.smpenv.rules import task_rules
from gcnt.morphology import DuplicateRobotError, load_robot, resolve_robots
from gcnt.morphology.mjcf3d import package_file
from gcnt.morphology.smpenv import SMPENV_ROBOTS
from gcnt.rl.evaluate import SHORT_EPISODE_STEPS, summarize, warn_short_episodes

ROOT = Path(__file__).parents[1]
DMC = package_file("dm_control", "suite")
GYM = package_file("gymnasium", "envs/mujoco/assets")
HAS_GYM = GYM is not None and GYM.is_dir()
needs_gym = pytest.mark.skipif(not HAS_GYM, reason="gymnasium (a dev extra) is not installed")

#: the 2-D robot files the README says load unchanged and evaluate zero-shot
DMC_2D = ["walker", "hopper", "cheetah"]
GYM_2D = ["walker2d", "hopper", "half_cheetah"]
FILES_2D = [DMC / f"{n}.xml" for n in DMC_2D] + (
    [GYM / f"{n}.xml" for n in GYM_2D] if HAS_GYM else []
)

TINY_TD3 = """\
base: {root}/recipes/smpenv/_td3.yaml
task: tiny
env: {{robots: [hopper_3], test_robots: [], max_episode_steps: 100}}
collector: {{total_frames: 40}}
td3: {{init_random_frames: 20, steps_per_batch: 5, batch_size: 8, buffer_size_per_robot: 2000,
      updates_per_step: 0.25}}
network: {{kwargs: {{d_model: 16, layers: 1, ff: 16, heads: 2}}}}
logger: {{backend: none, progress: false, log_interval: 20}}
eval: {{episodes: 1, interval: 0}}
checkpoint_interval: 20
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A tiny TD3 run on hopper_3 (100-step episodes, no test robots)."""
    tmp = tmp_path_factory.mktemp("run")
    recipe = tmp / "recipe.yaml"
    recipe.write_text(TINY_TD3.format(root=ROOT))
    assert gcnt(["train", str(recipe), f"run_dir={tmp / 'run'}"]) == 0
    return tmp / "run"


def _eval(capsys, run: Path, *files: Path) -> tuple[dict, str, str]:
    """``gcnt eval RUN --robots FILES --episodes 2``: the evaluation JSON, the printed text and
    the log (stderr)."""
    capsys.readouterr()
    assert gcnt(["eval", str(run), "--robots", *map(str, files), "--episodes", "2"]) == 0
    out, err = capsys.readouterr()
    return json.loads(Path(out.split("written: ")[-1].split()[0]).read_text()), out, err


def _dm_copy(tmp_path: Path, name: str, edit: tuple[str, str]) -> Path:
    """dm_control's ``name``.xml with one text replacement, beside a copy of its includes."""
    shutil.copytree(DMC / "common", tmp_path / "common", dirs_exist_ok=True)
    text = (DMC / f"{name}.xml").read_text()
    assert edit[0] in text
    path = tmp_path / f"{name}.xml"
    path.write_text(text.replace(*edit))
    return path


def _zero_action_lengths(robot, copies: int = 4, limit: int = 300) -> list[int]:
    """Length of the first episode of each of ``copies`` sub-envs under zero actions."""
    env = SMPEnv([robot] * copies, seed=0, num_threads=1, max_episode_steps=limit)
    td = env.reset()
    td["limbs", "action"] = torch.zeros(env.action_spec["limbs", "action"].shape)
    lengths: list[int | None] = [None] * copies
    for t in range(1, limit + 1):
        done = env.step(td)["next", "done"].reshape(-1).tolist()
        lengths = [t if (n is None and d) else n for n, d in zip(lengths, done, strict=True)]
        if None not in lengths:
            break
    env.close()
    return lengths


# ------------------------------------------------------------------ termination rules


def test_smpenvs_own_files_read_their_qpos_exactly():
    """SMPENV's rules read the root qpos of its own files unchanged (offset and ref exactly 0;
    cheetahs read no height)."""
    for name in SMPENV_ROBOTS:
        robot = load_robot(ROOT / "morphologies" / "smpenv" / f"{name}.xml")
        if not task_rules(robot).can_terminate:
            continue
        env = SMPEnv([robot], seed=0, num_threads=1)
        rules = env.task_rules(0)
        assert (rules.z_offset, rules.pitch_ref) == (0.0, 0.0), name
        model, _ = env.sim(0)
        assert model.qpos0[rules.root.z] == task_rules(robot).start_z, name
        env.close()


@pytest.mark.parametrize("path", FILES_2D, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_every_2d_file_the_readme_lists_runs_a_real_episode(path):
    robot = load_robot(path)
    env = SMPEnv([robot], seed=0, num_threads=1)
    rules, (model, _) = env.task_rules(0), env.sim(0)
    # the written pose reads as the SMPENV start height, whatever the slide-z joint's ref
    assert model.qpos0[rules.root.z] + rules.z_offset == task_rules(robot).start_z
    env.close()
    lengths = _zero_action_lengths(robot)
    assert min(lengths) >= 20, lengths  # dm_control's walker and hopper ended after 1 step


def test_the_tilt_is_read_from_the_pose_the_file_is_written_in(tmp_path):
    """A root hinge whose ref is 60° (qpos0 1.05 rad) starts the torso upright, not tilted."""
    rooty = '<joint name="rooty" axis="0 1 0" type="hinge"'
    path = _dm_copy(tmp_path, "walker", (rooty, rooty + ' ref="60"'))  # MJCF angles: degrees
    model = load_robot(path).compile()
    assert model.qpos0[model.joint("rooty").qposadr[0]] > 1.0  # the SMPENV bound on the tilt
    assert min(_zero_action_lengths(load_robot(path))) >= 20


# ------------------------------------------------------------------ evaluation of files


def test_a_run_evaluates_every_2d_file_with_real_episodes_and_reports_their_lengths(run, capsys):
    out, text, log = _eval(capsys, run, *FILES_2D)
    robots = out["robots"]
    assert len(robots) == out["over_robots"]["robots"] == len(FILES_2D)  # both hoppers
    if HAS_GYM:
        assert {"suite.hopper", "mujoco.hopper"} <= set(robots)
    for name, r in robots.items():
        assert {"mean", "stderr", "episodes", "returns"} <= set(r)  # the keys kept
        assert SHORT_EPISODE_STEPS <= r["length_min"] <= r["length_mean"] <= 100, name
        assert isinstance(r["length_min"], int)
    assert robots["cheetah"]["length_min"] == 100  # cheetahs never terminate: the time limit
    assert "length (mean, min)" in text
    assert "control steps on average" not in log


def test_episodes_that_end_at_once_are_warned_about(run, tmp_path, capsys):
    """A walker under 500 times Earth's gravity falls within a few control steps."""
    heavy = _dm_copy(tmp_path, "walker", ('<option timestep="0.0025"/>',
                                          '<option timestep="0.0025" gravity="0 0 -4900"/>'))  # fmt: skip
    out, text, log = _eval(capsys, run, heavy)
    r = out["robots"]["walker"]
    assert r["length_mean"] < SHORT_EPISODE_STEPS and r["length_min"] <= r["length_mean"]
    warned = [line for line in log.splitlines() if "control steps on average" in line]
    assert len(warned) == 1 and "WARNING" in warned[0] and "'walker'" in warned[0], log
    assert f"{r['length_mean']:.1f}, {r['length_min']}" in text


def test_the_short_episode_warning_leaves_time_limited_episodes_alone(caplog):
    results = {"a": summarize([1.0, 2.0], [3, 5]), "b": summarize([1.0], [12])}
    assert (results["a"]["length_mean"], results["a"]["length_min"]) == (4.0, 3)
    with caplog.at_level(logging.WARNING, logger="gcnt.rl.evaluate"):
        assert warn_short_episodes(results, max_episode_steps=1000) == ["a"]
        assert warn_short_episodes(results, max_episode_steps=4) == []  # a's time limit: 4
    assert "'a'" in caplog.records[0].getMessage()


# ------------------------------------------------------------------ robots identified by file


def test_robot_files_of_one_model_name_are_two_robots(tmp_path, capsys):
    other = tmp_path / "mine" / "hopper.xml"
    shutil.copytree(DMC / "common", other.parent / "common")
    shutil.copy(DMC / "hopper.xml", other)  # the same text in another folder: another file
    robots = resolve_robots([str(DMC / "hopper.xml"), str(other)])
    assert [r.name for r in robots] == ["suite.hopper", "mine.hopper"]
    capsys.readouterr()
    assert gcnt(["robots", str(DMC / "hopper.xml"), str(other)]) == 0
    rows = capsys.readouterr().out
    assert "suite.hopper" in rows and "mine.hopper" in rows


def test_a_robot_file_has_one_name_whatever_else_is_listed(tmp_path):
    def names(*specs) -> list[str]:
        return [r.name for r in resolve_robots([str(s) for s in specs])]

    smpenv = ROOT / "morphologies" / "smpenv"
    mine = tmp_path / "mine" / "xml" / "hopper_3.xml"  # a copy of a catalogue robot's file
    mine.parent.mkdir(parents=True)
    shutil.copy(smpenv / "hopper_3.xml", mine)
    # named apart from the catalogue's hopper_3 whether that is listed or not; the folder "xml"
    # tells nothing apart and is skipped
    assert names(mine) == ["mine.hopper_3"]
    assert names(mine, "hopper_3", "hopper_4") == ["mine.hopper_3", "hopper_3", "hopper_4"]
    assert names(smpenv / "hopper_3.xml") == ["hopper_3"]  # the catalogue robot's own file
    # two files of one name: the nearest folder that tells them apart, generic ones skipped
    other = tmp_path / "other" / "xml" / "hopper_3.xml"
    other.parent.mkdir(parents=True)
    shutil.copy(smpenv / "hopper_3.xml", other)
    assert names(mine, other) == ["mine.hopper_3", "other.hopper_3"]
    # a catalogue's file listed by its path is named as the catalogue names it
    assert names(DMC / "humanoid.xml") == names("dmc_humanoid") == ["dmc_humanoid"]


def test_the_same_robot_listed_twice_is_still_refused():
    hopper = str(DMC / "hopper.xml")
    with pytest.raises(DuplicateRobotError, match="'hopper' is listed twice.*env.copies"):
        resolve_robots([hopper, hopper])
    with pytest.raises(DuplicateRobotError, match="'dmc_humanoid'.*humanoid.xml"):
        resolve_robots(["dmc_humanoid", str(DMC / "humanoid.xml")])  # one file, one robot
    walker = str(ROOT / "morphologies" / "smpenv" / "walker_3_main.xml")
    with pytest.raises(DuplicateRobotError, match="'walker_3_main'"):
        resolve_robots(["walker_3_main", walker])
    assert len(resolve_robots([hopper, "hopper_3", hopper], repeats=True)) == 2


@needs_gym
def test_humanoids_of_both_packages_train_together(tmp_path):
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(f"""\
base: {ROOT}/recipes/mjcf3d/quickstart.yaml
task: two-humanoids
env: {{robots: [{DMC / "humanoid.xml"}, {GYM / "humanoid.xml"}], test_robots: [],
      max_episode_steps: 20}}
collector: {{total_frames: 64}}
ppo: {{num_envs: 2, steps_per_env: 32, minibatch_size: 32, epochs: 1, uniform_iterations: 1}}
network: {{kwargs: {{d_model: 8, layers: 1, ff: 8, heads: 2}}}}
logger: {{backend: none, progress: false, log_interval: 64}}
checkpoint_interval: 64
eval: {{episodes: 1}}
""")  # fmt: skip
    assert gcnt(["train", str(recipe), f"run_dir={tmp_path / 'run'}"]) == 0
    final = sorted((tmp_path / "run" / "eval").glob("step*.json"))[-1]
    assert set(json.loads(final.read_text())["robots"]) == {"dmc_humanoid", "gym_humanoid"}


# ------------------------------------------------------------------ the refusal comes first


def _eval_in_a_new_process(run: Path) -> subprocess.CompletedProcess:
    """``gcnt eval RUN`` in a fresh interpreter; prints its exit code and whether it loaded
    torch and MuJoCo."""
    code = (
        "import sys\n"
        "from gcnt.cli import main\n"
        f"rc = main(['eval', {str(run)!r}])\n"
        "print(rc, 'torch' in sys.modules, 'mujoco' in sys.modules)\n"
    )
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)


def test_eval_refuses_a_run_without_test_robots_before_loading_torch(run):
    done = _eval_in_a_new_process(run)
    assert done.stdout.split() == ["2", "False", "False"], done.stdout + done.stderr
    assert f"{run}: no robots to evaluate" in done.stderr


def test_a_recorded_plugin_not_named_here_loads_no_torch_for_a_built_in_method(run, tmp_path):
    """The run recorded a plugin (imported in its process) but is a built-in method's: checking
    the record needs no registry that loads torch."""
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    recipe = copy / "recipe.yaml"
    data = yaml.safe_load(recipe.read_text())
    data["resolved"]["plugins"] = [{"name": "elsewhere.py", "sha256": "0" * 64}]
    recipe.write_text(yaml.safe_dump(data, sort_keys=False))
    done = _eval_in_a_new_process(copy)
    assert done.stdout.split() == ["2", "False", "False"], done.stdout + done.stderr
    assert f"{copy}: no robots to evaluate" in done.stderr


@needs_gym
def test_a_robot_file_keeps_one_name_in_training_its_evaluation_and_analysis(tmp_path):
    from gcnt.analysis.runs import Run

    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(
        TINY_TD3.format(root=ROOT)
        .replace(
            "robots: [hopper_3], test_robots: []",
            f"robots: [{GYM / 'hopper.xml'}], test_robots: [{DMC / 'hopper.xml'}]",
        )
        .replace("max_episode_steps: 100", "max_episode_steps: 5")
    )  # episodes of 5 steps: training reports the robot's return
    assert gcnt(["train", str(recipe), f"run_dir={tmp_path / 'run'}"]) == 0
    run = Run(tmp_path / "run")
    trained = {k.split("/", 1)[-1] for row in run.metrics() for k in row}
    assert "mujoco.hopper" in trained
    final = sorted((tmp_path / "run" / "eval").glob("step*.json"))[-1]
    assert set(json.loads(final.read_text())["robots"]) == {"mujoco.hopper", "suite.hopper"}
    assert run.train_robot_names() == ["mujoco.hopper"]
    assert run.test_robot_names() == ["suite.hopper"]
    # another file of the name, evaluated later, is named apart from the run's own robots
    other = tmp_path / "mine" / "hopper.xml"
    shutil.copytree(DMC / "common", other.parent / "common")
    shutil.copy(DMC / "hopper.xml", other)
    robots = resolve_robots([str(GYM / "hopper.xml"), str(other)], names_from=run.train_robot_specs)
    assert [r.name for r in robots] == ["hopper", "mine.hopper"]


def test_linked_robot_files_are_named_after_the_paths_they_are_listed_under(tmp_path):
    for real, link in (("h1", "a"), ("h2", "b")):
        (tmp_path / "real").mkdir(exist_ok=True)
        shutil.copy(DMC / "hopper.xml", tmp_path / "real" / f"{real}.xml")
        shutil.copytree(DMC / "common", tmp_path / link / "common")
        (tmp_path / link / "hopper.xml").symlink_to(tmp_path / "real" / f"{real}.xml")
    robots = resolve_robots(
        [str(tmp_path / "a" / "hopper.xml"), str(tmp_path / "b" / "hopper.xml")]
    )
    assert [r.name for r in robots] == ["a.hopper", "b.hopper"]
