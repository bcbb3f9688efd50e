"""The batched env reproduces a reference SMPENV rollout recorded before the env base existed.

The reference (``tests/data/smpenv_rollout_reference.npz``) was recorded from the monolithic
SMPEnv with :func:`reference_rollout` below: five robots of all four families, a fixed seed, a
fixed action sequence (stored in the file), auto-resets after terminations and truncations
(``max_episode_steps=40``), an explicit partial reset and one partial step (``_step``). The env
must reproduce every output bit for bit: the same float operations run in the same order.
Regenerate (only on purpose) with ``python tests/test_env_reference_rollout.py``.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch

from gcnt.envs import PhysicsBlowupWarning, SMPEnv
from gcnt.morphology.catalogues import smpenv_robot

DATA = Path(__file__).parent / "data" / "smpenv_rollout_reference.npz"
ROBOTS = ["cheetah_7_full", "walker_2_main", "humanoid_2d_9_full", "hopper_4", "walker_7_main"]
STEPS = 90
SEED = 7
RESET_AT, RESET_WHICH = 17, [1, 3]  # an explicit partial reset before this step
PARTIAL_AT, PARTIAL_WHICH = 33, [0, 2, 4]  # only these sub-envs step at this step
BLOWUP_AT, BLOWUP_WHICH = 50, 2  # this sub-env's qvel is set to 1e12 before this step
FALL_AT, FALL_WHICH = 62, 3  # this sub-env (a hopper) is put below its healthy height


def reference_actions(n: int, k: int, a: int) -> np.ndarray:
    rng = np.random.default_rng(123)
    return rng.uniform(-1.3, 1.3, (STEPS, n, k, a)).astype(np.float32)


def reference_rollout(actions: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Run the reference rollout; arrays of every step's outputs (and the actions used)."""
    env = SMPEnv([smpenv_robot(r) for r in ROBOTS], max_episode_steps=40, seed=SEED, num_threads=2)
    n, k, a = env.action_spec["limbs", "action"].shape
    if actions is None:
        actions = reference_actions(n, k, a)
    keys = ("obs", "reward", "terminated", "truncated", "done", "reset_obs")
    out: dict[str, list[np.ndarray]] = {key: [] for key in keys}
    td = env.reset()
    first_obs = td["limbs", "obs"].numpy().copy()
    for t in range(STEPS):
        if t == RESET_AT:
            mask = torch.zeros(n, 1, dtype=torch.bool)
            mask[RESET_WHICH] = True
            td["_reset"] = mask
            td = env.reset(td)
        td["limbs", "action"] = torch.from_numpy(actions[t])
        if t == BLOWUP_AT:
            env.sim(BLOWUP_WHICH)[1].qvel[:] = 1e12
        if t == FALL_AT:
            m, d = env.sim(FALL_WHICH)
            qpos = d.qpos.copy()
            qpos[1] = 0.3  # root slide z
            env.set_state(FALL_WHICH, qpos, d.qvel)
        if t == PARTIAL_AT:
            step = torch.zeros(n, 1, dtype=torch.bool)
            step[PARTIAL_WHICH] = True
            td["_step"] = step
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PhysicsBlowupWarning)
            full, td = env.step_and_maybe_reset(td)
        td.pop("_step", None)
        nxt = full["next"]
        out["obs"].append(nxt["limbs", "obs"].numpy().copy())
        for key in ("reward", "terminated", "truncated", "done"):
            out[key].append(nxt[key].numpy().copy())
        out["reset_obs"].append(td["limbs", "obs"].numpy().copy())
    qpos = np.concatenate([env.sim(i)[1].qpos for i in range(n)])
    env.close()
    result = {key: np.stack(v) for key, v in out.items()}
    result.update(first_obs=first_obs, actions=actions, final_qpos=qpos)
    return result


def test_reference_rollout_is_reproduced():
    """Flags and ids exactly; floating-point outputs to a few float32 ulps (on the recording
    machine they match bit for bit, but numpy's transcendental functions may round differently
    on another CPU's SIMD path, and a test must not depend on one CPU's last bit)."""
    ref = dict(np.load(DATA))
    got = reference_rollout(ref["actions"])
    assert got.keys() == ref.keys()
    assert ref["terminated"].any() and ref["truncated"].any()  # the file covers both ends
    for key, want in ref.items():
        assert got[key].shape == want.shape, key
        if np.issubdtype(want.dtype, np.floating):
            np.testing.assert_allclose(got[key], want, rtol=1e-5, atol=1e-5, err_msg=key)
        else:
            np.testing.assert_array_equal(got[key], want, key)


if __name__ == "__main__":
    np.savez_compressed(DATA, **reference_rollout())
