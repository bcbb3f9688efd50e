"""A fixed probe of what a TD3 learner has become: its critic's values and its actor's actions on
transitions that do not depend on the run (``td3.probe_interval``).

The probe is ``td3.probe_steps`` lockstep steps of uniform-random actions on the run's training
robots, from a fixed seed (:data:`PROBE_SEED`): the same transitions for every method and every
seed of a task, so that values are comparable across runs. It is built without touching torch's
global random stream (a run with a probe trains exactly as one without, and resumes exactly).
Measured with no gradient and no random draw:

* ``probe/q1_mean``: critic 1's Q of the probe's (observation, stored action), averaged over
  real limbs, then transitions (the critic's value scale, per limb as the critics are trained);
* ``probe/saturated``: the fraction of the deterministic actor's driven action slots on the
  probe's observations with \\|a\\| > :data:`SATURATED` (a bang-bang policy);
* ``probe/action_std``: the std of those actions (near 0: one constant action).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase

from gcnt.keys import ACTION, ACTION_MASK, LIMB_Q, MASK, MORPH_ID, OBS

#: the probe's seed: the env's and the random actions'
PROBE_SEED = 20_261_207
#: |a| above this counts as saturated (tanh actions in [-1, 1])
SATURATED = 0.95


def make_probe(recipe, robots: Sequence, steps: int) -> TensorDictBase:
    """``steps`` lockstep steps of uniform-random actions on ``robots`` (flat [robots x steps]),
    from :data:`PROBE_SEED`, leaving torch's global random stream as it was."""
    from gcnt.rl.factories import make_env

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(PROBE_SEED)
        env = make_env(recipe, robots, seed=PROBE_SEED, num_threads=1)
        spec = env.full_action_spec[ACTION]
        try:
            data = env.rollout(
                steps,
                policy=lambda td: td.set(ACTION, spec.rand()),
                break_when_any_done=False,
            )
        finally:
            env.close()
    return data.reshape(-1).select(MORPH_ID, OBS, ACTION).to(recipe.device)


@torch.no_grad()
def probe_measures(learner, probe: TensorDictBase, chunk: int = 1000) -> dict[str, float]:
    """``probe/q1_mean``, ``probe/saturated`` and ``probe/action_std`` of ``learner`` (a
    :class:`~gcnt.rl.td3.learner.TD3Learner`) on ``probe``, in chunks of ``chunk``."""
    q_sum, q_n, actions = 0.0, 0, []
    for start in range(0, probe.numel(), chunk):
        part = probe[start : start + chunk]
        ids = part.get(MORPH_ID).reshape(-1)
        robots = learner.f_actor.robot_batch(ids, learner.critics.chain)
        mask = robots.gathered(MASK)
        now = {OBS: part.get(OBS), ACTION: part.get(ACTION)}
        q = learner.critics.one(0, now, robots, lambda out: out[LIMB_Q], fixed=True)
        per_robot = (q.squeeze(-1) * mask).sum(-1) / mask.sum(-1)
        q_sum += float(per_robot.sum())
        q_n += per_robot.numel()
        action = learner.f_actor({OBS: part.get(OBS)}, robots)[ACTION]
        actions.append(action[robots.gathered(ACTION_MASK)])
    a = torch.cat(actions)
    return {
        "probe/q1_mean": q_sum / q_n,
        "probe/saturated": float((a.abs() > SATURATED).float().mean()),
        "probe/action_std": float(a.std()),
    }
