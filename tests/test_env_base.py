"""The batched MuJoCo env base with a toy benchmark: 2 action slots per limb, a root output, a
static limb context, partial resets, per-sub-env rules; blow-up reporting; the SMPENV record.

Checks are structural or exact float64 comparisons of values the env copies (no float32
arithmetic whose rounding could differ between CPUs)."""

from __future__ import annotations

import dataclasses
import logging
import warnings

import mujoco
import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from gcnt.envs import (
    STATIC_KEYS,
    BatchedMujocoEnv,
    Featurizer,
    PhysicsBlowupWarning,
    RobotTooLargeError,
    SMPEnv,
    TaskRules,
    robot_table,
)
from gcnt.envs.benchmark import get_benchmark
from gcnt.morphology.catalogues import smpenv_robot

SLOTS = 2


def two_slot(name: str):
    """An SMPENV robot whose limb l drives action slot l % 2 (the physics is unchanged)."""
    r = smpenv_robot(name)
    slots = tuple(tuple(1 if limb % 2 else 0 for _ in j) for limb, j in enumerate(r.actuator_ids))
    return dataclasses.replace(r, joint_slots=slots)


class ToyFeaturizer(Featurizer):
    """obs: world position of each limb body (F=3); root output "probe": (time, qpos[0]);
    context: (limb index, body mass)."""

    obs_dim = 3
    context_dim = 2

    def __init__(self, robots, models, k):
        self.robots, self.k = robots, k
        n = len(robots)
        self.pos = np.zeros((n, k, 3))
        self.probe = np.zeros((n, 2))

    @property
    def root_outputs(self):
        return {"probe": 2}

    def limb_context(self, robot, model):
        return np.stack([np.arange(robot.num_limbs), model.body_mass[robot.mj_body_ids]], axis=1)

    def gather(self, j, data):
        r = self.robots[j]
        self.pos[j, : r.num_limbs] = data.xpos[r.mj_body_ids]
        self.probe[j] = data.time, data.qpos[0]

    def compute(self, rows=None):
        return (self.pos if rows is None else self.pos[rows]).astype(np.float32)

    def compute_root(self, rows=None):
        return {"probe": (self.probe if rows is None else self.probe[rows]).astype(np.float32)}


class ToyRules(TaskRules):
    """Start: qpos0 + U(±0.01); reward: time since begin(); terminated when ``fail`` is set."""

    edits_model = False

    def __init__(self, robot, model, dt):
        self.dt, self.t0, self.fail, self.renders = dt, 0.0, False, 0

    def reset(self, model, data, rng):
        data.qpos[:] += rng.uniform(-0.01, 0.01, model.nq)

    def begin(self, data):
        self.t0 = data.time

    def step(self, data, action_sq):
        return data.time - self.t0, self.fail

    def sync_render(self, model, renderer):
        self.renders += 1


class EditingRules(ToyRules):
    edits_model = True


def toy_env(names=("walker_7_main", "cheetah_3_back", "walker_7_main"), rules=ToyRules, **kw):
    kw.setdefault("seed", 0)
    kw.setdefault("num_threads", 2)
    return BatchedMujocoEnv(
        [two_slot(n) for n in names],
        featurizer=ToyFeaturizer,
        rules=rules,
        action_slots=SLOTS,
        frame_skip=2,
        name="ToyEnv",
        **kw,
    )


def test_toy_specs_shapes_and_static_keys():
    env = toy_env(max_limbs=8)
    check_env_specs(env, seed=0)
    td = env.reset()
    assert td["limbs", "obs"].shape == (3, 8, 3)
    assert td["probe"].shape == (3, 2) and td["probe"].dtype == torch.float32
    assert env.action_spec["limbs", "action"].shape == (3, 8, SLOTS)
    amask = td["limbs", "action_mask"]
    assert amask.shape == (3, 8, SLOTS)
    w = two_slot("walker_7_main")
    for limb in range(8):
        expected = [False, False]
        if 0 < limb < w.num_limbs:
            expected[limb % 2] = True
        assert amask[0, limb].tolist() == expected, limb
    # the static context: in the table and in every output, zeros on padding
    assert ("limbs", "context") in STATIC_KEYS
    ctx = env.table["limbs", "context"]
    assert ctx.shape == (2, 8, 2) and ctx.dtype == torch.float32
    m = env.sim(0)[0]
    want = np.zeros((8, 2))
    want[: w.num_limbs, 0] = np.arange(w.num_limbs)
    want[: w.num_limbs, 1] = m.body_mass[w.mj_body_ids]
    np.testing.assert_array_equal(ctx[0].double().numpy(), want.astype(np.float32))
    assert torch.equal(td["limbs", "context"], ctx[env.local_ids])
    env.close()


def test_actions_go_to_the_motor_of_their_slot():
    env = toy_env(num_threads=1)
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    act = torch.rand(env.action_spec["limbs", "action"].shape, generator=gen) * 3 - 1.5
    act[~td["limbs", "action_mask"]] = float("nan")  # ignored where no motor drives the slot
    td["limbs", "action"] = act
    env.step(td)
    for i, r in enumerate(env.robots):
        d = env.sim(i)[1]
        for limb, motors in enumerate(r.actuator_ids):
            for motor, slot in zip(motors, r.action_slots(limb), strict=True):
                want = float(np.clip(act[i, limb, slot].double().item(), -1, 1))
                assert d.ctrl[motor] == want, (r.name, limb)
    act = torch.zeros_like(act)
    act[1, 1, 1] = float("nan")  # cheetah_3_back limb 1 drives slot 1
    td["limbs", "action"] = act
    with pytest.raises(ValueError, match=r"cheetah_3_back' \(sub-env 1\)"):
        env.step(td)


def test_rules_reward_termination_and_root_output():
    env = toy_env(num_threads=1)
    td = env.reset()
    td["limbs", "action"] = torch.zeros(env.action_spec["limbs", "action"].shape)
    env.task_rules(2).fail = True
    out = env.step(td)["next"]
    assert out["terminated"][:, 0].tolist() == [False, False, True]
    assert torch.equal(out["done"], out["terminated"] | out["truncated"])
    for i in range(3):
        m, d = env.sim(i)
        assert float(out["reward"][i, 0]) == np.float32(d.time)  # time since reset
        assert float(out["probe"][i, 0]) == np.float32(d.time)
        assert d.time == pytest.approx(2 * m.opt.timestep)  # frame_skip 2
    r = env.robots[1]
    want = env.sim(1)[1].xpos[r.mj_body_ids].astype(np.float32)
    np.testing.assert_array_equal(out["limbs", "obs"][1, : r.num_limbs].numpy(), want)
    assert (out["limbs", "obs"][1, r.num_limbs :] == 0).all()


def test_partial_reset_and_partial_step():
    env = toy_env(num_threads=2)
    td = env.reset()
    zero = torch.zeros(env.action_spec["limbs", "action"].shape)
    for _ in range(3):
        td["limbs", "action"] = zero
        td = env.step(td)["next"]
    before = td.clone()
    qpos = [env.sim(i)[1].qpos.copy() for i in range(3)]
    td["_reset"] = torch.tensor([[False], [True], [False]])
    out = env.reset(td)
    for i in (0, 2):
        np.testing.assert_array_equal(env.sim(i)[1].qpos, qpos[i])
        assert torch.equal(out["limbs", "obs"][i], before["limbs", "obs"][i])
        assert torch.equal(out["probe"][i], before["probe"][i])
    assert env.sim(1)[1].time == 0.0 and float(out["probe"][1, 0]) == 0.0
    m1 = env.sim(1)[0]
    assert np.abs(env.sim(1)[1].qpos - m1.qpos0).max() <= 0.01
    # only sub-env 0 steps; the others keep state, reward 0
    out["limbs", "action"] = zero
    out["_step"] = torch.tensor([[True], [False], [False]])
    times = [env.sim(i)[1].time for i in range(3)]
    nxt = env.step(out)["next"]
    assert env.sim(0)[1].time > times[0]
    assert [env.sim(i)[1].time for i in (1, 2)] == times[1:]
    assert nxt["reward"][1:, 0].tolist() == [0.0, 0.0]
    # the same seed gives the same start states
    a, b = toy_env(seed=3), toy_env(seed=3)
    assert torch.equal(a.reset()["limbs", "obs"], b.reset()["limbs", "obs"])


def test_models_shared_unless_rules_edit_them():
    env = toy_env()
    assert env.sim(0)[0] is env.sim(2)[0]  # two copies of walker_7_main
    env = toy_env(rules=EditingRules)
    assert env.sim(0)[0] is not env.sim(2)[0]
    assert isinstance(env.task_rules(0), EditingRules)
    env.sync_render(2, env.sim(2)[0], None)
    assert env.task_rules(2).renders == 1 and env.task_rules(0).renders == 0


def test_root_output_names_may_not_shadow_the_contract():
    class Clash(ToyFeaturizer):
        @property
        def root_outputs(self):
            return {"reward": 1}

    with pytest.raises(ValueError, match="Clash: root output names"):
        BatchedMujocoEnv(
            [two_slot("walker_2_main")],
            featurizer=Clash,
            rules=ToyRules,
            action_slots=SLOTS,
            frame_skip=2,
        )


def test_robot_table_slots_context_and_errors():
    w = smpenv_robot("walker_3_main")
    t = robot_table([w])  # the original signature still works
    assert t["limbs", "action_mask"].shape == (1, 3, 1)
    assert ("limbs", "context") not in t.keys(True, True)
    t = robot_table([two_slot("walker_3_main")], 4, 2, context=[np.ones((3, 5))])
    assert t["limbs", "action_mask"][0].int().tolist() == [[0, 0], [0, 1], [1, 0], [0, 0]]
    assert t["limbs", "context"][0].sum(-1).tolist() == [5, 5, 5, 0]
    with pytest.raises(RobotTooLargeError, match="action slot 1"):
        robot_table([two_slot("walker_3_main")], None, 1)
    with pytest.raises(ValueError, match="walker_3_main.*context of shape"):
        robot_table([w], context=[np.ones((2, 5))])


# --------------------------------------------------------------------------- blow-ups


def test_one_blowup_warning_per_episode_and_no_mujoco_lines(caplog, capfd):
    env = SMPEnv([smpenv_robot("walker_7_main"), smpenv_robot("hopper_3")], seed=0)
    td = env.reset()
    zero = torch.zeros(env.action_spec["limbs", "action"].shape)
    caplog.set_level(logging.WARNING)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(4):  # blow up again and again without a reset
            env.sim(1)[1].qvel[:] = 1e12
            td["limbs", "action"] = zero
            td = env.step(td)["next"]
            assert bool(td["terminated"][1, 0])
        td["_reset"] = torch.tensor([[False], [True]])
        td = env.reset(td)
        env.sim(1)[1].qvel[:] = 1e12
        td["limbs", "action"] = zero
        env.step(td)
    blowups = [w for w in caught if issubclass(w.category, PhysicsBlowupWarning)]
    assert len(blowups) == 2  # one per episode
    assert "hopper_3" in str(blowups[0].message) and "sub-env 1" in str(blowups[0].message)
    assert not [r for r in caplog.records if "huge value" in r.getMessage()]
    captured = capfd.readouterr()
    assert "huge value" not in captured.out + captured.err


def test_other_mujoco_warnings_are_still_logged(caplog):
    SMPEnv([smpenv_robot("walker_2_main")], num_threads=1)  # installs the handler
    handler = mujoco.get_mju_user_warning()
    with caplog.at_level(logging.WARNING, logger="gcnt.mujoco"):
        handler("Nan, Inf or huge value in QACC at DOF 0. The simulation is unstable.")
        handler("Pre-allocated constraint buffer is full.")
    assert [r.getMessage() for r in caplog.records] == ["Pre-allocated constraint buffer is full."]


# --------------------------------------------------------------------------- the SMPENV record


def test_smpenv_benchmark_builds_its_env():
    bench = get_benchmark("smpenv")
    env = bench.make_env(
        [smpenv_robot("walker_2_main"), smpenv_robot("cheetah_2_back")],
        max_limbs=5,
        seed=1,
        num_threads=1,
        robot_ids=[4, 9],
    )
    assert isinstance(env, SMPEnv)
    assert env.observation_spec["limbs", "obs"].shape[-1] == bench.limb_obs_dim
    assert env.action_spec["limbs", "action"].shape[-1] == bench.action_slots
    assert env.reset()["morph_id"].tolist() == [4, 9]
    assert env.max_limbs == 5
    with pytest.raises(ValueError, match="smpenv.*no worlds"):
        bench.make_env([smpenv_robot("walker_2_main")], world="incline")


def test_spinning_openmp_is_reported_once(monkeypatch, caplog):
    import gcnt
    from gcnt.envs import stepper

    monkeypatch.setattr(gcnt, "OPENMP_SPINS", True)
    monkeypatch.setattr(stepper, "_openmp_warned", False)
    with caplog.at_level(logging.WARNING, logger="gcnt.envs.stepper"):
        for _ in range(2):
            toy_env(num_threads=2).close()
        toy_env(num_threads=1).close()
    lines = [r.getMessage() for r in caplog.records if "GOMP_SPINCOUNT" in r.getMessage()]
    assert len(lines) == 1 and "import gcnt first" in lines[0]


def test_gcnt_shortens_the_openmp_spin_before_torch():
    import os
    import subprocess
    import sys

    def run(code, **extra):
        env = {
            k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")
        }
        env.update(extra)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
        return out.stdout.split(), out.stderr

    show = "print(os.environ.get('GOMP_SPINCOUNT'), gcnt.OPENMP_SPINS)"
    got, err = run(f"import gcnt, os, torch; {show}")
    assert got == ["10000", "False"], err
    got, err = run(f"import torch, gcnt, os; {show}")  # too late for torch: reported
    assert got == ["10000", "True"], err
    got, err = run(f"import gcnt, os; {show}", OMP_WAIT_POLICY="PASSIVE")  # the user's wins
    assert got == ["None", "False"], err
    got, err = run(f"import gcnt, os; {show}", GOMP_SPINCOUNT="5")
    assert got == ["5", "False"], err


@pytest.mark.parametrize("benchmark", ["smpenv", "unimal"])
def test_partial_reset_merge_equals_torchrl_default(benchmark, monkeypatch):
    """The env merges a partial reset with one update; TorchRL's masked merge gives the same
    rollout (every key, every step, resets included)."""
    from torchrl.envs import EnvBase

    from gcnt.morphology.catalogues import resolve_robots

    bench = get_benchmark(benchmark)
    names = ["hopper_3", "walker_7_main", "cheetah_2_front"]
    if benchmark == "unimal":
        names = ["unimal_0000", "unimal_0001", "unimal_0002"]
    robots = resolve_robots(names)
    world = {"world": "obstacles"} if benchmark == "unimal" else {}

    def rollout(default_merge: bool):
        with monkeypatch.context() as m:
            if default_merge:
                m.setattr(BatchedMujocoEnv, "_reset_proc_data", EnvBase._reset_proc_data)
            env = bench.make_env(robots, seed=5, num_threads=1, max_episode_steps=7, **world)
            gen = torch.Generator().manual_seed(1)
            td, outs = env.reset(), []
            for step in range(20):
                shape = env.action_spec["limbs", "action"].shape
                td.set(("limbs", "action"), torch.rand(shape, generator=gen) * 2 - 1)
                out, td = env.step_and_maybe_reset(td)
                if step in (3, 10):  # an explicit partial reset
                    td["_reset"] = torch.tensor([[True], [False], [step == 10]])
                    td = env.reset(td)
                outs.append((out.clone(), td.clone()))
            env.close()
        return outs

    mine, torchrl_default = rollout(False), rollout(True)
    assert any(o["next", "done"].any() for o, _ in mine)  # step_and_maybe_reset reset some
    for (a, ta), (b, tb) in zip(mine, torchrl_default, strict=True):
        assert set(a.keys(True, True)) == set(b.keys(True, True))
        assert set(ta.keys(True, True)) == set(tb.keys(True, True))
        for key in a.keys(True, True):
            assert torch.equal(a[key], b[key]), key
        for key in ta.keys(True, True):
            assert torch.equal(ta[key], tb[key]), key
