"""TD3's twin critics in two processes (``compile.twin_processes``): the same update as on two
threads, a helper spawned anew when the weights were replaced or it died, and one line when it
fails during a step."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
import torch

from gcnt.recipes import load_recipe
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3 import twin_process
from gcnt.rl.td3.learner import TD3Learner
from gcnt.rl.td3.twin import AtOnce, InTurn
from gcnt.rl.td3.twin_process import InTwoProcesses, Link, TwinHelperError

ROOT = Path(__file__).parents[1]
QUICK = ROOT / "recipes/quickstart.yaml"
NET = "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}"


def _learners(method="gcnt"):
    """A learner with its twin critics on two threads and one with them in two processes, the
    same initial weights, and a mixed and a one-robot batch."""
    net = "network.kwargs={}" if method == "smp" else NET
    base = [net, f"network.name={method}", "td3.max_grad_norm=0.5", "td3.target=limb"]
    env_recipe = load_recipe(QUICK, base)
    robots = train_robots(env_recipe)
    env = make_env(env_recipe, robots)
    data = env.rollout(10, break_when_any_done=False)
    learners = []
    for processes in ("false", "true"):
        recipe = load_recipe(QUICK, [*base, f"compile.twin_processes={processes}"])
        torch.manual_seed(0)
        learners.append(TD3Learner(recipe, env, twin_threads=True))
    env.close()
    replay = rb.RobotReplay(len(robots), capacity=30, batch_size=6)
    replay.extend(data)
    return learners, [replay.sample_mixed(), replay.sample_robot(len(robots) - 1)]


def _update_both(learners, batch, seed):
    out = []
    for learner in learners:
        torch.manual_seed(seed)  # the target-smoothing noise
        out.append(learner.update(batch))
    return out


@pytest.mark.parametrize("method", ["gcnt", "smp"])
def test_two_processes_update_as_two_threads_float64(method):
    """Both schedules' batches, gradient clipping on, actor steps: the losses, the four networks'
    weights and both Adam states equal those of the critics on two threads; the helper is
    replaced when the weights moved to new storage and when it was killed between two steps."""
    (threads, procs), batches = _learners(method)
    assert isinstance(threads.twin, AtOnce) and isinstance(procs.twin, InTwoProcesses)
    for learner in (threads, procs):
        for m in (learner.actor, learner.critics, learner.target_actor, learner.target_critics):
            m.double()
    batches = [b.apply(lambda t: t.double() if t.is_floating_point() else t) for b in batches]
    pids = []
    for step in range(4):
        if step:
            pids.append(procs.twin._proc.pid)
        if step == 1:  # weights moved to new storage (as .to() does): a helper that reads them
            for learner in (threads, procs):
                for p in learner.target_actor.parameters():
                    p.data = p.data.clone()
        if step == 2:  # killed between steps: the next step starts a new helper
            os.kill(pids[-1], signal.SIGKILL)
            procs.twin._proc.join()
        for batch in batches:
            a, b = _update_both((threads, procs), batch, step)
            assert a.keys() == b.keys()
            assert b == pytest.approx(a, rel=1e-12, abs=1e-14)
    pids.append(procs.twin._proc.pid)
    assert pids[0] != pids[1] != pids[2] == pids[3]
    for x, y in zip(threads.shared_tensors(), procs.shared_tensors(), strict=True):
        assert x.dtype == y.dtype
        torch.testing.assert_close(y, x, rtol=1e-12, atol=1e-14)
    for opt in ("actor_opt", "critic_opt"):
        mine = getattr(procs, opt).state_dict()["state"]
        for j, state in getattr(threads, opt).state_dict()["state"].items():
            for k in ("exp_avg", "exp_avg_sq"):
                torch.testing.assert_close(mine[j][k], state[k], rtol=1e-12, atol=1e-16)
    procs.twin.close()
    assert procs.twin._proc is None


def test_a_helper_ignores_stop_signals_and_one_that_fails_in_a_step_is_one_error():
    (_, procs), batches = _learners()
    procs.update(batches[0])
    runner = procs.twin
    pid = runner._proc.pid
    for sig in (signal.SIGINT, signal.SIGTERM):  # a stop is the main process's to handle
        os.kill(pid, sig)
    procs.update(batches[1])
    assert runner._proc.pid == pid and runner._proc.is_alive()
    with pytest.raises(TwinHelperError, match="twin_processes.*failed: ValueError: no step"):
        with runner.step(procs, "no such step"):
            pass
    assert runner._proc is None  # ended: the two processes may be out of step
    losses = procs.update(batches[1])
    assert set(losses) >= {"loss_critic"} and runner._proc.is_alive()
    runner.close()


def test_waiting_for_a_helper_that_ended_is_one_error(monkeypatch):
    monkeypatch.setattr(twin_process, "POLL_S", 0.01)
    here, there = torch.multiprocessing.get_context("spawn").Pipe()
    arenas = [twin_process.Arena(64) for _ in range(2)]
    link = Link(here, arenas, arenas, alive=lambda: False)
    with pytest.raises(TwinHelperError, match="ended during an update"):
        link.recv()
    there.close()


def test_results_cross_in_arenas_that_grow():
    here, there = torch.multiprocessing.get_context("spawn").Pipe()
    a = Link(here, [twin_process.Arena(64) for _ in range(2)], [None, None], lambda: True)
    b = Link(there, [None, None], [None, None], lambda: True)
    b.theirs = a.mine  # one process here: the reader's arenas are the writer's
    sent = (torch.arange(5.0), None, [torch.ones(40, 3, dtype=torch.float64)], {"k": 2})
    for _ in range(3):  # both slots, then the first again
        a.send(sent)
        got = b.recv()
        assert torch.equal(got[0], sent[0]) and got[1] is None and got[3] == {"k": 2}
        assert got[2][0].dtype == torch.float64 and torch.equal(got[2][0], sent[2][0])
    assert max(x.buf.numel() for x in a.mine) >= 40 * 3 * 8


def test_twin_processes_need_the_critics_at_once():
    # one call (twin_threads=false) or a GPU: nothing runs at once, so no helper either
    env_recipe = load_recipe(QUICK, [NET, "compile.twin_processes=true"])
    env = make_env(env_recipe, train_robots(env_recipe))
    assert isinstance(TD3Learner(env_recipe, env, twin_threads=False).twin, InTurn)
    assert isinstance(TD3Learner(env_recipe, env, twin_threads=True, pair=True).twin, AtOnce)
    compiled = load_recipe(QUICK, [NET, "compile.twin_processes=true", "compile.compile=true"])
    assert isinstance(TD3Learner(compiled, env).twin, InTurn)
    env.close()
