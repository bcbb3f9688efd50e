"""A strobe picture of one rollout (paper figure 11): poses along the path in one image.

The run's deterministic policy drives one robot (by default ``humanoid_2d_9_full``) for up to
``steps`` control steps or until its episode ends. ``frames`` poses, evenly spaced in time, are
drawn into one MuJoCo scene (earlier poses fainter) seen from the side by a free camera that frames
the whole path, and rendered headless (``MUJOCO_GL=egl``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gcnt.analysis.runs import AnalysisError, Run

DEFAULT_ROBOT = "humanoid_2d_9_full"


def _policy_and_env(run: Run, robot: str, seed: int):
    """The run's trained deterministic policy and a one-robot env for ``robot``."""
    from gcnt.morphology.catalogues import resolve_robots
    from gcnt.rl.algorithm import get_algorithm
    from gcnt.rl.factories import make_env
    from gcnt.rl.run_dir import RunDir

    recipe = RunDir(run.path).load_recipe()
    policy_state = run.policy_state()
    robots = resolve_robots([robot])
    train_k = recipe.env.max_limbs or max(r.num_limbs for r in resolve_robots(recipe.env.robots))
    max_limbs = max(train_k, *(r.num_limbs for r in robots))
    env = make_env(recipe, robots, seed=seed, max_limbs=max_limbs, num_threads=1)
    policy = get_algorithm(recipe.algo).eval_policy(recipe, policy_state, env, deterministic=True)
    return policy, env


def rollout_poses(run: Run, robot: str = DEFAULT_ROBOT, steps: int = 300, seed: int = 0):
    """(model, data, qpos per step [T, nq], episode return) of one deterministic rollout."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    policy, env = _policy_and_env(run, robot, seed)
    model, data = getattr(env, "base_env", env).sim(0)  # under the TransformedEnv
    poses = []
    ret = 0.0
    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(steps):
            td = policy(td)
            td, td_next = env.step_and_maybe_reset(td)
            poses.append(data.qpos.copy())
            ret += float(td["next", "reward"].sum())
            if bool(td["next", "done"].any()):
                break
            td = td_next
    return env, model, data, np.stack(poses), ret


def render_strobe(
    model,
    data,
    poses: np.ndarray,
    path: str | Path,
    *,
    frames: int = 8,
    width: int = 1280,
    height: int = 480,
    title: str | None = None,
) -> Path:
    """Draw ``frames`` of ``poses`` into one scene and write a PNG."""
    import copy

    import mujoco

    from gcnt.envs.render import headless_gl

    idx = np.unique(np.linspace(0, len(poses) - 1, max(1, frames)).round().astype(int))
    rmodel = copy.copy(model)
    rmodel.vis.global_.offwidth = max(width, rmodel.vis.global_.offwidth)
    rmodel.vis.global_.offheight = max(height, rmodel.vis.global_.offheight)
    # where the robot goes: the root body's positions at the chosen frames
    root = 1 if model.nbody > 1 else 0
    centres = []
    for i in idx:
        data.qpos[:] = poses[i]
        mujoco.mj_forward(model, data)
        centres.append(data.xpos[root].copy())
    centres = np.array(centres)
    lo, hi = centres.min(0), centres.max(0)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = (lo + hi) / 2
    span = float(max(hi[0] - lo[0], hi[1] - lo[1], 1.0))
    cam.distance = 1.2 * span + 2.5
    cam.azimuth, cam.elevation = 90.0, -8.0
    headless_gl()
    renderer = mujoco.Renderer(rmodel, height=height, width=width, max_geom=20000)
    try:
        opt = mujoco.MjvOption()
        pert = mujoco.MjvPerturb()
        data.qpos[:] = poses[idx[-1]]
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, camera=cam, scene_option=opt)
        scene = renderer.scene
        for n, i in enumerate(idx[:-1]):
            data.qpos[:] = poses[i]
            mujoco.mj_forward(model, data)
            start = scene.ngeom
            mujoco.mjv_addGeoms(model, data, opt, pert, mujoco.mjtCatBit.mjCAT_DYNAMIC, scene)
            alpha = 0.25 + 0.6 * n / max(1, len(idx) - 1)
            for g in range(start, scene.ngeom):
                scene.geoms[g].rgba[3] = alpha
        image = renderer.render()
    finally:
        renderer.close()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    import imageio.v2 as imageio

    if title:
        image = _with_title(image, title)
    imageio.imwrite(path, image)
    return path


def _with_title(image: np.ndarray, title: str) -> np.ndarray:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h, w = image.shape[:2]
    fig = plt.figure(figsize=(w / 100, h / 100 + 0.4), dpi=100)
    ax = fig.add_axes((0, 0, 1, h / (h + 40)))
    ax.imshow(image)
    ax.axis("off")
    fig.suptitle(title, fontsize=11, y=0.99)
    fig.canvas.draw()
    out = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return out


def strobe_run(
    run: Run,
    out: Path,
    *,
    robot: str = DEFAULT_ROBOT,
    steps: int = 300,
    frames: int = 8,
    seed: int = 0,
) -> Path:
    """The strobe picture of ``run``'s policy on ``robot``, as ``out/<...>.png``."""
    if not run.has_checkpoint():
        raise AnalysisError(f"{run.path}: no checkpoint to take the policy from")
    env, model, data, poses, ret = rollout_poses(run, robot, steps, seed)
    try:
        name = f"strobe-{robot}-{run.task}-{run.algo}-{run.method}-seed{run.seed}.png"
        title = f"{run.method} on {robot} ({len(poses)} steps, return {ret:.0f})"
        return render_strobe(
            model, data, poses, out / name.replace("+", "p"), frames=frames, title=title
        )
    finally:
        env.close()


def strobe_runs(runs: Sequence[Run], out: Path, **kwargs) -> list[Path]:
    return [strobe_run(r, out, **kwargs) for r in runs]
