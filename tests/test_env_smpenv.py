"""SMPEnv: observations against an independent computation, padding, partial resets, seeding,
bad actions, physics blow-ups, specs and truncation."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from gcnt.envs import PhysicsBlowupWarning, RobotTooLargeError, SMPEnv
from gcnt.envs.smpenv.featurize import LimbFeaturizer
from gcnt.morphology import GLOBAL_TYPE_ID
from gcnt.morphology.catalogues import smpenv_robot

MIXED = ["walker_7_main", "cheetah_3_back", "humanoid_2d_8_left_knee", "hopper_5"]


def robots(*names):
    return [smpenv_robot(n) for n in names]


def random_actions(env, gen, k=None):
    """Uniform actions for the first ``k`` limb slots (default: all), 0.7 on the others."""
    n, kk, a = env.action_spec["limbs", "action"].shape
    k = kk if k is None else k
    act = torch.full((n, kk, a), 0.7)
    act[:, :k] = torch.rand((n, k, a), generator=gen) * 2 - 1
    return act


def run(env, steps, seed=0, td=None, k=None):
    """``steps`` random steps with partial resets; returns the stacked transitions."""
    gen = torch.Generator().manual_seed(seed)
    td = env.reset() if td is None else td
    out = []
    for _ in range(steps):
        td["limbs", "action"] = random_actions(env, gen, k)
        full, td = env.step_and_maybe_reset(td)
        out.append(full.clone())
    return torch.stack(out)


# --------------------------------------------------------------------------- observation


def axis_angle(q):
    """Rotation vector of a unit quaternion (w, x, y, z), angle in [0, π], by hand."""
    w, v = q[0], np.asarray(q[1:], float)
    if w < 0:
        w, v = -w, -v
    s = np.linalg.norm(v)
    if s < 1e-12:
        return np.zeros(3)
    return v / s * (2.0 * np.arctan2(s, w))


def reference_obs(robot, model, data):
    """The 19-d observation of every limb, one body at a time from a fresh mj_forward."""
    fresh = mujoco.MjData(model)
    fresh.qpos[:], fresh.qvel[:] = data.qpos, data.qvel
    mujoco.mj_forward(model, fresh)
    torso_x = fresh.xpos[robot.mj_body_ids[0]][0]
    rows = []
    for limb, body in enumerate(robot.mj_body_ids):
        vel = np.zeros(6)  # [angular, linear] of the body frame, world axes
        mujoco.mj_objectVelocity(model, fresh, mujoco.mjtObj.mjOBJ_XBODY, int(body), vel, 0)
        onehot = np.zeros(4)
        onehot[robot.family_slots[limb]] = 1
        if limb == 0:
            angle, rng = [0.0], [0.0, 0.0]
        else:
            j = robot.mj_joint_ids[limb][0]
            lo, hi = np.rad2deg(model.jnt_range[j])
            q = np.rad2deg(fresh.qpos[model.jnt_qposadr[j]])
            angle, rng = [(q - lo) / (hi - lo)], [(180 + lo) / 360, (180 + hi) / 360]
        pos = fresh.xpos[body] - [torso_x, 0, 0]
        rows.append(
            np.concatenate(
                [
                    pos,
                    np.clip(vel[3:], -10, 10),
                    vel[:3],
                    axis_angle(fresh.xquat[body]),
                    onehot,
                    angle,
                    rng,
                ]
            )
        )
    return np.array(rows)


@pytest.mark.parametrize("name", ["walker_7_main", "cheetah_7_full", "humanoid_2d_9_full"])
def test_observation_matches_independent_computation(name):
    robot = smpenv_robot(name)
    env = SMPEnv([robot, robot], max_limbs=11, seed=3, num_threads=2)
    data = run(env, 12)
    m, d = env.sim(1)
    obs = data["next", "limbs", "obs"][-1, 1].numpy()
    ref = reference_obs(robot, m, d)
    np.testing.assert_allclose(obs[: robot.num_limbs], ref, atol=2e-5, rtol=1e-5)
    assert (obs[robot.num_limbs :] == 0).all()
    assert (np.abs(obs[:, 3:6]) <= 10).all()
    assert obs[0, 0] == 0.0  # x relative to the torso


def test_observation_velocity_clipped():
    robot = smpenv_robot("cheetah_7_full")
    env = SMPEnv([robot], seed=0, num_threads=1)
    env.reset()
    m, d = env.sim(0)
    qvel = np.zeros(m.nv)
    qvel[0] = 25.0
    env.set_state(0, m.qpos0, qvel)
    obs = env.observe()["limbs", "obs"][0].numpy()
    assert (obs[: robot.num_limbs, 3] == 10.0).all()
    np.testing.assert_allclose(obs[: robot.num_limbs], reference_obs(robot, m, d), atol=2e-5)


def test_humanoid_limb_types():
    robot = smpenv_robot("humanoid_2d_9_full")
    env = SMPEnv([robot], seed=0, num_threads=1)
    td = env.reset()
    obs, types = td["limbs", "obs"][0], td["limbs", "type"][0]
    names = robot.body_names
    assert obs[0, 12] == 1  # torso
    for i, n in enumerate(names[1:], start=1):
        slot = 1 if n.endswith(("thigh", "upper_arm")) else 2
        assert obs[i, 12 + slot] == 1 and obs[i, 12:16].sum() == 1, n
        expected = next(t for t in ("thigh", "shin", "upper_arm", "lower_arm") if n.endswith(t))
        assert types[i] == GLOBAL_TYPE_ID[expected]


def test_featurizer_index_path_matches_slice_path():
    rs = robots("walker_5_main", "humanoid_2d_9_full")
    env = SMPEnv(rs, seed=1, max_limbs=10, num_threads=1)
    run(env, 5)
    f = LimbFeaturizer(rs, [env.sim(i)[0] for i in range(2)], 10)
    f._plan = [
        (ix.bodies, m, ix.joint_qpos) for ix, (_, m, _) in zip(f.index, f._plan, strict=True)
    ]
    for i in range(2):
        f.gather(i, env.sim(i)[1])
    np.testing.assert_array_equal(f.compute(), env.observe()["limbs", "obs"].numpy())


# --------------------------------------------------------------------------- padding, batching


def test_padding_does_not_change_real_limbs():
    rs = robots("walker_4_main", "hopper_3")
    a = SMPEnv(rs, seed=5, num_threads=1)
    b = SMPEnv(rs, max_limbs=13, seed=5, num_threads=2)
    ta, tb = run(a, 30), run(b, 30, k=4)
    k = a.max_limbs
    assert (a.max_limbs, b.max_limbs) == (4, 13)
    for key in ["obs", "mask", "type", "action_mask"]:
        torch.testing.assert_close(tb["next", "limbs", key][:, :, :k], ta["next", "limbs", key])
    assert (tb["next", "limbs", "obs"][:, :, k:] == 0).all()
    assert not tb["next", "limbs", "mask"][:, :, k:].any()
    assert not tb["next", "limbs", "action_mask"][:, :, k:].any()
    torch.testing.assert_close(tb["next", "reward"], ta["next", "reward"])
    assert (tb["next", "done"] == ta["next", "done"]).all()


def test_padded_and_torso_actions_are_ignored():
    rs = robots("walker_2_main", "cheetah_7_full")
    a, b = SMPEnv(rs, seed=2, num_threads=1), SMPEnv(rs, seed=2, num_threads=1)
    ta, tb = a.reset(), b.reset()
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        act = random_actions(a, gen)
        junk = act.clone()
        junk[~a.table["limbs", "action_mask"][a.local_ids]] = 55.0
        junk[0, 2:] = float("nan")  # padding of the 2-limb walker
        ta["limbs", "action"], tb["limbs", "action"] = act, junk
        ta, tb = a.step(ta)["next"], b.step(tb)["next"]
        torch.testing.assert_close(ta["limbs", "obs"], tb["limbs", "obs"])
        torch.testing.assert_close(ta["reward"], tb["reward"])


def test_table_morph_ids_and_robot_ids():
    w, c = robots("walker_7_main", "cheetah_2_front")
    env = SMPEnv([w, c, w, w], num_threads=1)
    assert env.batch_size == torch.Size([4])
    assert env.table.batch_size == torch.Size([2])
    assert env.morph_ids.tolist() == [0, 1, 0, 0]
    td = env.reset()
    assert td["morph_id"].tolist() == [0, 1, 0, 0]
    torch.testing.assert_close(td["graph", "adj"][2], env.table["graph", "adj"][0])
    assert td["graph", "dist"].dtype == torch.uint8
    env2 = SMPEnv([w, c, w, w], robot_ids=[7, 3, 7, 7], num_threads=1)
    assert env2.reset()["morph_id"].tolist() == [7, 3, 7, 7]
    with pytest.raises(ValueError, match="one id per robot"):
        SMPEnv([w, c], robot_ids=[1], num_threads=1)
    with pytest.raises(ValueError, match="same id"):
        SMPEnv([w, c], robot_ids=[1, 1], num_threads=1)


def test_robot_too_large():
    with pytest.raises(RobotTooLargeError, match="humanoid_2d_9_full"):
        SMPEnv(robots("walker_2_main", "humanoid_2d_9_full"), max_limbs=7)


def test_instances_with_same_k_stack():
    a = SMPEnv(
        robots("walker_7_main", "cheetah_4_front"), max_limbs=9, num_threads=1, robot_ids=[0, 1]
    )
    b = SMPEnv(
        robots("hopper_4", "humanoid_2d_9_full"), max_limbs=9, num_threads=1, robot_ids=[2, 3]
    )
    assert a.observation_spec == b.observation_spec
    assert a.action_spec == b.action_spec
    assert a.full_done_spec == b.full_done_spec
    both = torch.cat([run(a, 3), run(b, 3)], dim=1)
    assert both["next", "limbs", "obs"].shape == (3, 4, 9, 19)
    assert both["morph_id"][0].tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize("k", [None, 12])
def test_check_env_specs(k):
    env = SMPEnv(robots(*MIXED), max_limbs=k, seed=0)
    check_env_specs(env, seed=0)
    env.close()


def test_rollout_with_auto_reset_and_partial_steps():
    env = SMPEnv(robots("walker_2_main", "cheetah_2_back"), seed=0, num_threads=1)
    data = env.rollout(150, break_when_any_done=False)
    assert data.batch_size == (2, 150)
    assert data["next", "done"][0].any()  # the 2-limb walker falls and is reset
    # stop stepping sub-envs that are done, until all are (torchrl's "_step" key)
    data = env.rollout(1000, break_when_any_done=False, break_when_all_done=True)
    done = data["next", "done"][..., 0]
    assert done[:, -1].all()


# --------------------------------------------------------------------------- resets, seeding


def test_partial_reset_touches_only_flagged():
    env = SMPEnv(robots("walker_7_main", "cheetah_7_full", "hopper_3"), seed=0, num_threads=1)
    td = env.reset()
    gen = torch.Generator().manual_seed(1)
    for _ in range(10):
        td["limbs", "action"] = random_actions(env, gen)
        td = env.step(td)["next"]
    before = [env.sim(i)[1].qpos.copy() for i in range(3)]
    obs_before = td["limbs", "obs"].clone()
    td["_reset"] = torch.tensor([[False], [True], [False]])
    out = env.reset(td)
    after = [env.sim(i)[1].qpos for i in range(3)]
    np.testing.assert_array_equal(after[0], before[0])
    np.testing.assert_array_equal(after[2], before[2])
    m1 = env.sim(1)[0]
    assert np.abs(after[1] - m1.qpos0).max() <= 0.1  # back at the start pose (± cheetah noise)
    assert not np.allclose(after[1], before[1])
    torch.testing.assert_close(out["limbs", "obs"][[0, 2]], obs_before[[0, 2]])
    assert not torch.allclose(out["limbs", "obs"][1], obs_before[1])


def test_reset_noise_per_family():
    w, c = robots("walker_5_main", "cheetah_6_back")
    env = SMPEnv([w] * 20 + [c] * 20, seed=0, num_threads=1)
    env.reset()
    mw, mc = env.sim(0)[0], env.sim(20)[0]
    dqw = np.array([env.sim(i)[1].qpos - mw.qpos0 for i in range(20)])
    dvw = np.array([env.sim(i)[1].qvel for i in range(20)])
    dqc = np.array([env.sim(i)[1].qpos - mc.qpos0 for i in range(20, 40)])
    dvc = np.array([env.sim(i)[1].qvel for i in range(20, 40)])
    assert np.abs(dqw).max() <= 0.005 and np.abs(dvw).max() <= 0.005
    assert np.abs(dqw).max() > 0.004  # uniform over the whole interval
    assert np.abs(dqc).max() <= 0.1 and np.abs(dqc).max() > 0.08
    assert 0.07 < dvc.std() < 0.13  # N(0, 0.1²)


def test_same_seed_same_trajectories():
    rs = robots(*MIXED)
    a = run(SMPEnv(rs, seed=11, num_threads=2), 40, seed=4)
    b = run(SMPEnv(rs, seed=11, num_threads=1), 40, seed=4)
    assert (a == b).all()
    env = SMPEnv(rs, num_threads=2)
    env.set_seed(11)
    assert (run(env, 40, seed=4) == a).all()
    c = run(SMPEnv(rs, seed=12, num_threads=2), 40, seed=4)
    assert not torch.equal(c["limbs", "obs"][0], a["limbs", "obs"][0])


# --------------------------------------------------------------------------- failures


def test_nan_action_names_the_robot():
    env = SMPEnv(robots("walker_3_main", "hopper_4"), seed=0, num_threads=1)
    td = env.reset()
    act = torch.zeros(env.action_spec["limbs", "action"].shape)
    act[1, 2, 0] = float("nan")
    td["limbs", "action"] = act
    with pytest.raises(ValueError, match="hopper_4"):
        env.step(td)


@pytest.mark.parametrize("bad", [float("nan"), 1e12])
def test_physics_blowup_ends_only_that_episode(bad):
    rs = robots("walker_7_main", "humanoid_2d_9_full", "cheetah_7_full")
    env, twin = SMPEnv(rs, seed=0), SMPEnv(rs, seed=0)
    td, td_twin = env.reset(), twin.reset()
    m, d = env.sim(1)
    d.qvel[:] = bad
    td["limbs", "action"] = torch.zeros(env.action_spec["limbs", "action"].shape)
    td_twin["limbs", "action"] = td["limbs", "action"]
    with pytest.warns(PhysicsBlowupWarning, match="humanoid_2d_9_full"):
        full, td = env.step_and_maybe_reset(td)
    nxt = full["next"]
    assert nxt["terminated"][:, 0].tolist() == [False, True, False]
    same = twin.step(td_twin)["next"]  # the other robots are not affected
    torch.testing.assert_close(nxt["limbs", "obs"][[0, 2]], same["limbs", "obs"][[0, 2]])
    torch.testing.assert_close(nxt["reward"][[0, 2]], same["reward"][[0, 2]])
    assert torch.isfinite(nxt["limbs", "obs"]).all() and torch.isfinite(nxt["reward"]).all()
    # the blown-up sub-env was reset by the partial reset; the others go on
    assert not td["done"].any()
    assert np.isfinite(d.qvel).all() and np.abs(d.qvel).max() <= 0.005
    for _ in range(3):
        td["limbs", "action"] = torch.zeros(env.action_spec["limbs", "action"].shape)
        full, td = env.step_and_maybe_reset(td)
        assert not full["next", "terminated"][1]
    env.close()


def test_truncation_is_not_termination():
    env = SMPEnv(
        robots("cheetah_7_full", "cheetah_2_front"), max_episode_steps=5, seed=0, num_threads=1
    )
    data = run(env, 12)
    trunc, term, done = (data["next", k][..., 0] for k in ("truncated", "terminated", "done"))
    assert not term.any()
    expected = torch.tensor([False] * 4 + [True] + [False] * 4 + [True] + [False] * 2)
    assert (trunc == expected[:, None]).all()
    assert (done == trunc).all()


def test_error_in_a_physics_thread_is_raised_not_hung():
    import threading

    env = SMPEnv(robots(*MIXED) * 3, seed=0, num_threads=2)
    td = env.reset()
    td["limbs", "action"] = torch.zeros(env.action_spec["limbs", "action"].shape)
    for s in env._sims:  # every sub-env fails, whichever thread steps it
        s.ctrl_slice = slice(0, 1000)
    errors = []

    def step():
        try:
            env.step(td)
        except ValueError as e:
            errors.append(e)

    t = threading.Thread(target=step, daemon=True)
    t.start()
    t.join(timeout=30)
    assert not t.is_alive() and len(errors) == 1


def test_error_in_a_helper_thread_reaches_the_caller():
    import threading

    from gcnt.envs.stepper import StepQueue as _StepQueue

    env = SMPEnv(robots(*MIXED), seed=0, num_threads=2)
    env.reset()
    for s in env._sims:
        s.ctrl_slice = slice(0, 1000)
    queue = _StepQueue(list(range(4)))
    inside = threading.Event()

    def helper():
        assert queue.enter()
        inside.set()
        try:
            with pytest.raises(ValueError):
                env._work(queue, np.zeros(3), queue.take_first)
        finally:
            queue.leave()

    t = threading.Thread(target=helper, daemon=True)
    t.start()
    inside.wait(timeout=30)
    with pytest.raises(ValueError):
        queue.close()
    t.join(timeout=30)
    assert not t.is_alive()


def test_step_queue_hands_each_sub_env_out_once_and_waits_only_for_helpers_inside():
    """Helpers take the most expensive sub-envs (the front), the caller the cheapest (the
    back); a helper that starts after the caller closed the step does nothing, and close does
    not wait for it."""
    import threading

    from gcnt.envs.stepper import StepQueue as _StepQueue

    queue = _StepQueue([5, 3, 8, 1])
    assert queue.take_first() == 5 and queue.take_last() == 1
    assert queue.enter()
    queue.leave()
    assert queue.take_first() == 3 and queue.take_last() == 8
    assert queue.take_first() == -1 and queue.take_last() == -1
    queue.close()  # no helper inside: returns at once
    assert not queue.enter()  # a helper that starts now finds the step closed

    queue = _StepQueue([0, 1])
    assert queue.enter()
    closed = threading.Event()

    def caller():
        queue.close()
        closed.set()

    t = threading.Thread(target=caller, daemon=True)
    t.start()
    assert not closed.wait(timeout=0.2)  # waits for the helper inside
    queue.leave()
    assert closed.wait(timeout=30)
    t.join(timeout=30)


def test_thread_count_tuning():
    """num_threads=None probes 1 thread vs all now and then and keeps the faster."""
    env = SMPEnv(robots("walker_7_main") * 4, seed=0)
    if env.num_threads == 1:
        pytest.skip("one CPU")
    fast = {1: 1.0, env.num_threads: 0.5}
    used = []
    for _ in range(400):
        k = env._threads_now()
        used.append(k)
        env._times[k].append(fast[k])
    assert used.count(1) == 16  # two probes of 8 steps, with a longer pause after the first
    assert env._use == env.num_threads
    fast = {1: 0.5, env.num_threads: 1.0}  # now a single thread is faster
    for _ in range(800):
        k = env._threads_now()
        env._times[k].append(fast[k])
    assert env._use == 1
    assert SMPEnv(robots("walker_7_main") * 4, num_threads=2)._threads_now() == 2  # fixed


def test_an_output_written_in_place_leaves_the_next_ones_alone():
    """TorchRL's collector zeroes its carrier (the env's last output) in place when it resets:
    no tensor of an output, the static entries included, may be shared with a later one."""
    env = SMPEnv(robots("walker_2_main", "hopper_5"), max_limbs=5, seed=0, num_threads=1)
    first = env.reset()
    kept = first.clone()
    first.zero_()
    action = torch.zeros(env.action_spec["limbs", "action"].shape)
    out = env.step(kept.clone().set(("limbs", "action"), action))["next"]
    for key in [
        ("limbs", "mask"),
        ("limbs", "type"),
        ("graph", "adj"),
        ("graph", "dist"),
        "morph_id",
    ]:
        assert torch.equal(out.get(key), kept.get(key)), key
    again = env.reset()
    again.zero_()
    assert torch.equal(env.observe()["graph", "adj"], kept["graph", "adj"])
