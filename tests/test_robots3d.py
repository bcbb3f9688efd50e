"""Robot files of other projects: the family read from the structure (dm_control's planar
walker, hopper and cheetah), the general 3-D benchmark ``mjcf3d`` (dm_control's and gymnasium's
humanoid and ant, UNIMAL robots read as 3-D), what it refuses, and zero-shot evaluation of
trained runs on files they never saw."""

from __future__ import annotations

import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from cli_helpers import error_line

from gcnt.cli import main as gcnt
from gcnt.envs.mjcf3d import ACTION_SLOTS, CONTEXT_DIM, OBS_DIM, Mjcf3dEnv
from gcnt.envs.mjcf3d.rules import fall_height, lowest_point
from gcnt.envs.mjcf3d.world import world_model
from gcnt.morphology import (
    GLOBAL_TYPE_ID,
    RobotFileError,
    load_robot,
    morphologies_dir,
    robot_from_xml,
)
from gcnt.morphology.catalogues import resolve_robots
from gcnt.morphology.mjcf3d import package_file

ROOT = Path(__file__).parents[1]
DMC = package_file("dm_control", "suite")
GYM = package_file("gymnasium", "envs/mujoco/assets")
needs_gym = pytest.mark.skipif(
    GYM is None or not GYM.is_dir(), reason="gymnasium (a dev extra) is not installed"
)

# A small 3-D robot of this test's own: a free torso, a welded head, three legs (hip with two
# hinges, knee with one), the first leg's hip with three hinges.
TRIPOD = """<mujoco model="tripod">
  <default><geom conaffinity="0" density="400"/></default>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 .1" conaffinity="1"/>
    <light name="sun" pos="0 0 3"/>
    <body name="core" pos="0 0 0.6">
      <freejoint name="root"/>
      <geom type="sphere" size="0.15"/>
      <body name="head" pos="0.15 0 0.1"><geom type="sphere" size="0.06"/></body>
      {legs}
    </body>
  </worldbody>
  <actuator>{motors}</actuator>
  {extra}
</mujoco>"""


AXES = {"x": "1 0 0", "y": "0 1 0", "z": "0 0 1"}


def tripod(extra: str = "", knee_joint: str = "hinge", ctrl: str = "-1 1") -> str:
    legs, motors = [], []
    knee_range = "0 60" if knee_joint == "ball" else "-60 10"  # a ball joint's range is a cone
    for i, angle in enumerate((0, 120, 240)):
        c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
        hips = "xyz" if i == 0 else "yz"
        joints = "".join(
            f'<joint name="hip{i}_{a}" type="hinge" axis="{AXES[a]}" range="-40 40"/>' for a in hips
        )
        legs.append(
            f'<body name="thigh{i}" pos="{0.15 * c:.3f} {0.15 * s:.3f} 0">{joints}'
            f'<geom type="capsule" fromto="0 0 0 {0.2 * c:.3f} {0.2 * s:.3f} 0" size="0.04"/>'
            f'<body name="shin{i}" pos="{0.2 * c:.3f} {0.2 * s:.3f} 0">'
            f'<joint name="knee{i}" type="{knee_joint}" axis="0 1 0" range="{knee_range}"/>'
            f'<geom type="capsule" fromto="0 0 0 0 0 -0.35" size="0.03"/></body></body>'
        )
        motors += [f'<motor joint="hip{i}_{a}" gear="30" ctrlrange="{ctrl}"/>' for a in hips]
        motors.append(f'<motor name="knee{i}" joint="knee{i}" gear="30" ctrlrange="{ctrl}"/>')
    return TRIPOD.format(legs="".join(legs), motors="".join(motors), extra=extra)


def write(tmp_path: Path, text: str, name: str = "tripod.xml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# ------------------------------------------------------------------ the family from the structure


@pytest.mark.parametrize(
    ("name", "family", "limbs"), [("walker", "walker", 7), ("hopper", "hopper", 5),
                                  ("cheetah", "cheetah", 7)]
)  # fmt: skip
def test_dm_control_planar_files_load_unchanged_as_2d_robots(name, family, limbs):
    robot = load_robot(DMC / f"{name}.xml")
    assert (robot.family, robot.catalogue, robot.num_limbs) == (family, "smpenv", limbs)
    assert robot.num_motors == limbs - 1


def test_a_planar_robot_whose_names_hint_at_nothing_is_a_2d_robot():
    text = (DMC / "walker.xml").read_text().replace('model="planar walker"', 'model="biped"')
    robot = robot_from_xml(text, source="biped.xml", folder=DMC)  # its includes are in DMC
    assert robot.family == "cheetah" and robot.catalogue == "smpenv"  # rules without posture


def test_a_free_root_is_a_3d_robot_and_the_unimal_format_stays_unimal(tmp_path):
    robot = load_robot(write(tmp_path, tripod()))
    assert (robot.family, robot.catalogue) == ("mjcf3d", "mjcf3d")
    unimal = morphologies_dir() / "unimal" / "unimal_0000.xml"
    assert load_robot(unimal).family == "unimal"
    as3d = load_robot(unimal, "mjcf3d", family="mjcf3d")
    assert (as3d.family, as3d.catalogue) == ("mjcf3d", "mjcf3d")
    assert resolve_robots(["unimal3d_0000"])[0].body_names == as3d.body_names


def test_welded_bodies_join_their_parents_limb_and_limbs_carry_up_to_three_hinges(tmp_path):
    robot = load_robot(write(tmp_path, tripod()))
    assert robot.body_names == ("core", "thigh0", "shin0", "thigh1", "shin1", "thigh2", "shin2")
    assert robot.parents.tolist() == [-1, 0, 1, 0, 3, 0, 5]
    assert robot.joint_names[1] == ("hip0_x", "hip0_y", "hip0_z")  # slots in file order
    assert robot.action_slots(1) == (0, 1, 2)
    assert robot.global_types.tolist() == [
        GLOBAL_TYPE_ID[t] for t in ("torso", *("unimal_proximal", "unimal_distal") * 3)
    ]
    human = load_robot(DMC / "humanoid.xml")  # head on the torso, hands on the forearms
    assert "head" not in human.body_names and "right_hand" not in human.body_names
    assert human.joint_names[3] == ("right_hip_x", "right_hip_z", "right_hip_y")
    assert (human.num_limbs, human.num_motors) == (13, 21)


@needs_gym
def test_gymnasium_ant_and_humanoid_load():
    ant = load_robot(GYM / "ant.xml")
    # each leg's jointless first body is welded to the torso; unnamed bodies get a name
    assert (ant.family, ant.num_limbs, ant.num_motors) == ("mjcf3d", 9, 8)
    assert ant.parents.tolist() == [-1, 0, 1, 0, 3, 0, 5, 0, 7]
    assert ant.body_names[2].startswith("body#")
    human = load_robot(GYM / "humanoid.xml")
    assert (human.family, human.num_limbs, human.num_motors) == ("mjcf3d", 11, 17)
    names = resolve_robots(["gym_ant", "gym_humanoid", "dmc_humanoid"])
    assert [r.catalogue for r in names] == ["mjcf3d"] * 3


# ------------------------------------------------------------------ refused in one line


def test_quadruped_tendon_actuators_are_refused_naming_the_tendon(capsys):
    line = error_line(capsys, ["robots", str(DMC / "quadruped.xml")])
    assert "drives tendon 'lift_front_left'" in line
    assert "pitch_front_left, ankle_front_left" in line and "one torque per hinge" in line


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (dict(knee_joint="ball"), ["ball joint 'knee0'", "not a hinge"]),
        (dict(knee_joint="slide"), ["slide joint 'knee0'", "not a hinge"]),
        (
            dict(extra='<equality><connect name="loop" body1="shin0" body2="shin1" '
                       'anchor="0 0 -0.35"/></equality>'),
            ["equality constraint 'loop' (connect)", "closes a loop"],
        ),
    ],
)  # fmt: skip
def test_what_a_3d_robot_cannot_be_is_refused_naming_the_element(tmp_path, capsys, edit, words):
    path = write(tmp_path, tripod(**edit))
    line = error_line(capsys, ["robots", str(path)])
    assert str(path) in line
    for w in words:
        assert w in line, line


def test_four_hinges_on_one_body_are_refused(tmp_path):
    text = (
        tripod()
        .replace('<joint name="hip0_x"', '<joint name="hip0_w" axis="1 1 0"/><joint name="hip0_x"')
        .replace("</actuator>", '<motor joint="hip0_w"/></actuator>')
    )
    with pytest.raises(RobotFileError, match="limb 'thigh0' has 4 joints; family 'mjcf3d' allows"):
        load_robot(write(tmp_path, text))


# ------------------------------------------------------------------ the world, rules, tokens


def test_the_world_replaces_the_files_floor_lights_and_scales_each_control_range(tmp_path):
    robot = load_robot(write(tmp_path, tripod(ctrl="0 2")))
    model = world_model(robot, "ft")
    world_geoms = [model.geom(g).name for g in range(model.ngeom) if model.geom_bodyid[g] == 0]
    # the file's light ("sun") went with its world; the world brings its own
    assert world_geoms == ["floor"] and [model.light(i).name for i in range(model.nlight)] == [
        "world_light"
    ]
    floor = model.geom("floor").id
    # the file's <default><geom conaffinity="0"/> does not reach the world's floor
    assert model.geom_contype[floor] == 1 and model.geom_conaffinity[floor] == 1
    assert model.opt.timestep == 0.005
    data = mujoco.MjData(model)
    knee = model.actuator("knee0").id
    for action, force in ((-1.0, 0.0), (0.0, 1.0), (1.0, 2.0)):  # control range [0, 2]
        data.ctrl[:] = action
        mujoco.mj_forward(model, data)
        assert data.actuator_force[knee] == pytest.approx(force)


def test_fall_height_is_relative_to_the_robots_start_height_and_overridable(tmp_path):
    robot = load_robot(write(tmp_path, tripod()))
    model = world_model(robot, "ft")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    # the shins' capsule tips are the lowest points: 0.6 - 0.35 - 0.03 (radius)
    assert lowest_point(model, data) == pytest.approx(0.6 - 0.35 - 0.03)
    assert fall_height(robot, model, "ft") == pytest.approx(0.5 * (0.35 + 0.03))
    assert fall_height(robot, model, "mt") == pytest.approx(0.3 * (0.35 + 0.03))
    own = '<custom><numeric name="gcnt_fall_ratio" data="0.8"/></custom>'
    robot = load_robot(write(tmp_path, tripod(extra=own)))
    assert fall_height(robot, world_model(robot, "ft"), "mt") == pytest.approx(0.8 * 0.38)


def _yawed(qpos: np.ndarray, yaw: float, shift: tuple[float, float]) -> np.ndarray:
    """``qpos`` with the free root turned by ``yaw`` about z and moved by ``shift``."""
    out = qpos.copy()
    turn = np.zeros(4)
    mujoco.mju_axisAngle2Quat(turn, np.array([0.0, 0.0, 1.0]), yaw)
    c, s = math.cos(yaw), math.sin(yaw)
    x, y = qpos[0], qpos[1]
    out[0:2] = (c * x - s * y + shift[0], s * x + c * y + shift[1])
    quat = np.zeros(4)
    mujoco.mju_mulQuat(quat, turn, qpos[3:7].copy())
    out[3:7] = quat
    return out


def test_tokens_are_seen_in_the_torsos_heading_frame(tmp_path):
    robot = load_robot(write(tmp_path, tripod()))
    env = Mjcf3dEnv([robot], seed=0, num_threads=1)
    td = env.reset()
    assert td["limbs", "obs"].shape == (1, robot.num_limbs, OBS_DIM)
    assert td["limbs", "context"].shape == (1, robot.num_limbs, CONTEXT_DIM)
    assert env.table["limbs", "action_mask"][0].sum() == robot.num_motors
    assert env.table["limbs", "action_mask"][0, 1].tolist() == [True] * ACTION_SLOTS
    model, data = env.sim(0)
    rng = np.random.default_rng(0)
    qpos = data.qpos.copy()
    qvel = rng.normal(0.0, 0.5, model.nv)
    env.set_state(0, qpos, qvel)
    before = env.observe()["limbs", "obs"][0].double()
    # turn the whole robot (and its velocities) by 1 rad about z, move it
    yaw = 1.0
    c, s = math.cos(yaw), math.sin(yaw)
    turned_v = qvel.copy()
    turned_v[0:2] = (c * qvel[0] - s * qvel[1], s * qvel[0] + c * qvel[1])
    # a free joint's angular velocity is in the body frame: unchanged by a turn of the body
    env.set_state(0, _yawed(qpos, yaw, (3.0, -2.0)), turned_v)
    after = env.observe()["limbs", "obs"][0].double()
    torch.testing.assert_close(after, before, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("world", ["ft", "mt"])
def test_the_env_meets_its_specs_on_flat_and_mixed_terrain(world):
    from torchrl.envs.utils import check_env_specs

    robots = resolve_robots(["dmc_humanoid", "unimal3d_0001"])
    env = Mjcf3dEnv(robots, world=world, seed=0, num_threads=1, max_episode_steps=20)
    check_env_specs(env)
    td = env.rollout(25, break_when_any_done=False)
    assert torch.isfinite(td["next", "reward"]).all()
    assert ("hfield" in td.keys()) == (world == "mt")


# ------------------------------------------------------------------ zero-shot on unseen files

TINY_TD3 = """\
base: {root}/recipes/smpenv/_td3.yaml
task: tiny
env: {{robots: [walker_2_main, hopper_3], max_episode_steps: 15}}
collector: {{total_frames: 40}}
td3: {{init_random_frames: 10, steps_per_batch: 5, batch_size: 8, buffer_size_per_robot: 2000,
      updates_per_step: 0.25}}
network: {{kwargs: {{d_model: 16, layers: 1, ff: 16, heads: 2}}}}
logger: {{backend: none, progress: false, log_interval: 20}}
"""

TINY_PPO = """\
base: {root}/recipes/mjcf3d/quickstart.yaml
task: tiny3d
env: {{robots: [unimal3d_0001, dmc_humanoid], max_episode_steps: 20}}
collector: {{total_frames: 256}}
ppo: {{num_envs: 4, steps_per_env: 32, minibatch_size: 64, epochs: 1, uniform_iterations: 1}}
network: {{kwargs: {{d_model: 16, layers: 1, ff: 16, heads: 2}}}}
logger: {{backend: none, progress: false, log_interval: 128}}
checkpoint_interval: 256
eval: {{episodes: 1}}
"""


def _train(tmp_path: Path, recipe: str) -> Path:
    path = tmp_path / "recipe.yaml"
    path.write_text(recipe.format(root=ROOT))
    run = tmp_path / "run"
    assert gcnt(["train", str(path), f"run_dir={run}"]) == 0
    return run


def _eval(capsys, run: Path, *files: Path) -> dict[str, float]:
    """``gcnt eval RUN --robots FILES``: each robot's mean return."""
    capsys.readouterr()
    assert gcnt(["eval", str(run), "--robots", *map(str, files), "--episodes", "1"]) == 0
    written = Path(capsys.readouterr().out.split("written: ")[-1].split()[0])
    robots = json.loads(written.read_text())["robots"]
    return {name: r["mean"] for name, r in robots.items()}


def test_a_2d_run_evaluates_dm_controls_planar_robots_zero_shot(tmp_path, capsys):
    run = _train(tmp_path, TINY_TD3)
    files = [DMC / f"{name}.xml" for name in ("walker", "hopper", "cheetah")]
    returns = _eval(capsys, run, *files)
    assert sorted(returns) == ["cheetah", "hopper", "walker"]
    assert all(math.isfinite(v) for v in returns.values())


def test_a_3d_run_trains_on_a_mix_and_evaluates_an_unseen_3d_file_zero_shot(tmp_path, capsys):
    run = _train(tmp_path, TINY_PPO)
    unseen = GYM / "ant.xml" if GYM is not None else write(tmp_path, tripod())
    returns = _eval(capsys, run, unseen)
    name = "gym_ant" if GYM is not None else unseen.stem  # gymnasium's ant: the catalogue's name
    assert list(returns) == [name] and math.isfinite(returns[name])


def test_a_video_of_a_3d_robot_file_in_its_new_world(tmp_path):
    imageio = pytest.importorskip("imageio.v2")
    from gcnt.envs.render import render_rollout

    try:
        path = render_rollout(
            resolve_robots(["dmc_humanoid"])[0], steps=2, path=tmp_path / "h.mp4", width=32,
            height=32,
        )  # fmt: skip
    except Exception as e:  # no headless OpenGL on this machine
        if "EGL" in repr(e) or "OpenGL" in repr(e) or "gl" in type(e).__name__.lower():
            pytest.skip(f"no headless OpenGL: {e!r}")
        raise
    frames = [f for f in imageio.get_reader(str(path))]  # noqa: C416 (the reader has no len)
    assert frames and frames[0].std() > 0
